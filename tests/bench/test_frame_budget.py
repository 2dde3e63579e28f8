"""Splitting a py-spy profile of the daemon's main process by pipeline stage."""

from __future__ import annotations

from tactiled_bench import budget

PROFILE = """\
process 10:"python -m tactiled.cli bench --suite acquisition";process 11:"python run_baseline.py";<module> (run_baseline.py:5);measure (benchmarks/tactiled_bench/acquisition.py:590);SensorPipeline.on_frame (tactiled/pipeline/sensor.py:351);CalibrationStage.process (tactiled/calibration/stage.py:52);ContactDetector.update (tactiled/calibration/detection.py:230) 30
process 10:"python -m tactiled.cli bench --suite acquisition";process 11:"python run_baseline.py";<module> (run_baseline.py:5);measure (benchmarks/tactiled_bench/acquisition.py:590);SensorPipeline.on_frame (tactiled/pipeline/sensor.py:351);CalibrationStage.process (tactiled/calibration/stage.py:55) 50
process 10:"python -m tactiled.cli bench --suite acquisition";process 11:"python run_baseline.py";Thread._bootstrap (threading.py:1002);PortReader._run (tactiled_drivers/port_reader.py:90);PortReader._wait (tactiled_drivers/port_reader.py:123) 400
process 10:"python -m tactiled.cli bench --suite acquisition";process 11:"python run_baseline.py";<module> (run_baseline.py:5);measure (benchmarks/tactiled_bench/acquisition.py:590);FrameDecoder.feed (tactiled/frames.py:249) 20
process 10:"python -m tactiled.cli bench --suite acquisition";process 11:"python run_baseline.py";process 12:"python -m tactiled.pipeline.worker";fit (tactiled/fit/fitter.py:300) 999
process 10:"python -m tactiled.cli bench --suite acquisition";renice_simulators (benchmarks/tactiled_bench/acquisition.py:80) 77
"""


def test_samples_of_the_main_process_by_innermost_stage() -> None:
    """The worker's and the bench's own samples are left out, so are threads asleep in select;
    the detector inside the calibration stage counts as the detector."""
    per, total = budget.breakdown(PROFILE.splitlines())
    assert total == 100
    assert per == {"detector": 30, "calibration stage": 50, "decoding and reading": 20}
    text = budget.table(per, total, cpu_share=0.5, frames_per_s=5000)
    assert "| calibration stage | 50.0 % | 50.0 |" in text and "| total | 100 % | 100.0 |" in text


def test_the_stage_alone_is_timed_on_both_paths() -> None:
    assert budget.stage_cost("fearing1988", "hand-finger3", True, frames=20, repeats=1) > 0
    assert budget.stage_cost("flat16", "hand-palm", False, frames=20, repeats=1) > 0


def test_the_replayed_hand_counts_every_frame_and_its_relinearisations() -> None:
    """Two parts, 300 frames each, replayed lossless through a real daemon with a real
    worker: every frame handled, the CPU per frame measured, the moving contact (finger1's
    roll, from 0.7 s: so 1000 frames) relinearised."""
    parts = (budget.HAND_PARTS[0], budget.HAND_PARTS[1])
    runs = budget.replay_cost(parts, frames=1000, workers=1, passes=1)
    (r,) = runs
    assert r["frames"] == 2000
    assert 0.0 < r["us_per_frame"] < 1e5
    assert set(r["relinearized"]) == {"palm", "finger1"}
    assert r["relinearized"]["finger1"] > 0 and r["fits"]["finger1"] > 0


def test_the_read_path_alone_reads_every_frame_and_hands_none_to_the_pipeline() -> None:
    """``read_only``: every frame read, decoded and counted, none taken through the stage (no
    fit, no relinearisation although the part rolls a contact), and the pipeline's own
    ``on_frames`` back in place after."""
    from tactiled.pipeline.sensor import SensorPipeline

    on_frames = SensorPipeline.on_frames
    (r,) = budget.replay_cost(budget.HAND_PARTS[1:2], frames=1000, workers=1, passes=1,
                              read_only=True)
    assert r["frames"] == 1000 and 0.0 < r["us_per_frame"] < 1e5
    assert r["fits"] == {"finger1": 0} and r["relinearized"] == {"finger1": 0}
    assert SensorPipeline.on_frames is on_frames


def test_a_checkout_is_replayed_in_its_own_process_with_this_measure(tmp_path) -> None:
    """``--replay --baseline REV`` runs this module's replay_cost on another checkout's code
    (here this tree's own, in a subprocess that imports it from the given path); with
    ``profile``, that process's cProfile of the replay, read per frame."""
    from pathlib import Path

    tree = str(Path(budget.__file__).resolve().parents[2])
    out = tmp_path / "replay.pstats"
    (r,) = budget.replay_at(tree, passes=1, frames=300, parts=budget.HAND_PARTS[3:4],
                            profile=str(out))
    assert r["frames"] == 300 and r["us_per_frame"] > 0.0
    assert set(r["relinearized"]) == {"finger3"}
    per = budget.functions_per_frame(str(out), 300)
    # every frame goes through the pipeline's code of the tree, each at least once
    assert max(calls for name, (calls, _own, _cum) in per.items()
               if name.startswith("tactiled/pipeline/")) >= 1.0
    assert all(0.0 <= own <= cum for _calls, own, cum in per.values())


def test_fit_jobs_are_timed_as_a_worker_does_them_here_and_on_a_checkout() -> None:
    """``--fits``: the palm's frames fitted and linearised, each job's time; the same on a
    checkout's code in a process of its own (here this tree's)."""
    from pathlib import Path

    r = budget.fit_cost("flat16", "hand-palm", every=50, frames=200, repeats=1)
    assert r["jobs"] == 4
    assert 0.0 < r["fit_ms"]["p50"] <= r["fit_ms"]["p90"] < 1e4
    assert 0.0 < r["lin_ms"]["p50"] <= r["lin_ms"]["p90"]
    tree = str(Path(budget.__file__).resolve().parents[2])
    there = budget.fits_at(tree, "fearing1988", "hand-finger2")
    assert there["jobs"] == 60 and there["fit_ms"]["p50"] > 0.0

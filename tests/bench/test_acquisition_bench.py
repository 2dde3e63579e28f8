"""The acquisition benchmark on moving contacts: its bookkeeping (shares of contact frames,
accuracy matched to the truth by seq, the tare) on made-up runs, and one short real run through
the command line.  Speed is reported by the benchmark (docs/performance/benchmarks.md), never asserted."""

from __future__ import annotations

import gc
import math
import subprocess
import sys

import pytest

from tactiled_bench import acquisition as acq
from tactiled_bench import acquisition_report as report
from tactiled_bench import acquisition_runs as runs
from tactiled.physics.contact import Contact
from tactiled.sim import SCENES, FingerSimulator, Pose, SceneBuilder, named_scene

TACTILED = [sys.executable, "-m", "tactiled.cli", "bench", "--no-progress"]


def counters(frames: int = 0, superseded: int = 0, stale: int = 0, predicted: int = 0,
             free: int = 0) -> dict:
    return {"frames": frames, "superseded": superseded, "stale_dropped": stale, "fit_failed": 0,
            "fit_errors": 0, "predicted": predicted, "skipped": {"no_contact": free}}


def stats(**per_finger: dict) -> dict:
    return {"sensors": {name: per_finger.get(name, counters()) for name in runs.FINGERS}}


def fit_line(c: Contact | None, **changes) -> dict:
    if c is None:
        return {"contact": False}
    line = {"contact": True, "r1_mm": c.r1, "angle_deg": c.psi_deg, "force_n": c.force,
            "x_mm": c.x0, "y_mm": c.y0, "fit_ms": 0.5, "message": "converged"}
    line.update(changes)
    return line


def test_what_a_run_keeps_of_an_estimate_is_left_alone_by_the_collector() -> None:
    """The listener keeps each estimate as a tuple of numbers and strings: after a collection
    the garbage collector no longer tracks it, so ~60 000 of them do not make every full
    collection of the measured daemon longer (a whole fit line, nested dicts, stays tracked;
    they stalled the loop up to 69 ms each).  Rebuilt after the run, it summarises as the whole
    line does."""
    c = Contact(8.0, math.inf, 40.0, 1.2, 10.5, 12.5)
    line = {**fit_line(c), "std": {"x_mm": 0.01}, "reasons": {}, "model": "cylinder"}
    record = (0, 7, "fit", 1.5, runs.slim(line))
    whole = (0, 7, "fit", 1.5, line)
    gc.collect()
    gc.collect()  # (the inner tuple is let go in one pass, the record holding it in the next)
    assert not gc.is_tracked(record)
    assert gc.is_tracked(whole)  # (the test can fail: a record keeping the line would be)
    seen = runs.Seen.from_record(record)
    assert seen.fit == {k: line.get(k) for k in runs.SLIM_KEYS}
    truth = lambda seq: c  # noqa: E731
    run = runs.RunResult(2, stats(), stats(), 1.0, [seen], {})
    full = runs.RunResult(2, stats(), stats(), 1.0, [runs.Seen(0, 7, "fit", 1.5, line)], {})
    a, b = runs.summarise(run, truth), runs.summarise(full, truth)
    assert (a.own_fit, a.fit_ms, a.accuracy["all"].errors) == (b.own_fit, b.fit_ms, b.accuracy["all"].errors)


def test_truth_by_seq_is_the_simulators_contact() -> None:
    truth = runs.scene_truth("moving", 1000.0)
    sim = FingerSimulator(scene="moving", seed=3, rate_hz=1000.0)
    sim.skip(2 * sim.ticks_per_pass - 300)  # across the loop
    for _ in range(600):
        tick = sim.step()
        assert truth(tick.seq) == tick.contact


def test_tare_window_lies_in_the_first_long_idle(monkeypatch: pytest.MonkeyPatch) -> None:
    for scene in ("moving", "demo", "press"):
        lo, hi = runs.tare_window(scene, 1000.0)
        sc = named_scene(scene)
        assert all(sc.contact_at(k / 1000.0) is None for k in range(lo, hi + 250))  # + settling
    monkeypatch.setitem(SCENES, "busy", lambda g: (
        SceneBuilder(Pose(x0=10, y0=10)).idle(0.2).press(0.5, force=1.0).release(0.5).build("busy")))
    assert runs.tare_window("busy", 1000.0) is None  # no idle of 0.4 s


def test_errors_in_reporting_units() -> None:
    c = Contact(10.0, math.inf, 170.0, 1.0, 5.0, 6.0)
    assert runs.abs_error("r1_mm", 11.0, c) == pytest.approx(10.0)
    assert runs.abs_error("force_n", 0.9, c) == pytest.approx(10.0)
    assert runs.abs_error("angle_deg", 5.0, c) == pytest.approx(15.0)  # across the fold at 180
    assert runs.abs_error("x_mm", 5.02, c) == pytest.approx(20.0)
    assert runs.abs_error("y_mm", 5.99, c) == pytest.approx(10.0)
    assert runs.abs_error("angle_deg", 5.0, Contact(8.0, 8.0, 90.0, 1.0, 5.0, 6.0)) is None
    assert [runs.indentor(Contact(r, r2)) for r, r2 in ((8, 8), (0.5, math.inf), (10, math.inf), (5, 9))] \
        == ["sphere", "edge", "cylinder", "general"]


def test_shares_latency_and_accuracy_of_a_run() -> None:
    truth = runs.scene_truth("moving", 1000.0)
    base = 5450 * 3  # a later pass: the truth repeats
    rolling = [base + 700 + k for k in range(10)]  # the cylinder rolling at 20 mm/s
    assert all(truth(s) is not None for s in rolling)
    seen = []
    # frames 0, 4, 8: fitted exactly; 1-3, 5-7: reused; 9: superseded (no estimate)
    for k, seq in enumerate(rolling[:9]):
        if k % 4 == 0:
            seen.append(runs.Seen(0, seq, "fit", 2.0, fit_line(truth(seq))))
        else:
            fitted = rolling[k - k % 4]
            seen.append(runs.Seen(0, seq, "unchanged", 0.5, fit_line(truth(fitted))))
    seen.append(runs.Seen(1, base + 200, "no_contact", 0.1, fit_line(None)))  # idle: right
    seen.append(runs.Seen(1, base + 201, "fit", 3.0, fit_line(truth(rolling[0]))))  # phantom
    seen.append(runs.Seen(2, rolling[0], "fit", 4.0, fit_line(truth(rolling[0]), r1_mm=None)))
    seen.append(runs.Seen(2, rolling[1], "no_contact", 0.1, fit_line(None)))  # missed
    before = stats()
    after = stats(thumb=counters(frames=10, superseded=1, predicted=2), index=counters(frames=2),
                  middle=counters(frames=2, stale=1))
    a = runs.summarise(runs.RunResult(2, before, after, 1.0, seen, {}), truth)
    assert (a.own_fit, a.reused, a.superseded, a.unanswered) == (5, 6, 1, 1)
    assert a.predicted == 2 and a.share(a.predicted) == "15.4 %"  # of the reuses, not beside
    assert a.contact == 13 and a.frames == 14
    assert a.share(a.own_fit) == "38.5 %"
    assert sorted(a.latency_fit) == [2.0, 2.0, 2.0, 3.0, 4.0] and len(a.latency_contact) == 11
    assert (a.touching, a.missed, a.phantom) == (11, 1, 1)
    # the phantom counts as a lift-off published late only within late_ticks of the truth's
    # last touching tick before it
    gap = next(j for j in range(1, 6000) if truth(base + 201 - j) is not None)
    for late, want in ((gap - 1, 0), (gap, 1)):
        b = runs.summarise(runs.RunResult(2, before, after, 1.0, seen, {}), truth, late_ticks=late)
        assert (b.phantom, b.phantom_after_release) == (1, want), (late, gap)
    assert a.phantom_after_release == 0  # (late_ticks 0: none)
    own, reuses = a.accuracy["own fits"], a.accuracy["reuses"]
    assert own.estimates == 4 and own.errors["x_mm"] == pytest.approx([0.0] * 4)
    assert own.withheld["r1_mm"] == 1 and "25 % withheld" in own.cell("r1_mm")
    # a reuse k frames after its fit lags the contact by k x 20 um
    assert sorted(reuses.errors["x_mm"]) == pytest.approx([20, 20, 40, 40, 60, 60])
    assert a.accuracy["all"].estimates == 10 and set(a.accuracy) == {"all", "own fits", "reuses", "cylinder"}


def test_a_finger_that_never_sees_its_contact_end_is_marked_locked() -> None:
    """The moving scene leaves a finger untouched 15.6 % of the time (0.85 s of 5.45 s): over
    20 000 frames about 3100 "no contact" frames; under a tenth of that, the finger is locked
    in contact (the zeroer's known limitation), and its run is marked so."""
    untouched = report.untouched_share("moving", 1000.0)
    truth = runs.scene_truth("moving", 1000.0)
    assert untouched == sum(truth(k) is None for k in range(5450)) / 5450
    assert 0.15 < untouched < 0.16
    before = stats()
    after = stats(thumb=counters(frames=20000, free=3000), index=counters(frames=20000, free=250),
                  middle=counters(frames=20000, free=0))
    run = runs.RunResult(2, before, after, 20.0, [], {})
    assert report.locked_fingers(run, untouched) == ["index", "middle"]
    after["sensors"]["index"]["skipped"]["no_contact"] = 350  # above a tenth: free
    assert report.locked_fingers(run, untouched) == ["middle"]


@pytest.mark.parametrize("workers, seconds", [
    ("1", "1"), pytest.param("1,2", "2", marks=pytest.mark.slow)])
def test_the_moving_scene_on_ptys_with_a_workers_sweep(table_rows, workers: str,
                                                        seconds: str) -> None:
    """A short real run: three simulators on ptys, the daemon with 1 worker for 1 s (~20 s in
    all); with ``-m slow`` the sweep, 1 and then 2 workers for 2 s each."""
    proc = subprocess.run([*TACTILED, "--suite", "acquisition", "--scene", "moving", "--quick",
                           "--workers", workers, "--seconds", seconds],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    sweep = workers.split(",")
    out = proc.stdout
    assert "scene moving" in out and "--scene moving" in out

    def rows(header: str) -> list[list[str]]:
        return table_rows(out, header)

    answers = rows("| workers | contact frames |")
    assert [r[0] for r in answers] == sweep
    for r in answers:
        assert int(r[1]) > 0
        own, reused, predicted, superseded, lost = (float(c.rstrip(" %")) for c in r[2:7])
        assert own + reused + superseded + lost == pytest.approx(100.0, abs=0.25)
        assert 0.0 <= predicted <= reused  # predicted frames go out as reuses
        assert len(r[7].split(" / ")) == 2  # latency p50 / p99
        assert r[13] == "none" or set(r[13].split(", ")) <= set(runs.FINGERS)
    accuracy = rows("| workers | estimates of |")
    kinds = {(r[0], r[1]) for r in accuracy}
    # a row for the own fits where the run made some: on a loaded machine a short window's
    # contact frames may all go out as reuses or be superseded
    own = {r[0]: float(r[2].rstrip(" %")) for r in answers}
    assert {(w, "all") for w in sweep} | {(w, "own fits") for w in sweep if own[w] >= 1.0} <= kinds
    assert {k for _, k in kinds} <= {"all", "own fits", "reuses", *runs.INDENTORS, "general"}
    integrity = rows("| workers | finger |")
    assert len(integrity) == 3 * len(sweep) and {r[1] for r in integrity} == set(runs.FINGERS)
    assert all(r[-1] == "0" for r in integrity), integrity  # every frame accounted for


@pytest.mark.slow
def test_a_baseline_runs_its_own_code_side_by_side() -> None:
    """``--baseline REV``: the daemon of a git revision (here HEAD, archived into a temporary
    folder and run from there) alternates with this tree's, two runs each, labelled.  Four
    daemon runs with their warm-ups (1-2.5 min), so behind ``-m slow``; the renicing of a
    baseline's simulators is checked in the default run below."""
    proc = subprocess.run([*TACTILED, "--suite", "acquisition", "--scene", "moving", "--quick",
                           "--workers", "1", "--seconds", "1", "--baseline", "HEAD"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    i = next(k for k, line in enumerate(lines) if line.startswith("| code, workers | contact frames |"))
    runs = [line.split("|")[1].strip() for line in lines[i + 2:i + 6]]
    assert runs == ["this tree, 1", "baseline HEAD, 1", "baseline HEAD, 1", "this tree, 1"]
    assert all(int(line.split("|")[2]) > 0 for line in lines[i + 2:i + 6])  # contact frames


@pytest.mark.parametrize("argv, message", [
    (["--scene", "nope"], "unknown scene 'nope'"),
    (["--workers", "0"], "worker counts must lie in 1..64"),
    (["--workers", "two"], "expected worker counts like 1,2,4"),
    (["--seconds", "0"], "--seconds must be positive"),
    (["--sim-nice", "20"], "--sim-nice must be a niceness 0-19, got 20"),
])
def test_bad_acquisition_options(argv: list[str], message: str) -> None:
    proc = subprocess.run([*TACTILED, "--suite", "acquisition", *argv], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2 and message in proc.stderr


def test_simulators_under_a_harness_are_reniced_and_no_others(tmp_path) -> None:
    """``--sim-nice`` with ``--baseline``: the baseline's own harness starts its simulators, so
    they are found under its process (grandchildren here) and reniced from outside; a
    simulator that is not under it keeps its niceness."""
    import os
    import time

    def simulate(link: str) -> list[str]:
        return [sys.executable, "-m", "tactiled.cli", "simulate", "--pty", "--link",
                str(tmp_path / link), "--scene", "press", "--rate", "50"]

    harness = subprocess.Popen([sys.executable, "-c",
                                "import subprocess, sys; subprocess.run(sys.argv[1:])",
                                *simulate("under")],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    other = subprocess.Popen(simulate("other"), stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while not ((tmp_path / "under").exists() and (tmp_path / "other").exists()):
            assert time.monotonic() < deadline, "simulators did not start"
            time.sleep(0.05)
        assert acq.renice_simulators(harness.pid, 7) == 1
        assert acq.renice_simulators(harness.pid, 7) == 0  # already at 7
        assert os.getpriority(os.PRIO_PROCESS, other.pid) == os.getpriority(os.PRIO_PROCESS, 0)
    finally:
        for p in (other, harness):
            p.terminate()
        for p in (other, harness):
            p.wait(30)
        # the harness's own simulator outlives it (nothing passes the signal on)
        subprocess.run(["pkill", "-f", str(tmp_path / "under")], check=False)


def test_a_tare_is_repeated_until_the_baseline_forms_on_untouched_frames() -> None:
    class FakeDaemon:
        def __init__(self) -> None:
            self.tared: list[str] = []

        def tare(self, sensor: str) -> None:
            self.tared.append(sensor)

    rate, per_pass = 1000.0, 5450
    window = runs.tare_window("moving", rate)
    daemon = FakeDaemon()
    tarer = acq._Tarer(daemon, window, per_pass, rate, runs.scene_truth("moving", rate))
    lo = window[0]
    # thumb: tared in the window, then a starved simulator skips into the next contact
    tarer.frame("thumb", 100)  # touching, outside the window: nothing
    tarer.frame("thumb", lo)
    assert daemon.tared == ["thumb"]
    tarer.frame("thumb", 700)  # the baseline restarted from a contact frame: not good
    assert tarer.state["thumb"][0] == "waiting"
    # index and middle: tared, then 0.3 s of untouched frames
    for name in ("index", "middle"):
        for seq in range(per_pass + lo, per_pass + lo + 320):
            tarer.frame(name, seq)
    assert not tarer.done()
    for seq in range(2 * per_pass + lo, 2 * per_pass + lo + 320, 3):  # gaps are fine while idle
        tarer.frame("thumb", seq)
    assert tarer.done() and tarer.tares == 4 and daemon.tared == ["thumb", "index", "middle", "thumb"]


def test_touches_below_the_detection_limit_are_counted_apart() -> None:
    """A press's first frames and a release's last carry a few hundredths of a newton: their
    noise-free strain's statistic is below the detector's enter threshold, so a miss there is
    no miss of the daemon's.  Checked against the threshold computed here, from the strain
    model and the detector, and against the scene's force."""
    from tactiled.calibration.detection import ContactDetector
    from tactiled.physics.strain import StrainModel
    from tactiled.sensors.model import SensorModel
    from tactiled.sim import named_scene

    rate = 1000.0
    truth, detectable = runs.scene_truth("hand", rate), runs.scene_detectable("hand", rate)
    finger3 = runs.devices("hand").index(runs.Device("finger3", "hand-finger3"))
    touching = [k for k in range(4000) if truth(k) is not None]
    above = [k for k in touching if detectable(finger3, k)]
    assert detectable(finger3, 1500) and not detectable(finger3, 200)  # held; nothing touches
    # the ends of the touch are below: a light press and a lift-off, each tens of frames
    first, last = above[0], above[-1]
    assert 10 < first - touching[0] < 100 and 10 < touching[-1] - last < 100, (first, last)
    assert above == list(range(first, last + 1))
    sensor = SensorModel()
    det = ContactDetector(0.0005, sensor=sensor, average=2)
    model = StrainModel(sensor)
    own = named_scene("hand-finger3", sensor.geometry)  # (truth(k): any part's contact)
    for k in (first - 1, first, last, last + 1):
        c = own.contact_at(k / rate)
        assert c is not None and c.force < 0.1
        stat = det.statistic(model.predict(c))
        assert (stat >= det.enter_threshold) == (k in (first, last)), (k, stat)
    # summarise counts them apart: a miss below the limit, a miss above it
    seen = [runs.Seen(finger3, touching[0], "no_contact", 0.1, fit_line(None)),
            runs.Seen(finger3, 1500, "no_contact", 0.1, fit_line(None)),
            runs.Seen(finger3, 1501, "fit", 1.0, fit_line(truth(1501)))]
    parts = tuple(d.name for d in runs.devices("hand"))
    counts = {"sensors": {name: counters() for name in parts}}
    run = runs.RunResult(2, counts, counts, 1.0, seen, {}, parts=parts)
    a = runs.summarise(run, truth, accuracy=False, detectable=detectable)
    assert (a.touching, a.missed, a.touching_detectable, a.missed_detectable) == (3, 2, 2, 1)

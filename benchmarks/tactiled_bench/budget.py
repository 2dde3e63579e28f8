"""Where the daemon's main process spends its CPU per frame: a py-spy profile, by stage.

    python -m tactiled_bench.budget prof.txt --frames-per-s 6000 --cpu-share 0.46

Splits a ``py-spy --format raw`` profile of a running acquisition bench by pipeline stage, for
the daemon's main process only (event loop and serial read thread); ``--stage``, ``--replay``
and ``--fits`` time the calibration stage, the whole main process on a replay, and a fit worker;
``--estimate`` a tracked contact frame's estimate alone.
"""
# Record the profile with:
#     py-spy record --subprocesses --nonblocking --format raw -r 250 -o prof.txt -- \
#         tactiled bench --suite acquisition --scene hand --seconds 15 --sim-nice 10
# (one collapsed stack per line, its sample count last; fit workers and simulators excluded).
# A sample belongs to the innermost stage its stack passes through (the detector inside the
# calibration stage counts as the detector).  With --cpu-share (the main process's CPU in cores
# over the window, as the bench's table gives it) and --frames-per-s the shares become
# microseconds per frame.
# --stage: the calibration stage alone, compiled and reference paths; --replay: the hand's parts
# replayed lossless, nothing else competing (replay_cost); --fits: a fit worker's time per job on
# the palm's and a fingertip's frames (fit_cost).

from __future__ import annotations

import argparse
import contextlib
import os
import re
from collections import Counter
from collections.abc import Iterable, Iterator
from typing import Any

from tactiled_bench.checkout import run_at

#: Stage -> substrings of a stack frame ``function (file)`` that put a sample in it; matched
#: from the innermost frame outwards, so the first stage met wins.
STAGES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("detector", ("ContactDetector.", "calibration/detection.py", "stage_kernel")),
    ("calibration stage", ("CalibrationStage.", "Zeroer.", "Hysteresis", "LookupTable.",
                           "Segments.", "calibration/")),
    ("tracker step", ("Tracker.step", "Tracker._", "ContactTracking.track",
                      "ContactTracking.follow_drift")),
    ("estimate building", ("make_estimate", "Tracker.estimate", "SensorPipeline._publish",
                           "SensorPipeline._frame_peak", "pipeline/estimate.py")),
    ("hub fan-out and JSON", ("Hub.publish", "pipeline/hub.py", "tactiled_service/", "json")),
    ("decoding and reading", ("FrameDecoder", "tactiled/frames.py", "tactiled/sources.py",
                              "tactiled_drivers/", "serial/")),
    ("fit dispatch (pool IPC)", ("pipeline/pool.py", "pipeline/supervision.py",
                                 "multiprocessing/")),
    ("pipeline, other", ("pipeline/sensor.py", "pipeline/sensor_tracking.py",
                         "pipeline/meters.py")),
    ("bench listener", ("tactiled_bench/acquisition.py:listen", "listen (tactiled_bench")),
    ("garbage collection", ("tactiled/heap.py", "gc_")),
    ("event loop", ("asyncio/", "selectors.py")),
)
OTHER = "other"
#: Innermost frames of a thread asleep in a system call, which py-spy's sampler counted as
#: running: left out (the CPU time they would stand for is not the process's).
WAITING = ("Condition.wait (", "PortReader._wait (",
           "EpollSelector.select (", "_PollLikeSelector.select (")
_LINE = re.compile(r":\d+\)")


def main_process_stacks(lines: Iterable[str]) -> Iterable[tuple[list[str], int]]:
    """(frames outermost first, samples) of the daemon's main process in a raw py-spy
    profile of ``tactiled bench --suite acquisition`` (or of the daemon alone: stacks of one
    process), leaving out numba compilation (a baseline revision's cold kernel cache) and the bench's own start."""
    for line in lines:
        line = line.rstrip()
        if not line or " " not in line:
            continue
        stack, count = line.rsplit(" ", 1)
        frames = stack.split(";")
        procs = [i for i, f in enumerate(frames) if f.startswith("process ")]
        # bench -> harness (run_baseline.py: the daemon's process) -> workers, simulators
        if procs and "run_baseline" in "".join(frames[p] for p in procs[1:2]):
            if len(procs) > 2:
                continue  # a worker's or a simulator's
            frames = frames[procs[1] + 1:]
        elif procs:
            if len(procs) > 1 or " bench " in frames[0]:
                continue  # the bench's own process, or a child of a lone daemon
            frames = frames[1:]
        # the daemon at work: its loop (under the bench's measure) or a reader thread
        text = ";".join(frames)
        if "numba/core" in text or not ("measure (" in text or "threading.py" in text
                                         or "Daemon" in text or "asyncio" in text):
            continue
        yield [_LINE.sub(")", f) for f in frames], int(count)


def stage_of(frames: list[str]) -> str:
    """The stage of one stack: the first of :data:`STAGES` met from the innermost frame."""
    for f in reversed(frames):
        for stage, keys in STAGES:
            if any(k in f for k in keys):
                return stage
    return OTHER


def breakdown(lines: Iterable[str]) -> tuple[Counter, int]:
    """(samples per stage, total samples) of the main process."""
    per: Counter = Counter()
    total = 0
    for frames, n in main_process_stacks(lines):
        if frames and frames[-1].startswith(WAITING):
            continue
        per[stage_of(frames)] += n
        total += n
    return per, total


def table(per: Counter, total: int, cpu_share: float | None = None,
          frames_per_s: float | None = None) -> str:
    """A Markdown table of the breakdown (with us per frame when both figures are given)."""
    us = cpu_share is not None and frames_per_s
    head = "| stage | share of the main process's CPU |" + (" us per frame |" if us else "")
    lines = [head, "|---|---|" + ("---|" if us else "")]
    for stage, n in per.most_common():
        row = f"| {stage} | {100.0 * n / total:.1f} % |"
        if us:
            row += f" {1e6 * cpu_share * n / total / frames_per_s:.1f} |"
        lines.append(row)
    if us:
        lines.append(f"| total | 100 % | {1e6 * cpu_share / frames_per_s:.1f} |")
    return "\n".join(lines)


def stage_cost(description: str, scene: str, compiled: bool, frames: int = 300,
               repeats: int = 6) -> float:
    """Microseconds a frame of the calibration stage (table, zeroing, hysteresis, detector as
    the daemon sets them up: the daemon's default detector averaging, hysteresis compensated)
    on ``scene``'s frames of the array ``description``, on the compiled path or the reference
    path: the best of ``repeats`` runs of ``frames`` frames, after 300 frames of warm-up."""
    import time

    from tactiled.calibration.detection import ContactDetector
    from tactiled.calibration.lut import LookupTable
    from tactiled.calibration.stage import CalibrationStage
    from tactiled.calibration.zeroing import Zeroer
    from tactiled.sensors.finger import COUNTS_PER_STRAIN, ZERO_STRAIN_COUNTS
    from tactiled.frames import Frame
    from tactiled.sensors import load_description
    from tactiled.settings import SensorSettings
    from tactiled.sim import FingerSimulator

    sensor = load_description(description).sensor_model()
    g = sensor.geometry
    detector = ContactDetector(sensor=sensor, average=SensorSettings().detector_average)
    zeroer = Zeroer((g.rows, g.cols), detector=detector)
    zeroer.hysteresis.set(0.05, 0.5)
    stage = CalibrationStage(LookupTable.linear(g.rows, g.cols, COUNTS_PER_STRAIN,
                                                ZERO_STRAIN_COUNTS), zeroer)
    stage.compiled = compiled
    sim = FingerSimulator(sensor, scene, seed=1)
    sim.skip(round(0.8 * sim.rate_hz))  # into the contacts
    ticks = [sim.step() for _ in range(300 + frames * repeats)]
    batch = [Frame(seq=t.seq, device_time_us=t.device_time_us, raw=t.counts) for t in ticks]
    for f in batch[:300]:
        stage.process(f)
    best = float("inf")
    for r in range(repeats):
        part = batch[300 + r * frames:300 + (r + 1) * frames]
        t0 = time.perf_counter()
        for f in part:
            stage.process(f)
        best = min(best, (time.perf_counter() - t0) / frames)
    return 1e6 * best


#: The hand's parts as :func:`replay_cost` plays them: (sensor name, scene, description).
HAND_PARTS = (("palm", "hand-palm", "flat16"),
              *((f"finger{i}", f"hand-finger{i}", "fearing1988") for i in range(1, 6)))


def replay_cost(parts: tuple[tuple[str, str, str], ...] = HAND_PARTS, frames: int = 4000,
                workers: int = 2, passes: int = 2, batched: bool | None = None,
                profile: str | None = None, read_only: bool = False) -> list[dict[str, Any]]:
    """The main process's CPU per frame with nothing else competing: each part's ``frames``
    frames (its scene from the start, seed 1, at 1 kHz) recorded, then replayed as fast as
    the daemon takes them, every part at once, lossless (each frame waits for what it
    needs, so every run does the same work), fitted by ``workers`` worker processes.  The
    CPU time of this process (the daemon's event loop; replay has no read thread) divided by
    the frames: unlike the live bench, no device competes for the CPU and no frame is
    answered late, so two versions of the code compare to a few percent.  One dict per
    pass (the first loads what the kernels cache): ``us_per_frame``, ``frames``,
    ``relinearized`` and ``fits`` per part.  ``batched``: False runs every frame through the
    pipeline's per-frame path instead of the core's runs (``SensorPipeline.batched``).
    ``profile``: a file that gets the last pass's cProfile statistics (this process's CPU
    clock, the replay alone: ``python -m pstats FILE``); a profiled pass costs more, so its
    ``us_per_frame`` is no measure of the code.  ``read_only``: each read's frames are read,
    decoded and stamped, then only counted (``SensorPipeline.on_frames`` replaced): what the
    loop, the source and the decoder cost a frame without the pipeline."""
    import asyncio
    import cProfile
    import tempfile
    import time
    from pathlib import Path

    from tactiled.pipeline import Daemon
    from tactiled.pipeline.sensor import SensorPipeline
    try:
        from tactiled.io.recording import Recorder
    except ImportError:  # a revision from before tactiled.io held it
        from tactiled.recording import Recorder  # type: ignore[no-redef]
    from tactiled.sensors import load_description
    from tactiled.settings import load_settings
    from tactiled.sim import FingerSimulator

    async def play(paths: dict[str, Path], prof: Any = None) -> dict[str, Any]:
        over: dict[str, Any] = {"fit.workers": workers}
        for i, (name, _scene, description) in enumerate(parts):
            over[f"sensor[{i}].url"] = f"replay://{paths[name]}?speed=0"
            over[f"sensor[{i}].name"] = name
            over[f"sensor[{i}].description"] = description
        daemon = Daemon(load_settings(None, {}, over), lossless=True)
        await daemon.start()
        try:
            cpu = time.process_time()
            if prof is not None:
                prof.enable()
            await daemon.wait_finished(600)
            if prof is not None:
                prof.disable()
            cpu = time.process_time() - cpu
        finally:
            await daemon.stop()
        pipes = daemon.sensors
        total = sum(p.frames for p in pipes.values())
        return {"us_per_frame": 1e6 * cpu / max(total, 1), "frames": total,
                # (a revision from before SensorPipeline.tracking counts on the pipeline)
                "relinearized": {n: getattr(p, "tracking", p).relinearized
                                 for n, p in pipes.items()},
                "fits": {n: p.fitted for n, p in pipes.items()}}

    with tempfile.TemporaryDirectory(prefix="tactiled-budget-") as d:
        paths = {}
        for name, scene, description in parts:
            sim = FingerSimulator(load_description(description).sensor_model(), scene, seed=1)
            paths[name] = Path(d) / f"{name}.tact"
            rec = Recorder(paths[name])
            for k in range(frames):
                rec.record(sim.next_frame(), host_time=1.0 + k / sim.rate_hz)
            rec.close()
        # (a revision from before the core's runs has no SensorPipeline.batched)
        was = getattr(SensorPipeline, "batched", False)
        if batched is not None and hasattr(SensorPipeline, "batched"):
            SensorPipeline.batched = batched and was
        on_frames = SensorPipeline.on_frames
        if read_only:
            def counted(pipe: Any, frames: Any, start: int = 0, *_a: Any, **_k: Any) -> int:
                pipe.frames += len(frames) - start
                return len(frames)

            SensorPipeline.on_frames = counted  # type: ignore[method-assign]
        try:
            runs = [asyncio.run(play(paths)) for _ in range(passes - (profile is not None))]
            if profile is not None:
                prof = cProfile.Profile(time.process_time)
                runs.append(asyncio.run(play(paths, prof)))
                prof.dump_stats(profile)
            return runs
        finally:
            SensorPipeline.on_frames = on_frames  # type: ignore[method-assign]
            if hasattr(SensorPipeline, "batched"):
                SensorPipeline.batched = was


def estimate_cost(parts: tuple[tuple[str, str, str], ...] = HAND_PARTS, frames: int = 4000,
                  every: int = 53, repeats: int = 200,
                  profile: str | None = None) -> dict[str, Any]:
    """A tracked contact frame's estimate alone, from the core's numbers to the ``Estimate``
    record handed to ``SensorPipeline._send``: microseconds of this process's CPU per call of
    ``TrackedRun._publish_one`` (the zeroed frame handed to the hub, the trackers' frame
    counts, the tracker's estimate, the contacts' ids, the verdict, the record), ``Hub.publish``
    and ``_send`` left out (``Hub.publish_frame``, where the code has it, kept: with nobody
    taking frames, it keeps the frame's fields).  The hand replayed lossless as :func:`replay_cost` plays it (one pass); every
    ``every``-th tracked frame's call is repeated ``repeats`` times on the spot, on the
    pipeline's state then (what the repeats change is put back), and timed as one.  Per part:
    ``median_us``, ``p90_us`` and ``samples``; ``all``: the median over every part's samples
    (the palm's several contacts weigh as often as they are tracked).  ``profile``: instead,
    a file that gets the cProfile statistics of every call, once each (this process's CPU
    clock; ``calls`` in the answer: :func:`functions_per_frame`'s ``frames``)."""
    import copy
    import cProfile
    import time

    from tactiled.pipeline import tracked_run

    run = tracked_run.TrackedRun
    original = run._publish_one
    seen = [0]
    samples: dict[str, list[float]] = {}

    prof = None if profile is None else cProfile.Profile(time.process_time)

    def timed(self: Any, pipe: Any, w: Any, statistic: float, numbers: Any) -> Any:
        seen[0] += 1
        if prof is not None:
            prof.enable()
            try:
                return original(self, pipe, w, statistic, numbers)
            finally:
                prof.disable()
        if seen[0] % every == 0:
            trackers = pipe.tracking.tracker.trackers
            kept = ([(tr.t, tr.n, tr._eframes, tr._edt) for tr in trackers], pipe._ordinal,
                    dict(pipe.skipped), copy.deepcopy(pipe.ids.__dict__), w.ordinal,
                    dict(pipe.hub.published))
            pipe._send = pipe.hub.publish = lambda *a: None  # (instance attributes: removed below)
            try:
                t0 = time.process_time()
                for _ in range(repeats):
                    original(self, pipe, w, statistic, numbers)
                cpu = time.process_time() - t0
            finally:
                del pipe._send, pipe.hub.publish
                for tr, (t, n, ef, edt) in zip(trackers, kept[0]):
                    tr.t, tr.n, tr._eframes, tr._edt = t, n, ef, edt
                pipe._ordinal, w.ordinal = kept[1], kept[4]
                pipe.skipped.clear()
                pipe.skipped.update(kept[2])
                pipe.ids.__dict__.update(kept[3])
                pipe.hub.published.update(kept[5])  # (Hub.publish_frame counts, where it is)
            samples.setdefault(pipe.name, []).append(1e6 * cpu / repeats)
        return original(self, pipe, w, statistic, numbers)

    run._publish_one = timed
    try:
        replay_cost(parts, frames, passes=1)
    finally:
        run._publish_one = original
    if prof is not None:
        prof.dump_stats(profile)
        return {"calls": seen[0]}

    def stats(v: list[float]) -> dict[str, Any]:
        v = sorted(v)
        return {"median_us": v[len(v) // 2], "p90_us": v[int(0.9 * (len(v) - 1))],
                "samples": len(v)}

    out = {name: stats(v) for name, v in samples.items() if v}
    out["all"] = stats([x for v in samples.values() for x in v])
    return out


def estimate_at(tree: str, parts: tuple[tuple[str, str, str], ...] = HAND_PARTS,
                profile: str | None = None) -> dict[str, Any]:
    """:func:`estimate_cost` on the code of checkout ``tree``."""
    import inspect

    return run_at(tree, estimate_cost, f"estimate_cost({parts!r}, profile={profile!r})",
                  (f"HAND_PARTS = {HAND_PARTS!r}", inspect.getsource(replay_cost)))


#: The arrays whose fits :func:`fit_cost` times: (description, scene), the palm's several
#: contacts and a fingertip's two.
FIT_PARTS = (("flat16", "hand-palm"), ("fearing1988", "hand-finger2"))


def fit_cost(description: str, scene: str, every: int = 20, frames: int = 1200,
             repeats: int = 2) -> dict[str, Any]:
    """A worker's time per fit job (``fit+lin``) on ``scene``'s frames of the array
    ``description`` with nothing else competing: every ``every``-th frame of ``frames`` from
    1 s into the scene (seed 1, its contacts held and moving) fitted as a worker fits a frame
    the tracker hands it (:func:`tactiled.fit.multi.fit_contacts`, model ``auto``, a warm
    start from the fit before, a 50 ms budget), then linearised (each contact's, as the
    worker does for the tracker).  The last of ``repeats`` passes counts (the first loads
    what the kernels cache).  ``fit_ms`` and ``lin_ms``: ``p50`` and ``p90``; ``jobs``."""
    import time

    from tactiled.fit.fitter import FitOptions, Fitter
    from tactiled.fit.multi import fit_contacts, warm_of
    from tactiled.pipeline.worker import _several_lin
    from tactiled.sensors import load_description
    from tactiled.sim import FingerSimulator

    desc = load_description(description)
    sensor = desc.sensor_model()
    fitter = Fitter(sensor, FitOptions(window=desc.window))
    sim = FingerSimulator(sensor, scene, seed=1)
    sim.skip(round(sim.rate_hz))
    strains = [sim.step().strain for _ in range(frames)][::every]
    fit_ms: list[float] = []
    lin_ms: list[float] = []
    for _ in range(repeats):
        fit_ms.clear()
        lin_ms.clear()
        warm = None
        for strain in strains:
            t0 = time.perf_counter()
            results = fit_contacts(fitter, strain, "auto", warm=warm, budget_s=0.05)
            t1 = time.perf_counter()
            _several_lin(fitter, strain, results, None)
            lin_ms.append(1e3 * (time.perf_counter() - t1))
            fit_ms.append(1e3 * (t1 - t0))
            warm = warm_of(results)

    def q(v: list[float], p: float) -> float:
        return sorted(v)[int(p * (len(v) - 1))]

    return {"jobs": len(fit_ms), "fit_ms": {"p50": q(fit_ms, 0.5), "p90": q(fit_ms, 0.9)},
            "lin_ms": {"p50": q(lin_ms, 0.5), "p90": q(lin_ms, 0.9)}}


def functions_per_frame(path: str, frames: int) -> dict[str, tuple[float, float, float]]:
    """A cProfile statistics file (:func:`replay_cost`'s ``profile``) per frame: by function
    (``package/module.py:name``, the path from the package's folder on), its calls, own
    time and cumulative time (us, the profiled process's CPU clock) over ``frames``."""
    import pstats

    out: dict[str, tuple[float, float, float]] = {}
    for (file, _line, name), (_cc, calls, own, cum, _callers) in pstats.Stats(path).stats.items():
        parts = file.replace("\\", "/").split("/")
        where = next((i for i in range(len(parts) - 1, -1, -1)
                      if parts[i].startswith("tactiled")), len(parts) - 1)
        key = f"{'/'.join(parts[where:])}:{name}"
        c, o, u = out.get(key, (0.0, 0.0, 0.0))
        out[key] = (c + calls / frames, o + 1e6 * own / frames, u + 1e6 * cum / frames)
    return out


def replay_at(tree: str, passes: int = 2, frames: int = 4000,
              parts: tuple[tuple[str, str, str], ...] = HAND_PARTS,
              profile: str | None = None) -> list[dict[str, Any]]:
    """:func:`replay_cost` on the code of checkout ``tree`` (its daemon and its workers)."""
    return run_at(tree, replay_cost, f"replay_cost({parts!r}, {frames!r}, passes={passes!r}, "
                   f"profile={profile!r})", (f"HAND_PARTS = {HAND_PARTS!r}",))


def fits_at(tree: str, description: str, scene: str) -> dict[str, Any]:
    """:func:`fit_cost` on the code of checkout ``tree``."""
    return run_at(tree, fit_cost, f"fit_cost({description!r}, {scene!r})")


def _pstats(a: argparse.Namespace, code: str, round_: int) -> str | None:
    """Where ``--cprofile``'s statistics of ``code``'s run in round ``round_`` go (None:
    no --cprofile)."""
    return None if a.cprofile is None else os.path.join(a.cprofile, f"{code}-{round_}.pstats")


def _profile_table(per: dict[str, dict[str, tuple[float, float, float]]], top: int = 25) -> None:
    """The functions that cost the most own time per frame in any of ``per``'s codes, side
    by side: calls, own and cumulative us per frame (profiled CPU clock)."""
    names = sorted({n for d in per.values() for n in d},
                   key=lambda n: -max(d.get(n, (0.0, 0.0, 0.0))[1] for d in per.values()))[:top]
    codes = list(per)
    print()
    print("| function | " + " | ".join(f"{c}: calls / own / cumulative us per frame"
                                        for c in codes) + " |")
    print("|---|" + "---|" * len(codes))
    for n in names:
        cells = [per[c].get(n) for c in codes]
        print(f"| {n} | " + " | ".join("-" if v is None else f"{v[0]:.2f} / {v[1]:.2f} / {v[2]:.1f}"
                                       for v in cells) + " |")


def _here() -> str:
    """This checkout's top directory."""
    from pathlib import Path

    return str(Path(__file__).resolve().parents[2])


@contextlib.contextmanager
def _baseline_tree(rev: str | None) -> Iterator[str | None]:
    """A temporary checkout of git revision ``rev`` (None: no baseline, None)."""
    if rev is None:
        yield None
        return
    import tempfile

    from tactiled_bench.checkout import checkout

    with tempfile.TemporaryDirectory(prefix="tactiled-budget-base-") as tmp:
        yield checkout(rev, tmp)


def _cli() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("profile", nargs="?", help="py-spy record --format raw output")
    p.add_argument("--cpu-share", type=float, default=None,
                   help="the main process's CPU over the window, in cores (e.g. 0.46)")
    p.add_argument("--frames-per-s", type=float, default=None, help="frames handled per second")
    p.add_argument("--stage", action="store_true",
                   help="instead: time the calibration stage per frame, compiled and reference "
                        "paths, on the hand's palm and a fingertip")
    p.add_argument("--replay", action="store_true",
                   help="instead: the main process's CPU per frame on the hand's six parts "
                        "replayed lossless, nothing else competing (replay_cost)")
    p.add_argument("--fits", action="store_true",
                   help="instead: a worker's time per fit job (the fit, then its "
                        "linearisation) on the palm's and a fingertip's frames (fit_cost)")
    p.add_argument("--estimate", action="store_true",
                   help="instead: a tracked contact frame's estimate alone, us of CPU per "
                        "estimate, the hand replayed lossless (estimate_cost)")
    p.add_argument("--baseline", metavar="REV", default=None,
                   help="with --replay, --fits or --estimate: also the code of git revision "
                        "REV, in turn with this tree's (two rounds)")
    p.add_argument("--per-frame", action="store_true",
                   help="with --replay: this tree's runs through the core and its per-frame "
                        "path, in turn (two rounds)")
    p.add_argument("--empty", metavar="DESCRIPTION", nargs="+", default=None,
                   help="with --replay: instead of the hand, one array of each DESCRIPTION alone "
                        "on a scene that never touches it (three passes each): a frame with no "
                        "contact")
    p.add_argument("--cprofile", metavar="DIR", default=None,
                   help="with --replay: a third pass of each run under cProfile, its statistics "
                        "into DIR (<code>-<round>.pstats), and the functions that cost the most "
                        "per frame (own time, profiled CPU) in the last round")
    a = p.parse_args()
    if a.cprofile is not None and (not a.replay or a.per_frame):
        p.error("--cprofile goes with --replay, without --per-frame")
    if a.empty is not None and (not a.replay or a.per_frame or a.cprofile):
        p.error("--empty goes with --replay, without --per-frame or --cprofile")
    if a.per_frame and (not a.replay or a.baseline is not None):
        p.error("--per-frame goes with --replay, without --baseline")
    if a.baseline is not None and not (a.replay or a.fits or a.estimate):
        p.error("--baseline goes with --replay, --fits or --estimate")
    if a.estimate:
        print("| code | part | tracked estimates timed | us of CPU per estimate: median / p90 |")
        print("|---|---|---|---|")
        with _baseline_tree(a.baseline) as tree:
            codes = [("this tree", _here())]
            if tree is not None:
                codes = [*codes, (f"baseline {a.baseline}", tree)] * 2
            for code, where in codes:
                for part, r in estimate_at(where).items():
                    print(f"| {code} | {part} | {r['samples']} | {r['median_us']:.1f} / "
                          f"{r['p90_us']:.1f} |")
        return
    if a.fits:
        print("| code | array | scene | fit jobs | fit, ms p50 / p90 | linearisation, ms p50 / p90 |")
        print("|---|---|---|---|---|---|")
        codes: list[tuple[str, str]] = [("this tree", _here())]
        with _baseline_tree(a.baseline) as tree:
            if tree is not None:
                codes = [*codes, (f"baseline {a.baseline}", tree)] * 2
            for code, where in codes:
                for description, scene in FIT_PARTS:
                    r = fits_at(where, description, scene)
                    print(f"| {code} | {description} | {scene} | {r['jobs']} | "
                          f"{r['fit_ms']['p50']:.2f} / {r['fit_ms']['p90']:.2f} | "
                          f"{r['lin_ms']['p50']:.2f} / {r['lin_ms']['p90']:.2f} |")
        return
    if a.replay:
        print("| code | pass | frames | main process CPU per frame, us | relinearisations | fits |")
        print("|---|---|---|---|---|---|")
        rows: list[tuple[str, list[dict[str, Any]]]] = []
        with _baseline_tree(a.baseline) as tree:
            if a.per_frame:
                for _ in range(2):
                    rows.append(("this tree, runs", replay_cost(batched=True)))
                    rows.append(("this tree, per frame", replay_cost(batched=False)))
            elif a.empty is not None:
                for _ in range(1 if tree is None else 2):
                    for desc in a.empty:
                        part = (("one", "empty", desc),)
                        rows.append((f"this tree, {desc}", replay_at(_here(), 3, parts=part)))
                        if tree is not None:
                            rows.append((f"baseline {a.baseline}, {desc}",
                                         replay_at(tree, 3, parts=part)))
            elif tree is None:
                rows.append(("this tree", replay_cost(passes=3, profile=_pstats(a, "this", 1))
                             if a.cprofile else replay_cost()))
            else:
                for k in (1, 2):
                    rows.append(("this tree", replay_at(_here(), passes=2 + bool(a.cprofile),
                                                        profile=_pstats(a, "this", k))))
                    rows.append((f"baseline {a.baseline}",
                                 replay_at(tree, passes=2 + bool(a.cprofile),
                                           profile=_pstats(a, "baseline", k))))
        for code, runs in rows:
            for i, r in enumerate(runs, 1):
                print(f"| {code} | {i} | {r['frames']} | {r['us_per_frame']:.1f} | "
                      f"{sum(r['relinearized'].values())} | {sum(r['fits'].values())} |")
        if a.cprofile:
            last = 1 if a.baseline is None else 2
            frames = rows[-1][1][-1]["frames"]
            codes = [c for c in ("this", "baseline") if os.path.exists(_pstats(a, c, last))]
            _profile_table({c: functions_per_frame(_pstats(a, c, last), frames) for c in codes})
        return
    if a.stage:
        print("| array | scene | compiled path, us per frame | reference path, us per frame |")
        print("|---|---|---|---|")
        for description, scene in (("fearing1988", "hand-finger2"), ("flat16", "hand-palm")):
            print(f"| {description} | {scene} | {stage_cost(description, scene, True):.1f} | "
                  f"{stage_cost(description, scene, False):.1f} |")
        return
    if a.profile is None:
        p.error("give a profile, or --stage, --replay or --fits")
    with open(a.profile, encoding="utf-8") as fh:
        per, total = breakdown(fh)
    print(table(per, total, a.cpu_share, a.frames_per_s))


if __name__ == "__main__":
    _cli()

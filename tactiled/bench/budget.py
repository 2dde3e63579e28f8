"""Where the daemon's main process spends its CPU per frame: a py-spy profile, by stage.

Record a running acquisition bench with py-spy (``--format raw``: one collapsed stack per
line, its sample count last) and split the samples of the daemon's main process (the event
loop and the serial reader threads, not its fit workers nor the simulators) by pipeline stage::

    py-spy record --subprocesses --nonblocking --format raw -r 250 -o prof.txt -- \\
        tactiled bench --suite acquisition --scene hand --seconds 15 --sim-nice 10
    python -m tactiled.bench.budget prof.txt --frames-per-s 6000 --cpu-share 0.46

A sample belongs to the innermost stage its stack passes through (the detector inside the
calibration stage counts as the detector).  With ``--cpu-share`` (the main process's CPU in
cores over the window, as the bench's table gives it) and ``--frames-per-s`` the shares become
microseconds per frame.
"""

from __future__ import annotations

import argparse
import re
from collections import Counter
from collections.abc import Iterable

#: Stage -> substrings of a stack frame ``function (file)`` that put a sample in it; matched
#: from the innermost frame outwards, so the first stage met wins.
STAGES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("detector", ("ContactDetector.", "calibration/contact.py", "stage_kernel")),
    ("calibration stage", ("CalibrationStage.", "Zeroer.", "Hysteresis", "LookupTable.",
                           "Segments.", "calibration/")),
    ("tracker step", ("Tracker.step", "Tracker._", "SensorPipeline._track",
                      "SensorPipeline._follow_drift")),
    ("estimate building", ("make_estimate", "Tracker.estimate", "SensorPipeline._publish",
                           "SensorPipeline._frame_peak", "pipeline/estimate.py")),
    ("hub fan-out and JSON", ("Hub.publish", "pipeline/hub.py", "tactiled_service/", "json")),
    ("decoding and reading", ("FrameDecoder", "tactiled/frames.py", "tactiled/sources.py",
                              "tactiled_drivers/", "serial/")),
    ("fit dispatch (pool IPC)", ("pipeline/pool.py", "multiprocessing/")),
    ("pipeline, other", ("pipeline/sensor.py", "pipeline/meters.py")),
    ("bench listener", ("bench/acquisition.py:listen", "listen (tactiled/bench")),
    ("garbage collection", ("tactiled/heap.py", "gc_")),
    ("event loop", ("asyncio/", "selectors.py")),
)
OTHER = "other"
#: Innermost frames of a thread asleep in a system call, which py-spy's sampler counted as
#: running: left out (the CPU time they would stand for is not the process's).
WAITING = ("PortReader._wait (", "EpollSelector.select (", "_PollLikeSelector.select (")
_LINE = re.compile(r":\d+\)")


def main_process_stacks(lines: Iterable[str]) -> Iterable[tuple[list[str], int]]:
    """(frames outermost first, samples) of the daemon's main process in a raw py-spy
    profile of ``tactiled bench --suite acquisition`` (or of the daemon alone: stacks of one
    process), leaving out numba compilation (a cold kernel cache) and the bench's own start."""
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


def _cli() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("profile", help="py-spy record --format raw output")
    p.add_argument("--cpu-share", type=float, default=None,
                   help="the main process's CPU over the window, in cores (e.g. 0.46)")
    p.add_argument("--frames-per-s", type=float, default=None, help="frames handled per second")
    a = p.parse_args()
    with open(a.profile, encoding="utf-8") as fh:
        per, total = breakdown(fh)
    print(table(per, total, a.cpu_share, a.frames_per_s))


if __name__ == "__main__":
    _cli()

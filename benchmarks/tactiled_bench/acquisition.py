"""Acquisition under load: simulated fingers at 1 kHz over real pseudo-terminals.

Each finger is a ``tactiled simulate --pty`` process; the daemon reads it with pyserial and
decodes, linearises, zeroes, gates and fits exactly as it would a device.  Measured: frames lost
or rejected (the bar: none), every frame accounted for, the fit rate, latency from frame
arrival to published estimate, and, on moving contacts, the share of frames answered by their
own fit or a justified gate reuse, and accuracy against the scene's truth.
"""
# The daemon reads serial:// on a stable symlink, under the serving process's heap policy
# (tactiled.heap.serving, as tactiled run does), and what the run keeps of each estimate is flat,
# so the collector's work is the daemon's own.
# --scene moving asks whether every contact frame gets an answer of its own: its own fit, or a
# gate reuse the chi-square test justifies (the frame is the fitted one within noise), rather
# than being superseded while a fit runs.  Each run (one per worker count of the sweep) reports
# those shares, latency, and the streamed estimates' accuracy, matched by seq: the simulator's
# frame seq is its tick index, so the truth of any frame is
# scene.contact_at((seq mod ticks per pass) / rate), recomputed without talking to the simulator.

from __future__ import annotations

import asyncio
import gc
import math
import os
import pickle
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from tactiled import heap
from tactiled.physics.contact import Contact
from tactiled.pipeline import Daemon
from tactiled.settings import load_settings
from tactiled.sensors import DEFAULT_NAME
from tactiled_bench.acquisition_runs import (FINGERS, HAND, Device, RunResult, Seen, contacts_of,
                                             devices, scene_truth, slim, tare_window, timeline)
from tactiled_bench.acquisition_report import conditions, figures, report
from tactiled_bench.checkout import build, checkout, checkout_env


#: The simulators' command line, as /proc shows it (NUL-separated): how
#: :func:`renice_simulators` finds those a baseline checkout's own harness started.
_SIMULATE = b"tactiled.cli\x00simulate\x00--pty"


def _start_simulators(tmp: Path, rate: float, scene: str) -> list[subprocess.Popen]:
    procs = []
    for i, dev in enumerate(devices(scene)):
        link = tmp / f"tty{i}"
        sensor = [] if dev.description == DEFAULT_NAME else ["--sensor", dev.description]
        p = subprocess.Popen(
            [sys.executable, "-m", "tactiled.cli", "simulate", "--pty", "--link", str(link),
             "--scene", dev.scene, *sensor, "--rate", str(rate), "--sensor-id", str(i + 1),
             "--seed", str(i + 1)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(p)
    deadline = time.monotonic() + 60
    for i, p in enumerate(procs):
        line = p.stdout.readline() if p.stdout else ""
        if not line.startswith("pty:"):
            raise RuntimeError(f"simulator {i} did not start: {line!r} {p.stderr.read() if p.stderr else ''}")
        while not (tmp / f"tty{i}").exists() and time.monotonic() < deadline:
            time.sleep(0.01)
    return procs


_SUMMARY = re.compile(r"sent (\d+) frame\(s\), dropped (\d+) \(device full\), skipped (\d+)")


def renice_simulators(root: int, nice: int) -> int:
    """Set the scheduling niceness of every simulator descended from process ``root`` (not
    ``root`` itself; Linux /proc) to ``nice``; returns how many were changed."""
    parents: dict[int, int] = {}
    sims = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", "rb") as f:
                parents[int(entry)] = int(f.read().rsplit(b")", 1)[1].split()[1])
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                if _SIMULATE in f.read():
                    sims.append(int(entry))
        except (OSError, ValueError, IndexError):
            continue  # gone meanwhile
    changed = 0
    for pid in sims:
        p = parents.get(pid, 1)
        while p > 1 and p != root:
            p = parents.get(p, 1)
        if p == root:
            try:
                if os.getpriority(os.PRIO_PROCESS, pid) != nice:
                    os.setpriority(os.PRIO_PROCESS, pid, nice)
                    changed += 1
            except OSError:
                pass
    return changed


def _stop(procs: list[subprocess.Popen]) -> list[tuple[int, int, int] | None]:
    """Stop the simulators; each one's own count of (sent, dropped, skipped) frames: frames it
    generated but never wrote, because the pty was full or it fell behind schedule on a
    starved CPU, leave gaps the daemon's decoder counts as lost without acquisition at fault."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    out = []
    for p in procs:
        try:
            _, err = p.communicate(timeout=5)
        except subprocess.TimeoutExpired:
            p.kill()
            _, err = p.communicate()
        m = _SUMMARY.search(err or "")
        out.append(tuple(int(g) for g in m.groups()) if m else None)
    return out


def _cpu_seconds(pid: int | None) -> float | None:
    """User + system CPU seconds of process ``pid`` so far (Linux ``/proc``), or None."""
    if pid is None:
        return None
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime


# --------------------------------------------------------------------------------------------
# Running


class _Tarer:
    """Tares each sensor early in the scene's idle, and again at the next idle if the zeroer's
    baseline did not form on untouched frames only (a simulator starved on a busy machine skips
    frames: the frame after the tare, or one during the 0.25 s the baseline settles over, may
    then be one of the next contact)."""

    def __init__(self, daemon: Daemon, window: tuple[int, int], per_pass: int, rate: float,
                 truth: Callable[[int], Contact | None], sensors: int = len(FINGERS)) -> None:
        self.daemon, self.window, self.per_pass, self.truth = daemon, window, per_pass, truth
        self.sensors = sensors
        self.settle = math.ceil(0.3 * rate)  # ticks: the zeroer's 0.25 s and a margin
        self.state: dict[str, tuple[str, int]] = {}  # sensor -> ("settling", first seq) | ("ok", 0)
        self.tares = 0

    def done(self) -> bool:
        return len(self.state) == self.sensors and all(st == "ok" for st, _ in self.state.values())

    def frame(self, sensor: str, seq: int) -> None:
        st, first = self.state.get(sensor, ("waiting", 0))
        if st == "ok":
            return
        if st == "settling":
            if first < 0:  # this is the frame the baseline restarts from
                first = seq
                self.state[sensor] = (st, first)
            if self.truth(seq) is not None:  # a contact went into the baseline: again
                self.state[sensor] = ("waiting", 0)
            elif seq - first > self.settle:
                self.state[sensor] = ("ok", 0)
            return
        lo, hi = self.window
        if lo <= seq % self.per_pass < hi:
            # Synchronously, from the hub's listener, before the pipeline reads on: the
            # baseline restarts from the very next frame.
            self.daemon.tare(sensor)
            self.tares += 1
            self.state[sensor] = ("settling", -1)


async def _run(tmp: Path, seconds: float, warmup: float, workers: int, sim_pids: list[int],
               tare: tuple[tuple[int, int], int, float, float, Callable[[int], Contact | None]] | None,
               track: bool = True, parts: Sequence[Device] | None = None) -> RunResult:
    """``tare``: ``(window, ticks per pass, rate, seconds per pass, truth)``: tare each sensor
    in ``window`` of the pass (see :func:`tare_window` and :class:`_Tarer`).  ``parts``: the
    devices on ``tmp``'s ttys, in order (default the three fingers)."""
    parts = tuple(parts) if parts is not None else devices("demo")
    # what the daemon learns (hysteresis, flat fields) in the run's own directory: a run
    # starts from nothing learned, whatever earlier runs left in the user's state
    overrides: dict[str, object] = {"fit.workers": workers, "state.dir": str(tmp / "state")}
    for i, dev in enumerate(parts):
        overrides[f"sensor[{i}].name"] = dev.name
        overrides[f"sensor[{i}].url"] = f"serial://{tmp / f'tty{i}'}"
        overrides[f"sensor[{i}].wire_id"] = i + 1
        overrides[f"sensor[{i}].track"] = track
        if dev.description != DEFAULT_NAME:
            overrides[f"sensor[{i}].description"] = dev.description
    daemon = Daemon(load_settings(None, {}, overrides))
    index = {dev.name: i for i, dev in enumerate(parts)}
    seen: list[tuple[Any, ...]] = []
    counting = False
    # A hand starts with its fingers free: the daemon opened the ports at some arbitrary moment
    # of the scene, so each sensor is re-zeroed once nothing touches.
    tarer = None if tare is None else _Tarer(daemon, tare[0], tare[1], tare[2], tare[4], len(parts))

    def listen(item: Any) -> None:
        # In the pipeline's loop for every item: keep it to an append (or a few comparisons).
        kind = getattr(item, "kind", None)
        if counting and kind == "estimate":
            # a plain tuple (made a Seen after the run): the collector stops tracking it
            seen.append((index[item.sensor], item.seq, item.gate, item.latency_ms, slim(item.fit),
                         contacts_of(item)))
        elif kind == "frame" and tarer is not None:
            tarer.frame(item.sensor, item.seq)

    def total(pids: list[int]) -> float | None:
        per = [_cpu_seconds(p) for p in pids]
        return None if not per or None in per else sum(per)  # type: ignore[arg-type]

    def cpu() -> dict[str, float | None]:
        return {"daemon": time.process_time(),  # this process: the loop and the serial read thread
                "workers": total([p for p in daemon.pool.pids() if p is not None]),
                "simulators": total(sim_pids)}

    collections: list[float] = []
    gc_began = [0.0]

    def collected(phase: str, _info: dict[str, Any]) -> None:
        # in whichever thread collects; a float appended, nothing the collector tracks
        if phase == "start":
            gc_began[0] = time.perf_counter()
        elif counting:
            collections.append(time.perf_counter() - gc_began[0])

    daemon.hub.add_listener(listen)
    gc.callbacks.append(collected)
    await daemon.start()
    # The heap policy of the process that serves (tactiled run): the start-up heap frozen, a
    # full collection every few seconds.  Without it, CPython's own full collections walked
    # every object start-up left, stalling the loop up to 69 ms each.
    gc_task = heap.serving()
    try:
        started = time.monotonic()
        if tarer is not None:
            deadline = started + warmup + 4.0 * tare[3] + 5.0  # a few passes: a tare may fail
            while not tarer.done() and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
            if not tarer.done():
                raise RuntimeError(f"could not tare every sensor on untouched frames: {tarer.state}")
            # the baseline settles (0.25 s), then at least a second of fits before measuring
            await asyncio.sleep(max(warmup - (time.monotonic() - started), 1.5))
        else:
            await asyncio.sleep(warmup)
        before = daemon.stats()
        cpu0 = cpu()
        counting = True
        t0 = time.monotonic()
        windows = await _cpu_windows(daemon, seconds)
        counting = False
        after = daemon.stats()
        cpu1 = cpu()
        elapsed = time.monotonic() - t0
    finally:
        gc.callbacks.remove(collected)
        gc_task.cancel()
        await asyncio.gather(gc_task, return_exceptions=True)
        await daemon.stop()
    used = {k: (None if cpu0[k] is None or cpu1[k] is None else cpu1[k] - cpu0[k])  # type: ignore[operator]
            for k in cpu0}
    return RunResult(workers, before, after, elapsed,
                     [Seen.from_record(s) for s in seen], used,
                     tares=0 if tarer is None else tarer.tares,
                     parts=tuple(dev.name for dev in parts), windows=windows, gc_s=collections)


async def _cpu_windows(daemon: Daemon, seconds: float, step: float = 1.0) -> list[tuple[float, float, int]]:
    """Sleep ``seconds``, noting every ``step`` s the daemon's main process's CPU (this
    process: its loop and the serial read thread; not its fit workers) and the frames its
    sensors handled: ``(seconds, CPU seconds, frames)`` per window."""
    out = []
    end = time.monotonic() + seconds

    def sample() -> tuple[float, float, int]:
        return (time.monotonic(), time.process_time(),
                sum(p.frames for p in daemon.sensors.values()))

    last = sample()
    while (left := end - time.monotonic()) > 0:
        await asyncio.sleep(min(step, left))
        now = sample()
        out.append((now[0] - last[0], now[1] - last[1], now[2] - last[2]))
        last = now
    return out


def measure(seconds: float, warmup: float, rate: float, scene: str, workers: int,
            track: bool = True) -> RunResult:
    """One run: three simulators on ptys, a daemon with ``workers`` fit workers (and the
    sensors' ``track`` setting), ``seconds`` measured after ``warmup``."""
    with tempfile.TemporaryDirectory(prefix="tactiled-acq-") as d:
        tmp = Path(d)
        procs = _start_simulators(tmp, rate, scene)
        try:
            window = tare_window(scene, rate)
            duration = timeline(scene).duration
            per_pass = max(1, round(duration * rate))
            tare = None if window is None else (window, per_pass, rate, duration, scene_truth(scene, rate))
            result = asyncio.run(_run(tmp, seconds, warmup, workers, [p.pid for p in procs], tare,
                                      track, devices(scene)))
        finally:
            device = _stop(procs)
    result.device = device
    return result


#: Run in a checkout before its daemon starts: one fit of each model and a linearisation, so
#: a baseline revision whose kernels are numba's (before the compiled core held them; such a
#: run needs numba installed) compiles them into the checkout's own cache (a fresh one has
#: none, and a worker compiling them on its first fit, ~20 s, would be killed as hung again and
#: again); for a revision with the whole core it only warms the page cache.
#: Plain code, not a function of this tree: the checkout's own modules run it.
COMPILE_KERNELS = """
import math
import numpy as np
try:
    from tactiled.sensors.model import SensorModel
except ImportError:  # a revision from before tactiled.sensors held it
    from tactiled.config import SensorModel
from tactiled.fit.fitter import Fitter
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
sensor = SensorModel()
frame = StrainModel(sensor).predict(Contact(10.0, math.inf, 60.0, 1.0, 11.0, 13.0))
fitter = Fitter(sensor)
for model in ("cylinder", "sphere", "general", "auto"):
    fitter.fit(frame + np.random.default_rng(1).normal(0.0, 5e-4, frame.shape), model)
try:
    from tactiled.fit.linearize import linearize
except ImportError:  # a revision from before the tracker
    linearize = None
if linearize is not None:
    res = fitter.fit(frame, "cylinder")
    linearize(fitter, frame, res.model, np.asarray(res.params))
# a flat array's kernels (the hand's palm): its fitter's warm-up fits a line and a sphere
try:
    from tactiled.sensors import load_description
    flat = load_description("flat16").sensor_model()
except (ImportError, ValueError, KeyError):  # a revision without sensor descriptions
    flat = None
if flat is not None:
    flat_fitter = Fitter(flat, warm=True)
    g = flat.geometry
    flat_frame = StrainModel(flat).predict(Contact(6.0, 6.0, 90.0, 1.5, g.span_x / 2, g.span_y / 2))
    res = flat_fitter.fit(flat_frame, "auto")
    if linearize is not None and res.params is not None:
        linearize(flat_fitter, flat_frame, res.model, np.asarray(res.params))
# ... and what the daemon's workers meet only later in life (a learned model-error floor, a
# flat field, auto's switches on a moving contact): one pass of the moving scene, every frame
# answered, the fit deadline long enough for any compilation.
import asyncio
from tactiled.pipeline import Daemon
from tactiled.settings import load_settings


async def _one_pass():
    daemon = Daemon(load_settings(None, {}, {
        "sensor[0].url": "sim://?scene=moving&seed=1&rate=1000&speed=0&loop=0",
        "fit.workers": 1, "fit.timeout": 120.0}), lossless=True)
    await daemon.start()
    await daemon.wait_finished(900)
    await daemon.stop()


asyncio.run(_one_pass())
"""

#: ... and, before a run of the hand, one pass of its palm (a flat array pressed in several
#: places at once: frames no single contact explains, fitted and tracked on kernels of their own).
COMPILE_HAND = COMPILE_KERNELS.replace(
    "sim://?scene=moving&seed=1&rate=1000&speed=0&loop=0",
    "sim://?scene=hand-palm&sensor=flat16&seed=1&rate=1000&speed=0&loop=0").replace(
    '"fit.workers": 1,', '"sensor[0].description": "flat16", "fit.workers": 1,')


#: Seconds more a run that first compiles its checkout's kernels (COMPILE_KERNELS) is allowed.
COMPILE_ALLOWANCE_S = 1800


def measure_at(tree: str, seconds: float, warmup: float, rate: float, scene: str,
               workers: int, sim_nice: int = 0, compile_kernels: bool = True) -> RunResult:
    """:func:`measure` with the code of checkout ``tree`` (its own daemon, workers and
    simulators; this one's too, for a fresh process), in a subprocess; its result comes back
    pickled.  ``sim_nice``: the simulators' niceness (a device has a processor of its own:
    niced, they take only the CPU the daemon leaves), set from here as they appear, so a
    baseline's harness need not know the option.  ``compile_kernels``: first fill the
    checkout's numba cache, a baseline revision's that has one (:data:`COMPILE_KERNELS`; False when an earlier run of this
    invocation did: the cache stays in the checkout)."""
    env = checkout_env(tree, build(tree))
    with tempfile.TemporaryDirectory(prefix="tactiled-acq-base-") as d:
        out = os.path.join(d, "result.pickle")
        code = ("import pickle, sys\n"
                "try:\n"
                "    from tactiled_bench.acquisition import measure\n"
                "except ImportError:  # a checkout whose benchmarks are tactiled.bench\n"
                "    from tactiled.bench.acquisition import measure\n"
                "if __name__ == '__main__':\n"
                + (f"    exec({(COMPILE_HAND if scene == HAND else COMPILE_KERNELS)!r})\n"
                   if compile_kernels else "")
                + f"    r = measure({seconds!r}, {warmup!r}, {rate!r}, {scene!r}, {workers!r})\n"
                f"    open({out!r}, 'wb').write(pickle.dumps(r))\n")
        script = os.path.join(d, "run_baseline.py")
        Path(script).write_text(code)
        proc = subprocess.Popen([sys.executable, script], cwd=tree, env=env)
        # (a numba revision's first run compiles every kernel first: minutes on a busy machine)
        allowed = seconds + warmup + 300 + (COMPILE_ALLOWANCE_S if compile_kernels else 0)
        deadline = time.monotonic() + allowed
        try:
            while proc.poll() is None:
                if time.monotonic() > deadline:
                    raise subprocess.TimeoutExpired(proc.args, allowed)
                if sim_nice:
                    renice_simulators(proc.pid, sim_nice)
                time.sleep(0.2)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        if proc.returncode:
            raise subprocess.CalledProcessError(proc.returncode, proc.args)
        with open(out, "rb") as f:
            return pickle.load(f)


def run(quick: bool, rate: float = 1000.0, scene: str = "demo", workers: Sequence[int] = (2,),
        seconds: float | None = None, baseline: str | None = None, sim_nice: int = 0,
        json_path: str | None = None) -> str:
    """Measure one run per worker count in ``workers`` and report them side by side; with
    ``baseline`` (a git revision), two runs each of this tree and of the baseline's code per
    worker count, alternating (this, baseline, baseline, this): the machine's drift falls on
    both alike.  ``json_path``: also write every figure of the tables there (:func:`figures`
    of each run, with the conditions)."""
    warmup = 4.0 if quick else 5.0
    if seconds is None:
        seconds = 6.0 if quick else 20.0
    timeline(scene)  # an unknown scene fails here, before any process starts
    # Every run in a process of its own, this tree's as the baseline's: runs made one after
    # another in one process were not alike (on the moving scene the third of three answered
    # 82 % of the contact frames where the first answered 95 %, and three first runs in
    # fresh processes all 95 %), which made the baseline's always-fresh runs look better.
    here = str(Path(__file__).resolve().parents[2])
    compiled: set[str] = set()  # checkouts whose kernels a run of this invocation compiled

    def measure_in(tree: str, w: int) -> RunResult:
        first = tree not in compiled
        compiled.add(tree)
        return measure_at(tree, seconds, warmup, rate, scene, w, sim_nice, compile_kernels=first)

    if baseline is None:
        results = [measure_in(here, w) for w in workers]
    else:
        results = []
        with tempfile.TemporaryDirectory(prefix="tactiled-acq-") as tmp:
            tree = checkout(baseline, tmp)
            for w in workers:
                for mine in (True, False, False, True):
                    r = measure_in(here if mine else tree, w)
                    r.label = "this tree" if mine else f"baseline {baseline}"
                    results.append(r)
    figs = [figures(r, scene, rate) for r in results]
    if json_path is not None:
        import json

        doc = {"scene": scene, "rate_hz": rate, "seconds": seconds, "warmup_s": warmup,
               "sim_nice": sim_nice, "cores": os.cpu_count(),
               "conditions": conditions(scene, rate, seconds, warmup, results, sim_nice),
               "runs": figs}
        with open(json_path, "w", encoding="utf-8") as fh:
            json.dump(doc, fh, indent=1)
            fh.write("\n")
    return report(results, scene, rate, seconds, warmup, sim_nice, figs)

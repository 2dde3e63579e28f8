"""Acquisition under load: simulated fingers at 1 kHz over real pseudo-terminals.

Each finger is a separate ``tactiled simulate --pty`` process writing encoded frames to a pty at
its scene rate; the daemon reads them with pyserial (``serial://`` on a stable symlink), decodes,
linearises, zeroes, gates and fits in its worker pool, exactly as it would a device.  Measured:
frames the decoder lost or rejected (the bar: none), that every frame was published, superseded
or otherwise accounted for, the fit rate, and latency from frame arrival to published estimate.
The daemon runs under the heap policy of the process that serves (``tactiled.heap.serving``, as
``tactiled run`` does), and what the run keeps of each estimate is flat, so the collector's
work is the daemon's own.

On a scene of moving contacts (``--scene moving``) the question is whether every contact frame
gets an answer of its own: by its own fit, or by a gate reuse the chi-square test justifies (the
frame is the fitted one within noise), rather than being superseded while a fit runs.  Each
run (one per worker count of the sweep) reports those shares, latency, and the accuracy of the
streamed estimates against the scene's truth, matched by seq: the simulator's frame ``seq`` is
its tick index, so the truth of any frame is ``scene.contact_at((seq mod ticks per pass) /
rate)``, recomputed here without talking to the simulator.
"""

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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tactiled import heap
from tactiled.physics.contact import Contact
from tactiled.pipeline import Daemon
from tactiled.settings import load_settings
from tactiled.sensors import DEFAULT_NAME
from tactiled.sim import HAND_PARTS, AnyScene, MultiScene, named_scene

FINGERS = ("thumb", "index", "middle")
#: The scene that runs six devices at once: a hand's five fingertips and its palm, each its
#: own simulator playing its part of one grasp (``tactiled.sim.HAND_PARTS``).
HAND = "hand"


@dataclass(frozen=True)
class Device:
    """One simulated device of a run: the daemon's sensor name, the scene it plays and the
    sensor description of its array."""

    name: str
    scene: str
    description: str = DEFAULT_NAME


def devices(scene: str) -> tuple[Device, ...]:
    """The devices of a run of ``scene``: three fingers playing it, or the hand's six parts."""
    if scene == HAND:
        return tuple(Device(part, sc, desc) for part, (sc, desc) in HAND_PARTS.items())
    return tuple(Device(name, scene) for name in FINGERS)


def known_scene(scene: str) -> bool:
    """Whether ``scene`` names a run: a built-in scene or the hand."""
    from tactiled.sim import SCENES

    return scene == HAND or scene in SCENES


def timeline(scene: str) -> AnyScene:
    """The scene whose clock every device of a run keeps: the named one; for the hand, every
    track of its parts together, whose touching spans are each part's (every part is pressed
    when the grasp closes and released when it opens), so it says whether a frame's part
    touches, not with what."""
    if scene != HAND:
        return named_scene(scene)
    return MultiScene([tr for sc, _ in HAND_PARTS.values() for tr in named_scene(sc).tracks], HAND)
PARAMS = ("r1_mm", "angle_deg", "force_n", "x_mm", "y_mm")
INDENTORS = ("cylinder", "sphere", "edge")


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
# What one run saw, and what it means


@dataclass(frozen=True)
class Seen:
    """One estimate published in the measured window: the finger's index, the frame's seq,
    the gate's decision, frame -> estimate latency (ms) and the fit line's keys that the
    summary reads (``SLIM_KEYS``).  (Made after the run; a baseline's result, pickled by its
    own code, comes back as one too.)"""

    finger: int
    seq: int
    gate: str
    latency_ms: float
    fit: dict[str, Any]
    #: contacts the estimate reported: the length of its ``contacts`` list when it has one,
    #: else 1 or 0 (its top-level contact); None: not counted
    contacts: int | None = None

    @classmethod
    def from_record(cls, record: tuple[Any, ...]) -> Seen:
        """The Seen of a record as the run's listener keeps it: ``(finger, seq, gate,
        latency_ms, slim(fit)[, contacts])``."""
        return cls(*record[:4], dict(zip(SLIM_KEYS, record[4])), *record[5:6])


#: The keys of an estimate's fit line that :func:`summarise` reads.
SLIM_KEYS = ("contact", "fit_ms", "message", *PARAMS)


def contacts_of(item: Any) -> int:
    """How many contacts an estimate reports: its ``contacts`` list's length (on the estimate
    or in its fit line) when it carries one, else its top-level contact (1 or 0)."""
    listed = getattr(item, "contacts", None)
    if listed is None:
        listed = item.fit.get("contacts")
    if listed is not None:
        return len(listed)
    return int(bool(item.fit.get("contact")))


def slim(fit: dict[str, Any]) -> tuple[Any, ...]:
    """The values of ``SLIM_KEYS`` in a fit line: the flat part the summary needs.  What a
    run keeps of its ~60 000 estimates must not weigh on the daemon it measures: a tuple of
    numbers and strings is one the garbage collector stops tracking, while the whole fit
    lines (nested dicts) made every full collection walk them all (up to 69 ms each, a stall of
    the loop that showed as the run's p99 latency)."""
    return tuple(fit.get(k) for k in SLIM_KEYS)


@dataclass
class RunResult:
    """One run of the sweep: counters before and after the measured window, what the
    listener saw in it, CPU seconds used, the simulators' own counts."""

    workers: int
    before: dict[str, Any]
    after: dict[str, Any]
    elapsed: float  # s
    seen: list[Seen]
    cpu_s: dict[str, float | None]  # "daemon", "workers", "simulators": CPU seconds in the window
    device: list[tuple[int, int, int] | None] = field(default_factory=list)
    tares: int = 0  # tares it took to zero every sensor on untouched frames
    label: str = ""  # whose code ran ("" alone; "this tree" / "baseline REV" side by side)
    #: the daemon's sensor names, in device order (a baseline's result: the three fingers)
    parts: tuple[str, ...] = FINGERS
    #: the measured window in windows of about a second: (seconds, the daemon's main process's
    #: CPU seconds, frames every sensor handled)
    windows: list[tuple[float, float, int]] = field(default_factory=list)
    #: the duration (s) of every garbage collection the daemon's process ran in the measured
    #: window, of any generation
    gc_s: list[float] = field(default_factory=list)

    @property
    def who(self) -> str:
        """The run's name in the tables: its worker count, and whose code with a baseline."""
        return f"{self.label}, {self.workers}" if self.label else str(self.workers)


def indentor(c: Contact) -> str:
    """What the truth is: ``sphere`` (r1 = r2), ``edge`` (r1 < 1 mm), ``cylinder`` or
    ``general``."""
    if math.isclose(c.r1, c.r2, rel_tol=1e-9):
        return "sphere"
    if math.isinf(c.r2):
        return "edge" if c.r1 < 1.0 else "cylinder"
    return "general"


def scene_truth(scene: str, rate: float) -> Callable[[int], Contact | None]:
    """``truth(seq)``: the contact of the simulated finger's frame ``seq`` (a looping scene at
    ``rate`` Hz, as ``tactiled simulate`` plays it: seq = tick index)."""
    sc = timeline(scene)
    per_pass = max(1, round(sc.duration * rate))
    cache: dict[int, Contact | None] = {}

    def truth(seq: int) -> Contact | None:
        k = seq % per_pass
        if k not in cache:
            cache[k] = sc.contact_at(k / rate)
        return cache[k]

    return truth


def tare_window(scene: str, rate: float) -> tuple[int, int] | None:
    """Ticks ``[lo, hi)`` into a pass of ``scene`` at which to tare: early in its first idle of
    0.4 s or more, so the zeroer's baseline (formed over its 0.25 s settling time, and moved
    afterwards only while nothing touches) starts from an unloaded finger; None if the scene
    has no such idle."""
    sc = timeline(scene)
    if isinstance(sc, MultiScene):
        spans = sc.idle_spans()
    else:
        spans = [(sc.segment_start(i), sc.segment_start(i) + seg.duration)
                 for i, seg in enumerate(sc.segments) if seg.kind == "idle"]
    for t0, t1 in spans:
        if t1 - t0 >= 0.4:
            return round((t0 + 0.02) * rate), round((t0 + 0.1) * rate)
    return None


def abs_error(key: str, est: float, c: Contact) -> float | None:
    """|estimate - truth| in reporting units: % for radius (r1) and force, degrees (folded into
    [0, 90]; None for a sphere, which has no orientation), micrometres for x and y."""
    if key == "r1_mm":
        return 100.0 * abs(est / c.r1 - 1.0)
    if key == "force_n":
        return 100.0 * abs(est / c.force - 1.0)
    if key == "angle_deg":
        if indentor(c) == "sphere":
            return None
        return abs((est - c.psi_deg + 90.0) % 180.0 - 90.0)
    return 1000.0 * abs(est - (c.x0 if key == "x_mm" else c.y0))


@dataclass
class Accuracy:
    """Absolute errors of streamed estimates against the truth, per parameter; ``withheld``
    counts estimates in contact whose value was null (the fitter said why)."""

    estimates: int = 0
    errors: dict[str, list[float]] = field(default_factory=lambda: {k: [] for k in PARAMS})
    withheld: dict[str, int] = field(default_factory=lambda: dict.fromkeys(PARAMS, 0))

    def add(self, fit: dict[str, Any], c: Contact) -> None:
        self.estimates += 1
        for k in PARAMS:
            v = fit.get(k)
            if v is None:
                if not (k == "angle_deg" and indentor(c) == "sphere"):
                    self.withheld[k] += 1
                continue
            e = abs_error(k, float(v), c)
            if e is not None:
                self.errors[k].append(e)

    def cell(self, k: str) -> str:
        errs = self.errors[k]
        fmt = "{:.2f}" if k in ("angle_deg", "force_n") else "{:.1f}"
        text = fmt.format(float(np.median(errs))) if errs else "-"
        w = self.withheld[k]
        if w and self.estimates:
            text += f" ({100.0 * w / self.estimates:.0f} % withheld)"
        return text


@dataclass
class Answers:
    """How a run's contact frames were answered (all fingers together)."""

    frames: int = 0  # every frame the pipelines handled in the window
    contact: int = 0  # frames the detector called contact (answered or not)
    own_fit: int = 0  # answered by a fit of their own
    reused: int = 0  # answered by the last fit, the chi-square test finding them unchanged
    #: ... of which the tracker could only predict (their frame was not measured: a fit was
    #: late), from the pipelines' counters; not a justified reuse
    predicted: int = 0
    superseded: int = 0  # replaced in the slot by a newer frame before a worker took them
    unanswered: int = 0  # stale fit results dropped, fits lost, fitter errors
    touching: int = 0  # estimates of frames whose truth touches
    missed: int = 0  # ... published as no contact (too light at touch-down / lift-off)
    phantom: int = 0  # estimates in contact whose truth does not touch
    latency_contact: list[float] = field(default_factory=list)  # ms, fit + reuse
    latency_fit: list[float] = field(default_factory=list)  # ms, own fits only
    contacts_reported: int = 0  # contacts the estimates reported (a list's length, or 0/1)
    several: int = 0  # estimates that reported more than one contact
    fit_ms: list[float] = field(default_factory=list)  # the fitter's own time per fit, ms
    kept: int = 0  # auto fits that kept the previous frame's model (one model fitted)
    accuracy: dict[str, Accuracy] = field(default_factory=dict)  # by indentor, and "all"

    def share(self, n: int) -> str:
        return f"{100.0 * n / self.contact:.1f} %" if self.contact else "-"


def _delta(after: dict[str, Any], before: dict[str, Any], key: str, sub: str | None = None) -> int:
    if sub:
        return int(after[key][sub]) - int(before[key][sub])
    return int(after[key]) - int(before[key])


def summarise(result: RunResult, truth: Callable[[int], Contact | None] | None,
              only: str | None = None, accuracy: bool = True) -> Answers:
    """The shares, latencies and accuracy of one run (of its sensor ``only``, else of all).
    Published answers come from the estimates the listener saw in the window; frames never
    answered (superseded, stale, lost) from the pipelines' counters over the same window.
    ``accuracy=False``: compare with ``truth`` only whether a frame touches (the truth says
    when, not what)."""
    a = Answers()
    acc: dict[str, Accuracy] = {"all": Accuracy()}
    index = None if only is None else result.parts.index(only)
    for s in result.seen:
        if index is not None and s.finger != index:
            continue
        fit = s.fit
        if s.contacts is not None:
            a.contacts_reported += s.contacts
            a.several += s.contacts > 1
        in_contact = bool(fit.get("contact"))
        if s.gate == "fit":
            a.own_fit += 1
            a.latency_fit.append(s.latency_ms)
            a.latency_contact.append(s.latency_ms)
            if fit.get("fit_ms") is not None:
                a.fit_ms.append(float(fit["fit_ms"]))
            if str(fit.get("message", "")).startswith("model ") and "kept from the previous" in str(fit.get("message")):
                a.kept += 1
        elif s.gate == "unchanged":
            a.reused += 1
            a.latency_contact.append(s.latency_ms)
        if truth is None:
            continue
        c = truth(s.seq)
        if c is None:
            a.phantom += in_contact
            continue
        a.touching += 1
        if not in_contact:
            a.missed += 1
            continue
        if not accuracy:
            continue
        for key in ("all", indentor(c), "own fits" if s.gate == "fit" else "reuses"):
            acc.setdefault(key, Accuracy()).add(fit, c)
    a.accuracy = acc
    for name in (result.parts if only is None else (only,)):
        af, bf = result.after["sensors"][name], result.before["sensors"][name]
        a.frames += _delta(af, bf, "frames")
        a.superseded += _delta(af, bf, "superseded")
        a.predicted += _delta(af, bf, "predicted") if "predicted" in af else 0
        a.unanswered += (_delta(af, bf, "stale_dropped") + _delta(af, bf, "fit_failed")
                         + _delta(af, bf, "fit_errors"))
    a.contact = a.own_fit + a.reused + a.superseded + a.unanswered
    return a


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
    overrides: dict[str, object] = {"fit.workers": workers}
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


#: Run in a checkout before its daemon starts: one fit of each model and a linearisation,
#: so numba compiles the kernels into the checkout's own cache (a fresh one has none, and a
#: worker compiling them on its first fit, ~20 s, would be killed as hung again and again).
#: Plain code, not a function of this tree: the checkout's own modules run it.
COMPILE_KERNELS = """
import math
import numpy as np
from tactiled.sensors.model import SensorModel
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


def measure_at(tree: str, seconds: float, warmup: float, rate: float, scene: str,
               workers: int, sim_nice: int = 0, compile_kernels: bool = True) -> RunResult:
    """:func:`measure` with the code of checkout ``tree`` (its own daemon, workers and
    simulators; this one's too, for a fresh process), in a subprocess; its result comes back
    pickled.  ``sim_nice``: the simulators' niceness (a device has a processor of its own:
    niced, they take only the CPU the daemon leaves), set from here as they appear, so a
    baseline's harness need not know the option.  ``compile_kernels``: first fill the
    checkout's numba cache (:data:`COMPILE_KERNELS`; False when an earlier run of this
    invocation did: the cache stays in the checkout)."""
    path = os.pathsep.join([tree, os.path.join(tree, "drivers"), os.path.join(tree, "service")])
    env = {**os.environ, "PYTHONPATH": path}
    with tempfile.TemporaryDirectory(prefix="tactiled-acq-base-") as d:
        out = os.path.join(d, "result.pickle")
        code = ("import pickle, sys\n"
                "from tactiled_bench.acquisition import measure\n"
                "if __name__ == '__main__':\n"
                + (f"    exec({(COMPILE_HAND if scene == HAND else COMPILE_KERNELS)!r})\n"
                   if compile_kernels else "")
                + f"    r = measure({seconds!r}, {warmup!r}, {rate!r}, {scene!r}, {workers!r})\n"
                f"    open({out!r}, 'wb').write(pickle.dumps(r))\n")
        script = os.path.join(d, "run_baseline.py")
        Path(script).write_text(code)
        proc = subprocess.Popen([sys.executable, script], cwd=tree, env=env)
        deadline = time.monotonic() + seconds + warmup + 300
        try:
            while proc.poll() is None:
                if time.monotonic() > deadline:
                    raise subprocess.TimeoutExpired(proc.args, seconds + warmup + 300)
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


#: A finger counts as locked in contact when it published fewer "no contact" estimates than
#: this share of the frames its scene leaves untouched (the release residual or drift held
#: the detector on: docs/concepts/calibration.md, "The rubber's hysteresis is learnt and taken out"
#: and "Drift during a hold"): its run says little of fitting, and is marked so.
LOCKED_SHARE = 0.1


def untouched_share(scene: str, rate: float) -> float:
    """The share of a pass of ``scene`` at ``rate`` Hz in which nothing touches the finger."""
    truth = scene_truth(scene, rate)
    per_pass = max(1, round(timeline(scene).duration * rate))
    return sum(truth(k) is None for k in range(per_pass)) / per_pass


def locked_fingers(result: RunResult, untouched: float) -> list[str]:
    """The fingers of ``result`` locked in contact over the measured window: they published
    "no contact" for under ``LOCKED_SHARE`` of the frames their scene leaves untouched
    (``untouched``: :func:`untouched_share`)."""
    locked = []
    for name in result.parts:
        a, b = result.after["sensors"][name], result.before["sensors"][name]
        frames = _delta(a, b, "frames")
        free = _delta(a, b, "skipped", "no_contact")
        if frames and free < LOCKED_SHARE * untouched * frames:
            locked.append(name)
    return locked


def _pct(values: Sequence[float], q: float, digits: int = 2) -> str:
    return f"{np.percentile(values, q):.{digits}f}" if len(values) else "-"


def _q(values: Sequence[float], q: float) -> float | None:
    """The ``q``-th percentile of ``values`` (None for none), as JSON carries it."""
    return float(np.percentile(values, q)) if len(values) else None


def integrity(result: RunResult) -> dict[str, dict[str, Any]]:
    """Per sensor of one run: frames the device sent and the daemon received, lost, rejected
    and what became of every frame (counts over the measured window, rates per second; gaps
    and the device's own counts over the whole run)."""
    before, after, elapsed = result.before["sensors"], result.after["sensors"], result.elapsed
    out = {}
    for i, name in enumerate(result.parts):
        a, b = after[name], before[name]

        def delta(key: str, sub: str | None = None) -> int:
            return _delta(a, b, key, sub)

        frames = delta("frames")
        # whole-run totals: the device's own count of frames it never sent against the gaps
        # the decoder saw over the daemon's whole life
        gaps_total = int(a["decoder"]["lost"])
        dev = result.device[i] if i < len(result.device) else None
        unsent = (dev[1] + dev[2]) if dev else None
        accounted = (delta("published") + delta("superseded") + delta("stale_dropped") + delta("fit_failed")
                     + delta("fit_errors") + delta("wrong_sensor") + delta("bad_shape") + delta("errors"))
        in_hand = int(a["in_hand"]) - int(b["in_hand"])
        out[name] = {
            "frames": frames, "frames_per_s": frames / elapsed,
            "device_sent": dev[0] if dev else None,  # whole run
            "device_not_sent": unsent,  # whole run: pty full or behind schedule
            "gaps_seen": gaps_total,  # whole run
            "lost_in_acquisition": None if unsent is None else max(gaps_total - unsent, 0),
            "rejected": delta("decoder", "crc_errors") + delta("decoder", "cobs_errors") + delta("decoder", "truncated"),
            "duplicated": delta("decoder", "duplicated"),
            "fits_per_s": delta("fitted") / elapsed,
            "superseded_per_s": delta("superseded") / elapsed,
            "reused_per_s": delta("skipped", "unchanged") / elapsed,
            "no_contact_per_s": delta("skipped", "no_contact") / elapsed,
            "stale": delta("stale_dropped"),
            "unaccounted": frames - accounted - in_hand,
        }
    return out


def _answers_figures(a: Answers, elapsed: float, sensors: int) -> dict[str, Any]:
    """The answers of a run (or of one sensor of it) as plain figures (shares in %)."""
    def share(n: int) -> float | None:
        return 100.0 * n / a.contact if a.contact else None

    answered = a.own_fit + a.reused - a.predicted
    return {
        "frames": a.frames, "contact_frames": a.contact,
        "own_fit": a.own_fit, "reused": a.reused, "predicted": a.predicted,
        "superseded": a.superseded, "unanswered": a.unanswered, "answered": answered,
        "own_fit_pct": share(a.own_fit), "reused_pct": share(a.reused),
        "predicted_pct": share(a.predicted), "superseded_pct": share(a.superseded),
        "unanswered_pct": share(a.unanswered), "answered_pct": share(answered),
        "latency_ms": {"p50": _q(a.latency_contact, 50), "p99": _q(a.latency_contact, 99),
                       "max": max(a.latency_contact) if a.latency_contact else None},
        "own_fit_latency_ms": {"p50": _q(a.latency_fit, 50), "p99": _q(a.latency_fit, 99)},
        "fits_per_s_per_sensor": a.own_fit / elapsed / sensors,
        "fit_ms": {"p50": _q(a.fit_ms, 50), "p99": _q(a.fit_ms, 99)},
        "auto_kept_pct": 100.0 * a.kept / a.own_fit if a.own_fit else 0.0,
        "contacts_reported": a.contacts_reported, "estimates_with_several_contacts": a.several,
        "truth_touching": a.touching, "missed": a.missed, "phantom": a.phantom,
    }


def cpu_per_frame(result: RunResult) -> dict[str, float | None]:
    """The daemon's main process's CPU per frame handled (us), over the run's windows of
    about a second: median, p99 and max of the windows, and over the whole window."""
    windows = getattr(result, "windows", [])  # (a baseline's result may not have them)
    per = [1e6 * cpu / frames for _, cpu, frames in windows if frames > 0]
    cpu = result.cpu_s.get("daemon")
    frames = sum(_delta(result.after["sensors"][n], result.before["sensors"][n], "frames")
                 for n in result.parts)
    return {"median_us": _q(per, 50), "p99_us": _q(per, 99), "max_us": max(per) if per else None,
            "windows": len(per),
            "whole_us": None if cpu is None or not frames else 1e6 * cpu / frames}


def garbage_collection(result: RunResult) -> dict[str, float | int | None]:
    """The daemon's process's garbage collections in the measured window: how many, their
    total and their longest (ms); None where the run did not record them (a baseline's)."""
    times = getattr(result, "gc_s", None)
    if times is None:
        return {"collections": None, "total_ms": None, "max_ms": None}
    return {"collections": len(times), "total_ms": 1e3 * sum(times),
            "max_ms": 1e3 * max(times) if times else 0.0}


def figures(result: RunResult, scene: str, rate: float) -> dict[str, Any]:
    """Every figure of one run's tables, machine-readable: totals, and per sensor."""
    truth = scene_truth(scene, rate)
    accuracy = scene != HAND
    a = summarise(result, truth, accuracy=accuracy)
    sensors = integrity(result)
    n = len(result.parts)
    for name in result.parts:
        sensors[name].update(_answers_figures(summarise(result, truth, name, accuracy),
                                              result.elapsed, 1))
    total_keys = ("frames", "device_sent", "device_not_sent", "gaps_seen", "lost_in_acquisition",
                  "rejected", "duplicated", "stale", "unaccounted")
    total: dict[str, Any] = {
        k: (None if any(s[k] is None for s in sensors.values()) else sum(s[k] for s in sensors.values()))
        for k in total_keys}
    total["frames_per_s"] = total["frames"] / result.elapsed
    total.update(_answers_figures(a, result.elapsed, n))
    untouched = untouched_share(scene, rate)
    out: dict[str, Any] = {
        "run": result.who, "workers": result.workers, "elapsed_s": result.elapsed,
        "tares": result.tares,
        "cpu_pct_of_a_core": {k: None if v is None else 100.0 * v / result.elapsed
                              for k, v in result.cpu_s.items()},
        "main_process_cpu_per_frame": cpu_per_frame(result),
        "garbage_collection": garbage_collection(result),
        "locked_in_contact": locked_fingers(result, untouched),
        "total": total, "sensors": sensors,
    }
    if accuracy:
        out["accuracy"] = {k: {"estimates": acc.estimates,
                               "median_abs_error": {p: _q(acc.errors[p], 50) for p in PARAMS},
                               "withheld": dict(acc.withheld)}
                           for k, acc in a.accuracy.items() if acc.estimates}
    return out


def _cpu_cell(seconds: float | None, elapsed: float) -> str:
    return "?" if seconds is None else f"{100.0 * seconds / elapsed:.0f} %"


def _num(v: float | None, fmt: str = "{:.2f}") -> str:
    return "-" if v is None else fmt.format(v)


def _share(v: float | None) -> str:
    return "-" if v is None else f"{v:.1f} %"


def conditions(scene: str, rate: float, seconds: float, warmup: float, results: Sequence[RunResult],
               sim_nice: int) -> str:
    """The sentence that says how a sweep ran."""
    col = "workers" if not any(r.label for r in results) else "code, workers"
    sweep = ", ".join(dict.fromkeys(str(r.workers) for r in results))
    runs = ("one run each, everything restarted" if col == "workers" else
            "four runs each, alternating this tree and the baseline's code (this, baseline, "
            "baseline, this), everything restarted every run")
    devs = devices(scene)
    if scene == HAND:
        what = (f"{len(devs)} simulated devices, a hand (`tactiled simulate --pty --scene hand-palm --sensor "
                f"flat16` and `--scene hand-finger1` .. `hand-finger5` on the default finger, "
                f"`--rate {rate:g}`, one process each)")
    else:
        what = (f"{len(devs)} simulated fingers (`tactiled simulate --pty --scene {scene} --rate {rate:g}`, one "
                f"process each)")
    return (f"{what} read over real ptys with pyserial; {seconds:g} s measured after {warmup:g} s of "
            f"warm-up; each sensor tared early in an idle of the scene, as a hand starts with its fingers free "
            f"(the daemon opens the ports at an arbitrary moment of the scene), again at the next idle if the "
            f"baseline took in a contact frame (tares per run: {', '.join(str(r.tares) for r in results)}); fit "
            f"workers: {sweep} ({runs}); model `auto` (the daemon's default); "
            f"{os.cpu_count()} cores shared by everything"
            + (f" (the simulators at niceness {sim_nice}: a finger's device has a processor of its "
               f"own, so they take only the CPU the daemon leaves)" if sim_nice else
               " (the simulators at the daemon's own niceness, competing with it for the cores)") + ".")


def report(results: list[RunResult], scene: str, rate: float, seconds: float, warmup: float,
           sim_nice: int = 0, figs: list[dict[str, Any]] | None = None) -> str:
    """The Markdown tables of a sweep (from :func:`figures` of each run, ``figs`` if given)."""
    col = "code, workers" if any(r.label for r in results) else "workers"
    figs = figs if figs is not None else [figures(r, scene, rate) for r in results]
    lines = [conditions(scene, rate, seconds, warmup, results, sim_nice), ""]
    # -- answers and latency
    lines += ["### Every contact frame answered?", "",
              f"| {col} | contact frames | own fit | gate reuse (unchanged) | of which predicted | superseded | stale / lost | "
              "latency p50 / p99 ms (contact frames) | own fits p50 / p99 ms | fits/s per finger | "
              "fit_ms p50 / p99 | auto kept the model | CPU: daemon / workers / simulators | "
              "fingers locked in contact |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r, f in zip(results, figs):
        t = f["total"]
        lines.append(
            f"| {r.who} | {t['contact_frames']} | {_share(t['own_fit_pct'])} | {_share(t['reused_pct'])} | "
            f"{_share(t['predicted_pct'])} | {_share(t['superseded_pct'])} | {_share(t['unanswered_pct'])} | "
            f"{_num(t['latency_ms']['p50'])} / {_num(t['latency_ms']['p99'])} | "
            f"{_num(t['own_fit_latency_ms']['p50'])} / {_num(t['own_fit_latency_ms']['p99'])} | "
            f"{t['fits_per_s_per_sensor']:.0f} | {_num(t['fit_ms']['p50'], '{:.3f}')} / "
            f"{_num(t['fit_ms']['p99'], '{:.3f}')} | {t['auto_kept_pct']:.0f} % | "
            f"{_cpu_cell(r.cpu_s.get('daemon'), r.elapsed)} / {_cpu_cell(r.cpu_s.get('workers'), r.elapsed)} / "
            f"{_cpu_cell(r.cpu_s.get('simulators'), r.elapsed)} | "
            f"{', '.join(f['locked_in_contact']) or 'none'} |")
    lines += ["",
              "Shares are of the contact frames (frames the detector called contact): answered by a fit of their "
              "own, answered by the last fit because the chi-square test found them unchanged within noise (a "
              "justified reuse; with tracking, measured through the last fit's linearisation, which a test of "
              "its own admits: docs/concepts/tracking.md), of which predicted (the tracker had to publish the contact "
              "predicted to the frame's time because its fit came back late: not a justified reuse), superseded "
              "in the one-frame slot by a newer frame before a worker was free, or unanswered otherwise (a fit "
              "result dropped as stale, a fit lost).  Targets (issue 16): own fit + reuse - predicted >= 99 %, "
              "superseded <= 1 %, p99 latency <= 5 ms.  Latency: frame arrival (host receive) to "
              "published estimate.  fit_ms: the fitter's own time per fit in the worker (wall).  'auto kept the "
              "model': own fits where auto refitted only the previous frame's model, warm (one model, not three).  "
              "CPU over the measured window in % of one core: the daemon's main process (event loop and serial "
              "read thread), its fit workers, the simulators.  'Fingers locked in contact': fingers "
              f"that published 'no contact' for under {100 * LOCKED_SHARE:g} % of the frames the scene leaves "
              "untouched (a release residual or drift held the detector on, docs/concepts/calibration.md): their phantom contact frames "
              "count here, so such a run says little of the fitting."]
    # -- the main process's budget, per sensor
    lines += ["", "### The main process's CPU per frame, and each sensor's answers", "",
              f"| {col} | sensor | contact frames | answered (own fit + reuse - predicted) | contacts reported | "
              "estimates with several contacts | latency p50 / p99 / max ms |",
              "|---|---|---|---|---|---|---|"]
    for r, f in zip(results, figs):
        for name, s in [*f["sensors"].items(), ("all", f["total"])]:
            lat = s["latency_ms"]
            lines.append(f"| {r.who} | {name} | {s['contact_frames']} | {_share(s['answered_pct'])} | "
                         f"{s['contacts_reported']} | {s['estimates_with_several_contacts']} | "
                         f"{_num(lat['p50'])} / {_num(lat['p99'])} / {_num(lat['max'])} |")
    lines += ["", f"| {col} | main process CPU per frame, us: median / p99 of ~1 s windows | whole window | windows "
              "| garbage collections: count / total ms / longest ms |",
              "|---|---|---|---|---|"]
    for r, f in zip(results, figs):
        c, g = f["main_process_cpu_per_frame"], f["garbage_collection"]
        lines.append(f"| {r.who} | {_num(c['median_us'], '{:.1f}')} / {_num(c['p99_us'], '{:.1f}')} | "
                     f"{_num(c['whole_us'], '{:.1f}')} | {c['windows']} | {_num(g['collections'], '{}')} / "
                     f"{_num(g['total_ms'], '{:.1f}')} / {_num(g['max_ms'], '{:.1f}')} |")
    lines += ["",
              "Answered: the contact frames answered by their own fit or a justified reuse (the tracker's "
              "measurement included), less those only predicted; target >= 99 %.  Contacts reported: the "
              "estimates' `contacts` lists' lengths where they carry one, else their top-level contact (0 or "
              "1).  Main process CPU per frame: the CPU time of the daemon's main process (its event loop and "
              "serial read thread, not its fit workers) in each window of about a second, divided by the "
              "frames all its sensors handled in that window; target <= 40 us at the median.  Garbage "
              "collections: those the daemon's process ran in the measured window, of any generation "
              "(the start-up heap is frozen before the run: tactiled.heap)."]
    # -- accuracy
    if scene != HAND:
        lines += ["", "### Accuracy of the streamed estimates against the scene's truth", "",
                  f"| {col} | estimates of | count | radius % | angle deg | force % | x um | y um |",
                  "|---|---|---|---|---|---|---|---|"]
        truth = scene_truth(scene, rate)
        for r in results:
            a = summarise(r, truth)
            for key in ("all", "own fits", "reuses", *INDENTORS, "general"):
                acc = a.accuracy.get(key)
                if acc is None or not acc.estimates:
                    continue
                lines.append(f"| {r.who} | {key} | {acc.estimates} | {acc.cell('r1_mm')} | {acc.cell('angle_deg')} | "
                             f"{acc.cell('force_n')} | {acc.cell('x_mm')} | {acc.cell('y_mm')} |")
        lines += ["",
                  "Median absolute errors of every estimate in contact published in the window (own fits and reuses "
                  "alike) against the truth of *its own* frame (matched by seq), so a reuse that lags a moving contact "
                  "costs accuracy here (rows 'own fits' and 'reuses' split them; then by the true indentor); withheld: the estimate's value was null (e.g. radius 'force too low for "
                  "curvature'), its share of the estimates.  Angles are not compared on spheres."]
    lines += ["", f"| {col} | truth touching | missed (published as no contact) | contact published without truth |",
              "|---|---|---|---|"]
    for r, f in zip(results, figs):
        t = f["total"]
        lines.append(f"| {r.who} | {t['truth_touching']} | {t['missed']} "
                     f"({100.0 * t['missed'] / max(t['truth_touching'], 1):.1f} %) | {t['phantom']} |")
    # -- integrity
    lines += ["", "### Acquisition", "",
              f"| {col} | finger | frames/s | gaps seen | not sent by the device | lost in acquisition | "
              "CRC / COBS / truncated | duplicated | fits/s | superseded/s | reused (unchanged)/s | "
              "no contact/s | stale | unaccounted |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    total_lost = 0
    for r, f in zip(results, figs):
        for name, s in f["sensors"].items():
            lost = s["lost_in_acquisition"]
            total_lost += lost if lost is not None else s["gaps_seen"]
            lines.append(
                f"| {r.who} | {name} | {s['frames_per_s']:.0f} | {s['gaps_seen']} | "
                f"{'?' if s['device_not_sent'] is None else s['device_not_sent']} | "
                f"{'?' if lost is None else lost} | {s['rejected']} | {s['duplicated']} | "
                f"{s['fits_per_s']:.0f} | {s['superseded_per_s']:.0f} | {s['reused_per_s']:.0f} | "
                f"{s['no_contact_per_s']:.0f} | {s['stale']} | {s['unaccounted']} |")
    lines += ["",
              f"Frames lost in acquisition: {total_lost}.  'Gaps seen' are sequence gaps the decoder counted over "
              "the whole run; 'not sent by the device' is the simulators' own count of frames they generated but "
              "did not write (pty full, or behind schedule on a starved CPU); the difference is what acquisition "
              "lost.  Rates and 'unaccounted' are over the measured window: 'unaccounted' = frames - (published + "
              "superseded + stale + failed + rejected), corrected for a frame waiting or in flight at the two "
              "snapshots; 0 means every frame was either answered or counted as superseded."]
    return "\n".join(lines)


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
        from tactiled_bench.speed import _checkout

        results = []
        with tempfile.TemporaryDirectory(prefix="tactiled-acq-") as tmp:
            tree = _checkout(baseline, tmp)
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

"""Soak: three simulated fingers at 1 kHz over real ptys, WebSocket subscribers (some of which
never read), for minutes or hours.

Each finger is a ``tactiled simulate --pty`` process streaming a looping scene at ``--rate`` Hz:
by default ``busy`` (:func:`tactiled_bench.scenes.busy_scene`), whose contact presses, rolls,
turns and changes shape all the time, so the fit workers are kept busy (``--scene demo`` plays
the demo scene, mostly held contacts that the gate answers without a fit).
This process runs the service (:class:`tactiled_service.server.Service`: the daemon with its
``serial://`` sensors read by pyserial, the fit worker pool, the hub, and uvicorn on 127.0.0.1,
an ephemeral port) and nothing else, so its resident memory is the service's.  ``--subscribers
N`` WebSocket subscribers (default 50) run in a child process of their own, so they neither
add to the measured memory nor compete for its GIL: minimal raw-socket clients sharing one
selector thread (:mod:`tactiled_bench.websocket_fanout`'s).  The healthy ones subscribe as the
dashboard does (estimates of every sensor, ``--max-rate`` 30 Hz) and read everything;
``--stalled K`` of them (default 5) subscribe the same way and never read: the server closes
them (1013) once a send has been stuck for its send timeout, and they reconnect and stall
again.  ``--subscribers 0`` runs the bare daemon (acquisition only).

After ``--warmup`` seconds the run is measured for ``--seconds``:

* memory: the service's RSS (and each fit worker's) sampled every ``--interval`` s; growth =
  the largest sample minus the one at the end of the warm-up, and the slope of a line fitted
  to the samples taken ``--settle`` s (300) after the start; the heap figures of the service
  and, asked over the worker protocol (``memory``), of each worker (:mod:`tactiled.heapstats`:
  RSS split into anonymous and file pages, malloc's and pymalloc's books, the fitter's
  caches); and the service's open file descriptors (the most over 1 s) at the end of the
  warm-up and at the end;
* acquisition, per finger: frames decoded, frames lost (gaps in seq seen by the decoder),
  chunks rejected, frames not accounted for by the pipeline (``frames - published -
  superseded - ...``, corrected for a frame waiting or in flight).  Lost frames are attributed
  by seq (a frame's seq is the simulator's tick index; :func:`simulator_main` records which
  seqs were never written and why): *skipped* (the simulator, starved for more than a
  second, never generated the frames it was late for), *overflowed* (its catch-up batch went
  over its own pending-bytes limit before any write), both not the daemon's doing since they
  never reached the wire; and *dropped* because the pty was full (the daemon did not read in
  time).  Over the seqs the window decoded, ``daemon_lost = lost - skipped - overflowed``,
  and the decoder must have decoded every frame the simulators wrote in that range
  (``frames == sent``: the rate over frames actually sent is 100 %);
* subscribers: per healthy subscriber, delivery = estimates received / (messages the server
  sent it + messages it dropped for it), from the server's own per-session counters once an
  ``unsubscribe`` has flushed the connection; the closes of never-reading subscribers (1013)
  and their reconnections;
* CPU: this soak's processes (service, fit workers, simulators, subscribers) and the other
  jobs on the machine (``/proc/stat`` minus this process tree), in cores;
* the service's event loop: how often a 10 ms sleep woke more than 50 / 125 ms late (a pty
  holds ~125 ms of a 1 kHz finger), and the fraction of the time the service's loop thread
  and each simulator were runnable but waiting for a CPU (``/proc/PID/schedstat``).

Bars (docs/performance/reliability.md), judged whatever the load: RSS growth under 5 MB, and, on runs whose
samples after the settling span at least 10 minutes, an RSS slope under 1 MB per hour for the
service and for every fit worker; no frame lost
through the daemon's fault (``daemon_lost == 0``) and none dropped on a full pty, every frame
written decoded, none rejected, duplicated or unaccounted, no disconnect; every healthy
subscriber >= 99 % delivered and none closed; the never-reading ones closed and back; no
descriptor leaked.  Frames the simulators never wrote, worker restarts and the CPU of other
jobs are reported, not judged.

    python -m tactiled_bench.reliability --quick          # 20 s (after a 60 s warm-up)
    python -m tactiled_bench.reliability                  # 10 min
    python -m tactiled_bench.reliability --seconds 3600   # 1 h (the slope bar: after 5 min)
    python -m tactiled_bench.reliability --scene demo     # the demo scene (mostly gated)
    python -m tactiled_bench.reliability --subscribers 0  # acquisition only (the bare daemon)
    python -m tactiled_bench.reliability --quick --json   # one JSON object (what the test reads)
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import json
import logging
import math
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from array import array
from pathlib import Path
from typing import Any

from tactiled.heapstats import heap_figures, rss_mb, rss_parts_mb

FINGERS = ("thumb", "index", "middle")
RSS_BAR_MB = 5.0
#: Bar on the slope of RSS (service and every fit worker) after ``SETTLE_S``, MB per hour ...
SLOPE_BAR_MB_PER_H = 1.0
#: ... judged from this long after the start (caches fill, code pages are first touched) ...
SETTLE_S = 300.0
#: ... when the samples after it span at least this long (a slope over less is noise).
SLOPE_MIN_SPAN_S = 600.0
#: The soak's default scene: keeps the fitter busy (tactiled_bench.scenes).  A built-in
#: scene for the same purpose (``moving``, tactiled.sim) may replace it.
DEFAULT_SCENE = "busy"
DELIVERY_BAR = 0.99
_SUMMARY = re.compile(r"sent (\d+) frame\(s\), dropped (\d+) \(device full\), skipped (\d+)")
_RUNS = re.compile(r"^seq runs: (\{.*\})$", re.MULTILINE)

#: A simulator: ``tactiled simulate`` run through :func:`simulator_main` (arguments follow).
_SIMULATOR = ("import sys; from tactiled_bench.reliability import simulator_main; "
              "sys.exit(simulator_main(sys.argv[1:]))")
#: The subscribers: :func:`subscribers_main` with the port and counts as arguments.
_SUBSCRIBERS = ("import sys; from tactiled_bench.reliability import subscribers_main; "
                "sys.exit(subscribers_main(*sys.argv[1:]))")


def open_fds(pid: int | str = "self") -> int:
    """Open file descriptors of a process (Linux /proc)."""
    return len(os.listdir(f"/proc/{pid}/fd"))


def _total_busy_ticks() -> int:
    """Busy CPU time of the whole machine (all cores), in clock ticks (/proc/stat)."""
    with open("/proc/stat", encoding="ascii") as fh:
        fields = [int(x) for x in fh.readline().split()[1:]]
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)  # idle + iowait
    return sum(fields[:8]) - idle


def _proc_ticks(pid: int) -> int:
    """CPU time of one process (user + system, its threads included), in ticks; 0 if gone."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
            rest = fh.read().rsplit(")", 1)[1].split()
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return 0
    return int(rest[11]) + int(rest[12])


def _run_delay_s(pid: int) -> float:
    """Time the main thread of ``pid`` has spent runnable but waiting for a CPU (s; Linux
    schedstat), 0 if gone or unknown: how much other processes kept it off the CPU."""
    try:
        with open(f"/proc/{pid}/schedstat", encoding="ascii") as fh:
            return int(fh.read().split()[1]) / 1e9
    except (FileNotFoundError, ProcessLookupError, IndexError, ValueError):
        return 0.0


def _tree_ticks(root: int) -> int:
    """CPU time of ``root`` and its live descendants, including the children each has reaped
    (so fit workers replaced meanwhile, reaped by the forkserver, still count), in ticks."""
    parents: dict[int, int] = {}
    ticks: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", encoding="ascii") as fh:
                rest = fh.read().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError, IndexError):
            continue
        pid = int(entry)
        parents[pid] = int(rest[1])
        ticks[pid] = sum(int(x) for x in rest[11:15])  # utime stime cutime cstime
    total = 0
    for pid, t in ticks.items():
        p, seen = pid, 0
        while p and p != root and seen < 64:
            p, seen = parents.get(p, 0), seen + 1
        if p == root:
            total += t
    return total


# -- the simulators -------------------------------------------------------------------------------


def simulator_main(argv: list[str]) -> int:
    """``tactiled simulate ARGV`` (the real command, in this process), which also prints, at
    exit, ``seq runs: {"skipped": [[seq, n], ...], "dropped": [...], "overflowed": [...]}``
    on stderr, so the soak can tell which of the frames missing at the daemon's decoder were
    ever offered to the device (the seq of a frame is its tick index):

    * ``skipped``: behind schedule by more than ``MAX_LAG_S`` (starved), never generated;
    * ``dropped``: refused because the device was full: the last write left bytes pending
      (``EAGAIN``), i.e. the reader had not emptied the pty in time;
    * ``overflowed``: refused by the writer's own limit with the device not full: after a
      starved spell the command queues a catch-up batch of up to ``MAX_BATCH`` (32) frames
      before writing any, and 32 frames of 152 bytes exceed ``PENDING_LIMIT`` (4096), so the
      frames past the 26th of such a batch are dropped without the device being tried.

    ``dropped + overflowed`` is the command's own "dropped (device full)" count and
    ``skipped`` its "skipped"; only the positions and the split are added here."""
    from tactiled_bench.scenes import register_bench_scenes
    from tactiled.cli import main as cli_main
    from tactiled.commands import simulate

    _exit_with_parent()
    register_bench_scenes()  # --scene busy
    runs: dict[str, list[list[int]]] = {"skipped": [], "dropped": [], "overflowed": []}
    tick = [0]  # seq of the next frame handed to the writer

    def add(kind: str, seq: int, n: int) -> None:
        r = runs[kind]
        if r and r[-1][0] + r[-1][1] == seq:
            r[-1][1] += n
        else:
            r.append([seq, n])

    class Schedule(simulate.FrameSchedule):
        def take(self, now: float, limit: int) -> tuple[int, int]:
            first = self.sent
            skip, send = super().take(now, limit)
            if skip:
                add("skipped", first, skip)  # the command calls sim.skip(skip): seqs jump
            tick[0] = first + skip
            return skip, send

    class Writer(simulate.FrameWriter):
        full = False  # the last flush left bytes pending: the device refused them

        def send(self, data: bytes) -> None:
            dropped = self.dropped
            super().send(data)
            if self.dropped != dropped:
                add("dropped" if self.full else "overflowed", tick[0], 1)
            tick[0] += 1

        def flush(self) -> None:
            super().flush()
            self.full = bool(self.pending)

    simulate.FrameSchedule = Schedule  # type: ignore[misc]  # looked up by _serve at run time
    simulate.FrameWriter = Writer  # type: ignore[misc]
    code = cli_main(["simulate", *argv])
    print("seq runs: " + json.dumps(runs), file=sys.stderr, flush=True)
    return code


def _exit_with_parent() -> None:
    """Be sent SIGTERM when the soak process dies (killed by a test's timeout, say), so no
    simulator outlives it (Linux ``prctl(PR_SET_PDEATHSIG)``; elsewhere nothing)."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() == 1:  # the parent is already gone
        os.kill(os.getpid(), signal.SIGTERM)


def _start_simulators(tmp: Path, rate: float, scene: str) -> list[tuple[subprocess.Popen, Path]]:
    sims = []
    for i, _ in enumerate(FINGERS):
        log = tmp / f"sim{i}.log"
        with open(log, "w") as err:
            p = subprocess.Popen(
                [sys.executable, "-c", _SIMULATOR, "--pty", "--link", str(tmp / f"tty{i}"),
                 "--scene", scene, "--rate", repr(rate), "--sensor-id", str(i + 1),
                 "--seed", str(i + 1)],
                stdout=subprocess.PIPE, stderr=err, text=True)
        sims.append((p, log))
    for i, (p, log) in enumerate(sims):
        line = p.stdout.readline() if p.stdout else ""
        if not line.startswith("pty:"):
            _stop_simulators(sims)
            raise RuntimeError(f"simulator {i} did not start: {line!r} {log.read_text()}")
    return sims


def _stop_simulators(sims: list[tuple[subprocess.Popen, Path]]) -> list[dict[str, Any]]:
    for p, _ in sims:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    out = []
    for p, log in sims:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
        if p.stdout:
            p.stdout.close()
        text = log.read_text()
        m, runs = _SUMMARY.search(text), _RUNS.search(text)
        out.append({"sent": int(m[1]), "dropped": int(m[2]), "skipped": int(m[3]),
                    "runs": json.loads(runs[1]) if runs else None} if m else {})
    return out


def _in_range(runs: list[list[int]] | None, lo: int, hi: int) -> int:
    """How many seqs of ``runs`` ([first, count] pairs) fall within ``lo..hi`` inclusive."""
    return sum(max(0, min(hi, s + n - 1) - max(lo, s) + 1) for s, n in runs or ())


# -- the subscribers (a child process) ------------------------------------------------------------


def subscribers_main(port: str, healthy: str, stalled: str, max_rate: str) -> int:
    """Subscribers of ``ws://127.0.0.1:PORT/v1/stream``, driven through stdin / stdout lines.

    ``healthy`` readers (one selector thread) and ``stalled`` never-reading subscribers, all
    asking for the estimates of every sensor at ``max_rate``; a never-reading one the server
    has closed reconnects (within 0.2 s) and stalls again.  Prints ``ready`` once all are
    connected; on ``stop``: stops reconnecting, sends every reader an ``unsubscribe``, waits
    for the confirmations (the server's counters are then final) and prints one JSON line
    (per reader: local port, estimates received, closed; the never-reading ones'
    connections); on ``exit`` (or end of input): closes everything.
    """
    from tactiled_bench.websocket_fanout import Readers, Restaller, Staller

    sub = json.dumps({"type": "subscribe", "streams": ["estimates"],
                      "max_rate": float(max_rate)}).encode()
    stallers = [Staller(int(port), sub) for _ in range(int(stalled))]
    readers = Readers()
    restaller = Restaller(stallers, name="soak-stallers")
    try:
        for s in stallers:
            s.connect()
        for _ in range(int(healthy)):
            readers.add(int(port), sub)
        readers.start()
        restaller.start()
        print("ready", flush=True)
        for line in sys.stdin:
            command = line.strip()
            if command == "exit":
                break
            if command != "stop":
                continue
            restaller.stop()
            # A reader without its confirmation is reported, and counts as failed.
            readers.unsubscribe_all(30.0)
            print(json.dumps({
                "readers": [{"port": c.port, "received": c.total, "closed": c.closed,
                             "unsubscribed": c.unsubscribed} for c in readers.clients],
                "stalled_connects": [s.connects for s in stallers]}), flush=True)
    finally:
        restaller.stop()
        for s in stallers:
            s.close()
        readers.stop()
    return 0


class _Subscribers:
    """The subscriber child process, seen from the soak (asyncio)."""

    def __init__(self, proc: asyncio.subprocess.Process) -> None:
        self.proc = proc

    @classmethod
    async def start(cls, port: int, healthy: int, stalled: int,
                    max_rate: float) -> _Subscribers:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-c", _SUBSCRIBERS, str(port), str(healthy), str(stalled),
            repr(max_rate), stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE)
        self = cls(proc)
        line = await self._line(60.0)
        if line != "ready":
            await self.close()
            raise RuntimeError(f"the subscribers did not start (printed {line!r})")
        return self

    async def _line(self, timeout: float) -> str:
        assert self.proc.stdout is not None
        return (await asyncio.wait_for(self.proc.stdout.readline(), timeout)).decode().strip()

    async def stop(self) -> dict[str, Any]:
        """Unsubscribe the readers (flushing the server's counters); their tallies."""
        assert self.proc.stdin is not None
        self.proc.stdin.write(b"stop\n")
        await self.proc.stdin.drain()
        return json.loads(await self._line(60.0))

    async def close(self) -> None:
        if self.proc.returncode is None:
            try:
                assert self.proc.stdin is not None
                self.proc.stdin.write(b"exit\n")
                await self.proc.stdin.drain()
                self.proc.stdin.close()
                await asyncio.wait_for(self.proc.wait(), 10)
            except (OSError, TimeoutError):
                self.proc.kill()
                await self.proc.wait()


# -- the soak -------------------------------------------------------------------------------------


def _seq_decoder() -> Any:
    """The daemon's own decoder, also keeping the seq of the last frame it delivered (so the
    window's seq range is known exactly)."""
    from tactiled.frames import Frame, FrameDecoder

    class SeqDecoder(FrameDecoder):
        last_seq: int | None = None

        def feed(self, data: bytes, host_time: float | None = None) -> list[Frame]:
            frames = super().feed(data, host_time)
            if frames:
                self.last_seq = frames[-1].seq
            return frames

    return SeqDecoder()


class _LoopLag:
    """How late the service's event loop wakes a task that sleeps 10 ms (the loop reads the
    ptys too: one late by more than ~125 ms lets a 1 kHz finger's pty fill, 15 KB, plus the
    simulator's 4 KB).  Counters only, so a long soak's memory does not grow by them."""

    TICK = 0.01
    EDGES_MS = (10, 25, 50, 100, 125, 250, 1000)

    def __init__(self) -> None:
        self.over = [0] * len(self.EDGES_MS)
        self.ticks = 0
        self.max_ms = 0.0
        self._task: asyncio.Task[None] | None = None
        # Garbage-collector pauses of the service process (every thread waits for them).
        self.gc_runs = [0, 0, 0]
        self.gc_max_ms = [0.0, 0.0, 0.0]
        self.gc_total_ms = 0.0
        self._gc_t0 = 0.0

    def _on_gc(self, phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            self._gc_t0 = time.perf_counter()
            return
        ms = (time.perf_counter() - self._gc_t0) * 1e3
        g = info["generation"]
        self.gc_runs[g] += 1
        self.gc_max_ms[g] = max(self.gc_max_ms[g], ms)
        self.gc_total_ms += ms

    def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="soak-loop-lag")
        gc.callbacks.append(self._on_gc)

    def stop(self) -> None:
        if self._on_gc in gc.callbacks:
            gc.callbacks.remove(self._on_gc)
        if self._task is not None:
            self._task.cancel()
            self._task = None

    async def _run(self) -> None:
        while True:
            t = time.monotonic()
            await asyncio.sleep(self.TICK)
            late = (time.monotonic() - t - self.TICK) * 1e3
            self.ticks += 1
            self.max_ms = max(self.max_ms, late)
            for i, edge in enumerate(self.EDGES_MS):
                if late > edge:
                    self.over[i] += 1

    def figures(self) -> dict[str, Any]:
        return {"ticks": self.ticks, "max_ms": round(self.max_ms, 1),
                **{f"over_{e}ms": n for e, n in zip(self.EDGES_MS, self.over)},
                "gc": {"runs": self.gc_runs, "max_ms": [round(v, 1) for v in self.gc_max_ms],
                       "total_ms": round(self.gc_total_ms)}}


def _heap() -> dict[str, float]:
    """The service's heap figures (:func:`tactiled.heapstats.heap_figures`)."""
    return heap_figures()


class _Series:
    """Rows of floats kept in ``array('d')`` columns: the soak runs in the process it
    measures, so its own records must not grow its heap (a list of per-sample dicts did, by
    ~2 MB an hour of pymalloc's live bytes)."""

    def __init__(self, columns: int) -> None:
        self._cols = [array("d") for _ in range(columns)]

    def append(self, *row: float | None) -> None:
        for col, value in zip(self._cols, row):
            col.append(math.nan if value is None else float(value))

    def __len__(self) -> int:
        return len(self._cols[0])

    def rows(self) -> list[tuple[float | None, ...]]:
        """Every row (NaN back to None), for the report, after the measurement."""
        return [tuple(None if math.isnan(v) else v for v in row) for row in zip(*self._cols)]


#: The columns of a worker's heap series: its answers to the memory request.
_WORKER_HEAP_KEYS = ("rss_anon_mb", "malloc_in_use_mb", "pymalloc_live_mb", "cache_rule_mb",
                     "fits")
#: ... and of the service's.
_SERVICE_HEAP_KEYS = ("pymalloc_arenas", "pymalloc_live_mb", "malloc_in_use_mb",
                      "malloc_free_kept_mb", "rss_anon_mb")


async def _fd_peak(span: float = 1.0, samples: int = 11) -> int:
    """The most descriptors this process had open over ``span`` s: a never-reading subscriber
    between two connections (~0.3 s of its ~7 s cycle) is not counted as a descriptor less,
    so the counts at the warm-up's end and at the end compare like with like."""
    peak = open_fds()
    for _ in range(samples - 1):
        await asyncio.sleep(span / (samples - 1))
        peak = max(peak, open_fds())
    return peak


def _slope_mb_per_h(samples: list[tuple[float, float]]) -> float | None:
    """Least-squares slope of ``(t s, MB)`` samples, MB per hour (None below 3 samples)."""
    if len(samples) < 3:
        return None
    t0 = samples[0][0]
    xs = [t - t0 for t, _ in samples]
    ys = [v for _, v in samples]
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    sxx = sum((x - mx) ** 2 for x in xs)
    return 3600.0 * sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx if sxx else None


async def _soak(tmp: Path, seconds: float, warmup: float, interval: float, subscribers: int,
                stalled: int, max_rate: float, sim_pids: list[int],
                fit_timeout: float | None = None, settle: float = SETTLE_S) -> dict[str, Any]:
    from tactiled.pipeline import Daemon
    from tactiled.settings import load_settings
    from tactiled.sources import open_source

    overrides: dict[str, Any] = {"server.host": "127.0.0.1", "server.port": 0}
    if fit_timeout is not None:
        overrides["fit.timeout"] = fit_timeout
    sources = {}
    for i, name in enumerate(FINGERS):
        url = f"serial://{tmp / f'tty{i}'}"
        overrides[f"sensor[{i}].name"] = name
        overrides[f"sensor[{i}].url"] = url
        overrides[f"sensor[{i}].wire_id"] = i + 1
        sources[name] = open_source(url, decoder=_seq_decoder())
    settings = load_settings(None, {}, overrides)
    service: Any = None
    subs: _Subscribers | None = None
    if subscribers:
        try:
            from tactiled_service.options import ServiceOptions
            from tactiled_service.server import Service
        except ImportError as err:
            raise SystemExit(f"the service is not installed ({err}): run with --subscribers 0")
        # One line per stalled subscriber closed, and per health transition they cause
        # (lost frames make a sensor WARN), would flood the output: both are counted here.
        logging.getLogger("tactiled_service").setLevel(logging.ERROR)
        service = Service(settings, ServiceOptions(max_subscribers=subscribers + stalled + 10),
                          sources=sources)
        await service.start()
        service.settle_heap()  # as tactiled run (tactiled_service.server.serve) does
        daemon = service.daemon
    else:
        daemon = Daemon(settings, sources=sources)
        await daemon.start()
    started = time.monotonic()
    manager = service.ctx.manager if service is not None else None

    def marks() -> dict[str, Any]:
        return {"stats": daemon.stats(),
                "last_seq": {n: daemon.sensors[n].source.decoder.last_seq for n in FINGERS},
                # Most bytes the serial driver's reader thread held for the loop (whole run).
                "read_backlog": {n: getattr(daemon.sensors[n].source, "read_backlog", None)
                                 for n in FINGERS},
                "stalled_closed": manager.stalled if manager is not None else 0,
                "heap": _heap()}

    lag = _LoopLag()
    try:
        if subscribers:
            subs = await _Subscribers.start(service.port, subscribers - stalled, stalled,
                                            max_rate)
        await asyncio.sleep(max(0.0, warmup - 1.0))
        fds_before = await _fd_peak()
        before = marks()
        lag.start()
        t0 = time.monotonic()
        me = os.getpid()
        child = subs.proc.pid if subs is not None else None

        def cpu() -> dict[str, int]:
            return {"machine": _total_busy_ticks(), "tree": _tree_ticks(me),
                    "service": _proc_ticks(me), "simulators": sum(map(_proc_ticks, sim_pids)),
                    "subscribers": _proc_ticks(child) if child else 0}

        cpu0, w0 = cpu(), time.monotonic()
        waits0 = [_run_delay_s(me)] + [_run_delay_s(p) for p in sim_pids]
        base = rss_mb()
        offset = t0 - started
        samples = _Series(2)  # (t, rss)
        samples.append(0.0, base or 0.0)
        fds = array("i", [open_fds()])
        heaps = _Series(1 + len(_SERVICE_HEAP_KEYS))
        heaps.append(0.0, *(before["heap"].get(k) for k in _SERVICE_HEAP_KEYS))
        # per worker pid: (t, rss, anon, file); its own heap answers (t, *_WORKER_HEAP_KEYS),
        # with the whole answer kept twice only: the first after settling and the last
        workers: dict[int, _Series] = {}
        worker_heaps: dict[int, _Series] = {}
        worker_ends: dict[int, list[dict[str, Any] | None]] = {}
        seen_answers: dict[int, float] = {}

        def sample_workers(t: float) -> None:
            pool = daemon.pool
            for w in pool.stats()["workers"]:
                pid, mem, age = w["pid"], w.get("memory"), w.get("memory_age_s")
                if pid and mem is not None and age is not None:
                    answered = round(t - age, 3)
                    if seen_answers.get(pid) != answered:
                        seen_answers[pid] = answered
                        worker_heaps.setdefault(pid, _Series(1 + len(_WORKER_HEAP_KEYS))).append(
                            answered, *(mem.get(k) for k in _WORKER_HEAP_KEYS))
                        ends = worker_ends.setdefault(pid, [None, None])
                        if ends[0] is None and answered + offset >= settle:
                            ends[0] = mem
                        ends[1] = mem
            for pid in pool.pids():
                if pid and (r := rss_mb(pid)) is not None:
                    parts = rss_parts_mb(pid)
                    workers.setdefault(pid, _Series(4)).append(
                        t, r, parts.get("rss_anon_mb"), parts.get("rss_file_mb"))
            pool.request_memory()  # answered after the fit each holds: read next time

        sample_workers(0.0)
        while (elapsed := time.monotonic() - t0) < seconds:
            await asyncio.sleep(min(interval, seconds - elapsed))
            now = time.monotonic() - t0
            samples.append(now, rss_mb() or 0.0)
            fds.append(open_fds())
            heaps.append(now, *(_heap().get(k) for k in _SERVICE_HEAP_KEYS))
            sample_workers(now)
        await asyncio.sleep(min(interval, 1.0))
        sample_workers(time.monotonic() - t0)  # the last answers
        after = marks()
        lag.stop()
        elapsed = time.monotonic() - t0
        cpu1, w1 = cpu(), time.monotonic()
        waits1 = [_run_delay_s(me)] + [_run_delay_s(p) for p in sim_pids]
        fds_after = await _fd_peak()
        delivery: dict[str, Any] | None = None
        if subs is not None:
            tally = await subs.stop()
            by_peer = {s.peer: s.stats() for s in manager.sessions.values()}
            delivery = {"readers": [], "stalled_connects": tally["stalled_connects"],
                        "stalled_closed_total": manager.stalled}
            for c in tally["readers"]:
                srv = by_peer.get(f"127.0.0.1:{c['port']}")
                row = {"received": c["received"], "closed": c["closed"]}
                if srv is not None:
                    # The server's "sent" also counts version, subscribed and unsubscribed.
                    row.update(sent=srv["sent"] - 3, dropped=srv["dropped"])
                delivery["readers"].append(row)
    finally:
        lag.stop()
        if subs is not None:
            await subs.close()
        if service is not None:
            await service.stop()
        else:
            await daemon.stop()
    hz = os.sysconf("SC_CLK_TCK")
    wall = w1 - w0
    use = {k: (cpu1[k] - cpu0[k]) / hz / wall for k in cpu0}
    cores = {"soak": round(use["tree"], 2), "service": round(use["service"], 2),
             "fit_workers": round(max(0.0, use["tree"] - use["service"] - use["simulators"]
                                      - use["subscribers"]), 2),
             "simulators": round(use["simulators"], 2),
             "subscribers": round(use["subscribers"], 2),
             "other_jobs": round(max(0.0, use["machine"] - use["tree"]), 2),
             # Fraction of the time the service's loop thread (and each simulator) was
             # ready to run but waiting for a CPU held by another process.
             "runqueue_wait": {
                 "service": round((waits1[0] - waits0[0]) / wall, 3),
                 "simulators": [round((b - a) / wall, 3)
                                for a, b in zip(waits0[1:], waits1[1:])]}}
    return {"before": before, "after": after, "elapsed": elapsed, "rss": samples.rows(),
            "fds": list(fds), "heaps": heaps.rows(), "offset": offset,
            "worker_heaps": {pid: v.rows() for pid, v in worker_heaps.items()},
            "worker_ends": worker_ends,
            "fds_peak": (fds_before, fds_after),
            "workers_rss": {pid: v.rows() for pid, v in workers.items()},
            "cpu_cores": cores, "delivery": delivery,
            "loop_lag": lag.figures()}


def _sensor_delta(a: dict[str, Any], b: dict[str, Any], elapsed: float) -> dict[str, Any]:
    def d(key: str, sub: str | None = None) -> int:
        return int(a[key][sub] if sub else a[key]) - int(b[key][sub] if sub else b[key])

    frames = d("frames")
    accounted = sum(d(k) for k in ("published", "superseded", "stale_dropped", "fit_failed",
                                   "fit_errors", "wrong_sensor", "bad_shape", "errors"))
    in_hand = int(a["in_hand"]) - int(b["in_hand"])
    rejected = sum(d("decoder", k) for k in ("crc_errors", "length_errors", "version_errors",
                                             "cobs_errors", "truncated", "oversize"))
    return {"frames": frames, "frame_rate_hz": round(frames / elapsed, 1),
            "lost": d("decoder", "lost"), "rejected": rejected,
            "duplicated": d("decoder", "duplicated"), "unaccounted": frames - accounted - in_hand,
            "fits_per_s": round(d("fitted") / elapsed, 1),
            "superseded_per_s": round(d("superseded") / elapsed, 1),
            "disconnects": d("disconnects"), "connected": a["connected"]}


def _attribute(s: dict[str, Any], sim: dict[str, Any], first: int | None, last: int | None,
               elapsed: float) -> None:
    """Add to sensor figures ``s`` who lost its frames, by seq: the window decoded the seqs
    ``first+1 .. last``; the simulator says which of them it skipped and which it dropped."""
    runs = sim.get("runs")
    if first is None or last is None or runs is None:
        s.update(skipped_by_simulator=None, overflowed_in_simulator=None,
                 dropped_device_full=None, daemon_lost=None, sent=None)
        return
    skipped = _in_range(runs["skipped"], first + 1, last)
    dropped = _in_range(runs["dropped"], first + 1, last)
    overflowed = _in_range(runs["overflowed"], first + 1, last)
    # Frames written to the pty in that range: all but those the simulator never offered.
    sent = (last - first) - skipped - overflowed - dropped
    s.update(skipped_by_simulator=skipped, overflowed_in_simulator=overflowed,
             dropped_device_full=dropped, daemon_lost=s["lost"] - skipped - overflowed,
             sent=sent,
             sent_rate_hz=round(sent / elapsed, 1),
             decoded_of_sent=round(s["frames"] / sent, 6) if sent else None)


def default_warmup(seconds: float, subscribers: int) -> float:
    """Warm-up before measuring, s.  Without subscribers 5 s.  With them 60 s: the service's
    message and ellipse caches (``tactiled_service.messages.Encoder``: 1024 entries each,
    filled at the paced rate and the fit rate) take 3-4 MB over the first minute or so, then
    stay (measured: +3.7 MB from 15 s to 75 s after the start, +0.25 MB over the next
    minute); measuring after they are full makes the growth show leaks, not them.  It also
    covers several cycles of the never-reading subscribers (connect, fill the socket
    buffers, stuck for the send timeout, closed, reconnect: ~6 s)."""
    del seconds  # the same for every length: what has to settle does not depend on it
    return 60.0 if subscribers else 5.0


def _worker_figures(series: list[tuple[float, float, float | None, float | None]],
                    heaps: list[tuple[float | None, ...]],
                    ends: list[dict[str, Any] | None], offset: float,
                    settle: float) -> dict[str, Any]:
    """One worker's memory over the soak: RSS (and its anonymous and file parts) at its
    first and last sample, growth, the slope after ``settle`` s since the start (samples are
    ``offset`` s after it), and its own heap figures first after ``settle`` and last
    (``ends``; ``heaps`` rows are ``(t, *_WORKER_HEAP_KEYS)``)."""
    late = [row for row in series if row[0] + offset >= settle]
    slope = _slope_mb_per_h([(t, r) for t, r, _, _ in late])
    first, last = series[0], series[-1]
    return {
        "rss_first": round(first[1], 2), "rss_last": round(last[1], 2),
        "growth": round(max(r for _, r, _, _ in series) - first[1], 2),
        "anon_first": first[2], "anon_last": last[2], "file_first": first[3],
        "file_last": last[3],
        "slope_after_settle_mb_per_h": None if slope is None else round(slope, 2),
        "settled_span_s": round(late[-1][0] - late[0][0], 1) if late else 0.0,
        "samples": len(series),
        "heap_first": ends[0] or ends[1],
        "heap_last": ends[1],
        # [s since the start, RssAnon MB, malloc in use MB, pymalloc live MB, rule cache MB, fits]
        "heap_series": [[round(row[0] + offset), *row[1:]]
                        for row in heaps[::max(1, len(heaps) // 40)]],
    }


def soak(seconds: float, warmup: float | None = None, rate: float = 1000.0,
         scene: str = DEFAULT_SCENE, interval: float | None = None, subscribers: int = 50,
         stalled: int = 5, max_rate: float = 30.0,
         settle: float = SETTLE_S, fit_timeout: float | None = None) -> dict[str, Any]:
    """Run the soak; a JSON-ready result with ``passed`` and the figures."""
    if subscribers < 0 or stalled < 0 or (subscribers and stalled >= subscribers):
        raise ValueError("need subscribers >= 0 and 0 <= stalled < subscribers")
    interval = interval or (1.0 if seconds <= 120 else 5.0)
    warmup = warmup if warmup is not None else default_warmup(seconds, subscribers)
    with tempfile.TemporaryDirectory(prefix="tactiled-soak-") as d:
        tmp = Path(d)
        sims = _start_simulators(tmp, rate, scene)
        try:
            run = asyncio.run(_soak(tmp, seconds, warmup, interval, subscribers, stalled,
                                    max_rate, [p.pid for p, _ in sims], fit_timeout, settle))
        finally:
            simulators = _stop_simulators(sims)
    before, after, elapsed = run["before"], run["after"], run["elapsed"]
    sensors = {}
    for i, name in enumerate(FINGERS):
        s = _sensor_delta(after["stats"]["sensors"][name], before["stats"]["sensors"][name],
                          elapsed)
        _attribute(s, simulators[i], before["last_seq"][name], after["last_seq"][name],
                   elapsed)
        s["read_backlog_bytes"] = after["read_backlog"][name]
        sensors[name] = s
    rss = run["rss"]
    base = rss[0][1]
    growth = max(v for _, v in rss) - base
    offset = run["offset"]
    settled = [(t, v) for t, v in rss if t + offset >= settle]
    slope_settled = _slope_mb_per_h(settled)
    settled_span = settled[-1][0] - settled[0][0] if settled else 0.0
    workers = {str(pid): _worker_figures(v, run["worker_heaps"].get(pid, []),
                                         run["worker_ends"].get(pid, [None, None]), offset,
                                         settle)
               for pid, v in run["workers_rss"].items()}
    worker_growth = {pid: w["growth"] for pid, w in workers.items()}
    fds = run["fds"]
    bw, aw = before["stats"]["workers"], after["stats"]["workers"]
    result: dict[str, Any] = {
        "seconds": round(elapsed, 1), "warmup_s": warmup, "rate_hz": rate, "scene": scene,
        "fit_timeout_s": fit_timeout,
        "cpus": os.cpu_count(), "cpu_cores": run["cpu_cores"],
        "fit_workers": aw["size"],
        "worker_restarts": aw["restarts"] - bw["restarts"],
        "worker_restarts_by_reason": {
            k: v - bw["restarts_by_reason"].get(k, 0)
            for k, v in aw["restarts_by_reason"].items()
            if v - bw["restarts_by_reason"].get(k, 0)},
        "rss_mb": {"after_warmup": round(base, 2), "max": round(max(v for _, v in rss), 2),
                   "last": round(rss[-1][1], 2), "growth": round(growth, 2),
                   "slope_mb_per_h": (None if (s := _slope_mb_per_h(rss)) is None
                                      else round(s, 2)),
                   "settle_s": settle, "settled_span_s": round(settled_span, 1),
                   "slope_after_settle_mb_per_h": (None if slope_settled is None
                                                   else round(slope_settled, 2)),
                   "samples": len(rss), "interval_s": interval,
                   "series": [[round(t), round(v, 2)]
                              for t, v in rss[::max(1, len(rss) // 40)]]},
        "service_loop_lag": run["loop_lag"],
        "heap": {"after_warmup": before["heap"], "end": after["heap"],
                 # [s, pymalloc arenas, pymalloc live MB, malloc in use MB, malloc free kept
                 # MB, RssAnon MB], as the RSS series.
                 "series": [[round(row[0]), *row[1:]]
                            for row in run["heaps"][::max(1, len(run["heaps"]) // 40)]]},
        "fds": {"after_warmup": run["fds_peak"][0], "end": run["fds_peak"][1],
                "growth": run["fds_peak"][1] - run["fds_peak"][0],
                "min": min(fds), "max": max(fds)},
        "workers_rss_growth_mb": worker_growth,
        "workers_memory": workers,
        "sensors": sensors,
        "simulators": [{k: v for k, v in s.items() if k != "runs"} for s in simulators],
        "subscribers": None,
    }
    passed = {
        "rss_growth_under_5MB": growth < RSS_BAR_MB,
        "no_frame_lost_by_the_daemon": all(
            s["daemon_lost"] == 0 and s["dropped_device_full"] == 0 for s in sensors.values()),
        "every_frame_sent_decoded": all(s["sent"] is not None and s["frames"] == s["sent"]
                                        for s in sensors.values()),
        "none_rejected": all(s["rejected"] == 0 and s["duplicated"] == 0
                             for s in sensors.values()),
        "every_frame_accounted": all(s["unaccounted"] == 0 for s in sensors.values()),
        "sensors_connected": all(s["connected"] and s["disconnects"] == 0
                                 for s in sensors.values()),
        "no_fd_leaked": run["fds_peak"][1] <= run["fds_peak"][0],
        "no_worker_restart": result["worker_restarts"] == 0,
    }
    if settled_span >= SLOPE_MIN_SPAN_S:
        # The bar: after the first 5 minutes, the RSS of the service and of every
        # worker grows less than 1 MB per hour (the slope of a line fitted to the samples).
        slopes = [slope_settled] + [w["slope_after_settle_mb_per_h"] for w in workers.values()
                                    if w["settled_span_s"] >= SLOPE_MIN_SPAN_S]
        passed["rss_slope_under_1MB_per_h"] = all(
            v is not None and v < SLOPE_BAR_MB_PER_H for v in slopes)
    if run["delivery"] is not None:
        dv = run["delivery"]
        ratios = []
        for r in dv["readers"]:
            owed = r.get("sent", 0) + r.get("dropped", 0)
            # A reader the server closed, or no longer knows, is a failure.
            ok = not r["closed"] and "sent" in r
            ratios.append(r["received"] / owed if ok and owed else (1.0 if ok else 0.0))
        connects = dv["stalled_connects"]
        result["subscribers"] = {
            "healthy": len(ratios), "stalled": len(connects), "max_rate_hz": max_rate,
            "delivery_min": round(min(ratios), 5) if ratios else None,
            "delivery_median": round(statistics.median(ratios), 5) if ratios else None,
            "healthy_closed": sum(1 for r in dv["readers"] if r["closed"]),
            "received": sum(r["received"] for r in dv["readers"]),
            "server_dropped": sum(r.get("dropped", 0) for r in dv["readers"]),
            "messages_per_s": round(sum(r["received"] for r in dv["readers"])
                                    / (elapsed + warmup), 1),
            "stalled_closed": after["stalled_closed"] - before["stalled_closed"],
            "stalled_closed_total": dv["stalled_closed_total"],
            "stalled_reconnects": sum(connects) - len(connects),
        }
        passed["healthy_delivery_99pct"] = bool(ratios) and min(ratios) >= DELIVERY_BAR
        passed["stalled_closed_and_back"] = (not connects) or (
            result["subscribers"]["stalled_closed"] > 0
            and result["subscribers"]["stalled_reconnects"] > 0)
    result["passed"] = passed
    return result


def _number(v: object) -> bool:
    """A figure the heap lines print (a count or a size; nested tables are left out)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _markdown(r: dict[str, Any]) -> str:
    sub = r["subscribers"]
    who = (f"{sub['healthy']} healthy + {sub['stalled']} never-reading WebSocket subscribers "
           f"(estimates at {sub['max_rate_hz']:g} Hz) on the service" if sub
           else "no subscribers (bare daemon)")
    lines = [f"Soak: {len(FINGERS)} fingers (`tactiled simulate --pty --scene {r['scene']} --rate "
             f"{r['rate_hz']:g}`), {who}; {r['seconds']:g} s measured after {r['warmup_s']:g} s "
             f"of warm-up; {r['fit_workers']} fit workers on {r['cpus']} cores.", "",
             "| finger | frames/s | sent/s | lost | skipped by simulator | overflowed in "
             "simulator | dropped (pty full) | daemon lost | rejected | unaccounted | fits/s | "
             "superseded/s |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, s in r["sensors"].items():
        lines.append(f"| {name} | {s['frame_rate_hz']:g} | {s.get('sent_rate_hz')} | "
                     f"{s['lost']} | {s['skipped_by_simulator']} | "
                     f"{s['overflowed_in_simulator']} | {s['dropped_device_full']} | "
                     f"{s['daemon_lost']} | {s['rejected']} | {s['unaccounted']} | "
                     f"{s['fits_per_s']:g} | {s['superseded_per_s']:g} |")
    m, f = r["rss_mb"], r["fds"]
    lines += ["", f"RSS of the {'service' if sub else 'daemon'}: {m['after_warmup']:.1f} MB after "
              f"warm-up, max {m['max']:.1f} MB, growth {m['growth']:.2f} MB (bar "
              f"{RSS_BAR_MB:g} MB), slope {m['slope_mb_per_h']} MB/h over {m['samples']} "
              f"samples, {m['slope_after_settle_mb_per_h']} MB/h after {m['settle_s']:g} s "
              f"(over {m['settled_span_s']:g} s; bar {SLOPE_BAR_MB_PER_H:g} MB/h when that "
              f"spans {SLOPE_MIN_SPAN_S:g} s); descriptors {f['after_warmup']} -> {f['end']} (most over 1 s; sampled "
              f"min {f['min']}, max {f['max']}); worker RSS growth (MB): "
              f"{r['workers_rss_growth_mb']}; worker "
              f"restarts {r['worker_restarts']} {r['worker_restarts_by_reason']}."]
    for pid, w in r["workers_memory"].items():
        h0, h1 = w["heap_first"] or {}, w["heap_last"] or {}
        lines.append(
            f"Fit worker {pid}: RSS {w['rss_first']} -> {w['rss_last']} MB (anonymous "
            f"{w['anon_first']} -> {w['anon_last']}, file {w['file_first']} -> "
            f"{w['file_last']}), slope after settling {w['slope_after_settle_mb_per_h']} MB/h "
            f"over {w['settled_span_s']:g} s; its heap after settling -> end: " + ", ".join(
                f"{k} {h0[k]:g} -> {h1[k]:g}" for k in h0 if k in h1 and _number(h0[k])) + ".")
    h0, h1 = r["heap"]["after_warmup"], r["heap"]["end"]
    if h0 and h1:
        lines.append("Heap after warm-up -> end: " + ", ".join(
            f"{k} {h0[k]:g} -> {h1[k]:g}" for k in h0 if k in h1 and _number(h0[k])) + ".")
    if sub:
        lines.append(f"Subscribers: delivery min {100 * sub['delivery_min']:.2f} %, median "
                     f"{100 * sub['delivery_median']:.2f} % (bar {100 * DELIVERY_BAR:g} %), "
                     f"{sub['messages_per_s']:g} estimates/s received in all, "
                     f"{sub['server_dropped']} dropped by the server, {sub['healthy_closed']} "
                     f"healthy closed; never-reading closed (1013) {sub['stalled_closed']} "
                     f"times in the window ({sub['stalled_closed_total']} in all), "
                     f"{sub['stalled_reconnects']} reconnections.")
    lag = r["service_loop_lag"]
    lines += [f"CPU (cores, average): {r['cpu_cores']}.",
              f"Event loop of the {'service' if sub else 'daemon'} woken late (10 ms sleeps): "
              f"max {lag['max_ms']:g} ms, > 50 ms {lag['over_50ms']} times, > 125 ms "
              f"{lag['over_125ms']} times of {lag['ticks']}.",
              f"Simulators (whole life, including before the daemon opened their ptys): "
              f"{r['simulators']}", f"Passed: {r['passed']}"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="20 s instead of 10 min")
    p.add_argument("--seconds", type=float, default=None, help="measured duration, s")
    p.add_argument("--warmup", type=float, default=None,
                   help="warm-up before measuring, s (default 60 with subscribers, else 5)")
    p.add_argument("--rate", type=float, default=1000.0, help="frames/s per finger")
    p.add_argument("--scene", default=DEFAULT_SCENE,
                   help=f"simulator scene, looped (default {DEFAULT_SCENE}: keeps the fitter "
                        "busy; demo: mostly gated)")
    p.add_argument("--settle", type=float, default=SETTLE_S,
                   help=f"s after the start from which RSS slopes are judged (default "
                        f"{SETTLE_S:g})")
    p.add_argument("--interval", type=float, default=None, help="RSS sampling period, s")
    p.add_argument("--subscribers", type=int, default=50,
                   help="WebSocket subscribers in all (default 50; 0: the bare daemon)")
    p.add_argument("--stalled", type=int, default=5,
                   help="of which never read (default 5)")
    p.add_argument("--max-rate", type=float, default=30.0,
                   help="subscribers' max_rate, Hz per sensor (default 30, the dashboard's)")
    p.add_argument("--fit-timeout", type=float, default=None,
                   help="fit.timeout for the soak's workers, s (default the daemon's, 1): a "
                        "machine starved by other jobs can hold a fit past 1 s, and a worker "
                        "killed as hung starts its memory series afresh")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    args = p.parse_args(argv)
    if args.subscribers < 0 or args.stalled < 0 or (
            args.subscribers and args.stalled >= args.subscribers):
        p.error("need --subscribers >= 0 and 0 <= --stalled < --subscribers")
    seconds = args.seconds if args.seconds is not None else (20.0 if args.quick else 600.0)
    result = soak(seconds, args.warmup, args.rate, args.scene, args.interval, args.subscribers,
                  args.stalled, args.max_rate, args.settle, args.fit_timeout)
    print(json.dumps(result) if args.json else _markdown(result))
    return 0 if all(result["passed"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())

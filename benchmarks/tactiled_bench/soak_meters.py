"""What the soak measures in the process it runs in: CPU ticks and descriptors (Linux /proc), how
late the event loop wakes, the collector's pauses, heap series kept without growing the heap,
and memory slopes.  Read by :mod:`tactiled_bench.reliability`.
"""

from __future__ import annotations

import asyncio
import gc
import math
import os
import time
from array import array
from typing import Any

from tactiled.heapstats import heap_figures


def open_fds(pid: int | str = "self") -> int:
    """Open file descriptors of a process (Linux /proc)."""
    return len(os.listdir(f"/proc/{pid}/fd"))


def total_busy_ticks() -> int:
    """Busy CPU time of the whole machine (all cores), in clock ticks (/proc/stat)."""
    with open("/proc/stat", encoding="ascii") as fh:
        fields = [int(x) for x in fh.readline().split()[1:]]
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)  # idle + iowait
    return sum(fields[:8]) - idle


def proc_ticks(pid: int) -> int:
    """CPU time of one process (user + system, its threads included), in ticks; 0 if gone."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
            rest = fh.read().rsplit(")", 1)[1].split()
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return 0
    return int(rest[11]) + int(rest[12])


def run_delay_s(pid: int) -> float:
    """Time the main thread of ``pid`` has spent runnable but waiting for a CPU (s; Linux
    schedstat), 0 if gone or unknown: how much other processes kept it off the CPU."""
    try:
        with open(f"/proc/{pid}/schedstat", encoding="ascii") as fh:
            return int(fh.read().split()[1]) / 1e9
    except (FileNotFoundError, ProcessLookupError, IndexError, ValueError):
        return 0.0


def tree_ticks(root: int) -> int:
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


def seq_decoder() -> Any:
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


class LoopLag:
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


def service_heap() -> dict[str, float]:
    """The service's heap figures (:func:`tactiled.heapstats.heap_figures`)."""
    return heap_figures()


class Series:
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
WORKER_HEAP_KEYS = ("rss_anon_mb", "malloc_in_use_mb", "pymalloc_live_mb", "cache_rule_mb",
                     "fits")
#: ... and of the service's.
SERVICE_HEAP_KEYS = ("pymalloc_arenas", "pymalloc_live_mb", "malloc_in_use_mb",
                      "malloc_free_kept_mb", "rss_anon_mb")


async def fd_peak(span: float = 1.0, samples: int = 11) -> int:
    """The most descriptors this process had open over ``span`` s: a never-reading subscriber
    between two connections (~0.3 s of its ~7 s cycle) is not counted as a descriptor less,
    so the counts at the warm-up's end and at the end compare like with like."""
    peak = open_fds()
    for _ in range(samples - 1):
        await asyncio.sleep(span / (samples - 1))
        peak = max(peak, open_fds())
    return peak


def floor_growth_mb(samples: list[tuple[float, float]]) -> float:
    """MB by which ``(t s, MB)`` samples at their least over the second half of their span
    exceed the first sample: what the soak's memory bar judges.

    A leak raises every later sample, the floor with them; what a busy machine adds for a
    while (bytes the serial readers hold while the loop waits for a CPU, messages queued for
    subscribers) raises some samples and is given back (one ``pytest -n 2`` run saw a peak
    9.3 MB above the start, against 2.2 MB in a run alone)."""
    start = samples[0][0]
    half = start + (samples[-1][0] - start) / 2.0
    return min(v for t, v in samples if t >= half) - samples[0][1]


def slope_mb_per_h(samples: list[tuple[float, float]]) -> float | None:
    """Least-squares slope of ``(t s, MB)`` samples, MB per hour (None below 3 samples)."""
    if len(samples) < 3:
        return None
    t0 = samples[0][0]
    xs = [t - t0 for t, _ in samples]
    ys = [v for _, v in samples]
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    sxx = sum((x - mx) ** 2 for x in xs)
    return 3600.0 * sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx if sxx else None

"""The long-running process's garbage-collection policy."""

# Objects that die in reference cycles (a closed WebSocket session: its protocol, transport,
# tasks and the ``Stalled``/``CancelledError`` tracebacks point at each other) are freed only by
# CPython's cyclic collector.  Left to its thresholds, a long-running service collects fully
# only every few minutes, each pass over everything start-up left (30+ MB: FastAPI, pydantic,
# numpy, scipy); dead sessions pile up in between, and pymalloc's arenas, sized for each pile
# and fragmented, are not all given back, so the RSS creeps (docs/performance/reliability.md,
# "Soak").
#
# :func:`settle` moves what start-up left alive into the permanent generation
# (:func:`gc.freeze`), which the collector never scans again, so a full collection weighs only
# what was made since; :func:`collect_every` then runs one every few seconds.

from __future__ import annotations

import asyncio
import gc

#: Seconds between the service's full collections (see the module docstring).
COLLECT_PERIOD_S = 10.0
#: Seconds between returns of malloc's free memory to the system (:func:`trim`).
TRIM_PERIOD_S = 60.0


def settle() -> None:
    """Collect start-up garbage, freeze what is alive, and restart the collector's count.

    Call once, when a process is serving: frozen objects are still freed when their reference
    count drops to zero, but one that later dies in a cycle is never collected, so only what
    lives as long as the process should be frozen.  The last collection (of nothing) resets
    CPython's record of how much lives in the oldest generation, which otherwise still counts
    the frozen objects and holds back its own full collections.
    """
    gc.collect()
    gc.freeze()
    gc.collect()


#: glibc's malloc serves a block of at least this many bytes with its own mmap, returned to the
#: system when freed (see :func:`pin_malloc`), and trims the heap's free top beyond
#: ``TRIM_THRESHOLD`` bytes.
MMAP_THRESHOLD = 256 * 1024
TRIM_THRESHOLD = 1 << 20
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # mallopt's parameter numbers (malloc.h)


def pin_malloc() -> bool:
    """Fix glibc's thresholds (``mallopt``) so that what a process frees goes back to the
    system: blocks of ``MMAP_THRESHOLD`` bytes or more are mmapped and unmapped when freed,
    and the heap's top is trimmed past ``TRIM_THRESHOLD``.  False where there is no glibc.

    Why: by default both thresholds *slide*.  Once a mmapped block is freed, the mmap
    threshold rises to its size (up to 32 MiB) and the trim threshold to twice that, so the
    next blocks of that size come from the heap and stay there when freed.  A fit of a large
    contact builds megabytes of quadrature arrays and frees them, so a worker's RSS jumped by
    up to 10 MB at a time between its periodic trims, and its books stayed flat (the fourth
    soak hour, docs/performance/reliability.md).  Measured in a fresh process: after a 16 MB array, three
    of 8 MB and thirty of 0.8 MB, each freed, glibc kept 23.8 MB by default and 0.08 MB pinned.
    The cost is an mmap and a munmap per such block, microseconds against the milliseconds of
    filling it."""
    from tactiled.heapstats import _libc

    libc = _libc()
    if libc is None or not hasattr(libc, "mallopt"):
        return False
    ok = libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
    return bool(libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1 and ok)


def trim() -> bool:
    """Give the memory glibc's malloc holds free back to the system (``malloc_trim(0)``: the
    heap's top, and the free pages inside every arena); False where there is no glibc.

    Why: after a burst (the loop stalled for seconds on a starved machine, then worked off
    megabytes of buffered frames) malloc keeps what it freed, and its high-water marks showed
    as steps in a long run's RSS while the bytes in use stayed flat (docs/performance/reliability.md,
    "Soak").  A few milliseconds a minute."""
    from tactiled.heapstats import _libc

    libc = _libc()
    if libc is None or not hasattr(libc, "malloc_trim"):
        return False
    libc.malloc_trim(0)
    return True


def serving(period_s: float = COLLECT_PERIOD_S) -> asyncio.Task[None]:
    """The policy of a process that serves from now on (the daemon's, the service's):
    :func:`settle` the start-up heap, :func:`pin_malloc`, and a task running
    :func:`collect_every` (cancel it on the way out).  Call from its event loop."""
    settle()
    pin_malloc()
    return asyncio.create_task(collect_every(period_s), name="tactiled-gc")


async def collect_every(period_s: float = COLLECT_PERIOD_S,
                        trim_period_s: float = TRIM_PERIOD_S) -> None:
    """Run a full collection every ``period_s`` s, and :func:`trim` every ``trim_period_s``
    (in the event loop, until cancelled)."""
    if period_s <= 0 or trim_period_s <= 0:
        raise ValueError(f"periods must be > 0, got {period_s!r}, {trim_period_s!r}")
    since_trim = 0.0
    while True:
        await asyncio.sleep(period_s)
        gc.collect()
        since_trim += period_s
        if since_trim >= trim_period_s:
            since_trim = 0.0
            trim()

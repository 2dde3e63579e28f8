"""The service's garbage-collection policy (tactiled.heap): start-up frozen, dead cycles freed
within a period.  Run in a child process, since freezing would keep the test process's
objects for good."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

from tactiled import heap

CHILD = textwrap.dedent("""
    import asyncio, gc, json, weakref
    from tactiled import heap

    class Node:
        pass

    def cycle():
        a, b = Node(), Node()
        a.other, b.other = b, a   # freed only by the cyclic collector
        a.payload = [0.0] * 1000
        return a

    startup = [[i] for i in range(100_000)]   # what start-up leaves alive (tracked lists)
    heap.settle()
    frozen = gc.get_freeze_count()
    startup_scanned = any(o is startup for o in gc.get_objects())

    async def main():
        # Alive long enough to reach the oldest generation, as a session does.
        node = cycle()
        gc.collect()
        ref = weakref.ref(node)
        del node
        gc.collect(0)
        alive_after_young = ref() is not None
        task = asyncio.create_task(heap.collect_every(0.2))
        waited = 0.0
        while ref() is not None and waited < 5.0:
            await asyncio.sleep(0.05)
            waited += 0.05
        task.cancel()
        return alive_after_young, ref() is None, waited

    alive_after_young, freed, waited = asyncio.run(main())
    print(json.dumps({"frozen": frozen, "startup_scanned": startup_scanned,
                      "alive_after_young": alive_after_young, "freed": freed,
                      "waited": waited}))
""")


def test_startup_is_frozen_and_a_dead_old_cycle_is_freed_within_a_period() -> None:
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True,
                         timeout=60, check=True).stdout
    r = json.loads(out)
    print("FIGURES heap_policy:", r)
    assert r["frozen"] >= 100_000
    assert not r["startup_scanned"], "frozen objects must not be scanned by the collector"
    # The young collections alone do not free a cycle that reached the oldest generation...
    assert r["alive_after_young"]
    # ...the periodic full collection does, within a period (0.2 s) plus scheduling slack.
    assert r["freed"], "the cycle was still alive after 5 s"
    assert r["waited"] <= 1.0


def test_collect_every_refuses_a_period_that_is_not_positive() -> None:
    import asyncio

    with pytest.raises(ValueError, match="periods must be > 0"):
        asyncio.run(heap.collect_every(0.0))


TRIM_CHILD = textwrap.dedent("""
    import json
    from tactiled import heap
    from tactiled.heapstats import malloc_figures, rss_parts_mb

    # 64 KiB blocks come from malloc's heap (under its 128 KiB mmap threshold); freeing all but
    # every 10th leaves ~45 MB free *between* survivors, which malloc keeps: the high-water
    # mark of a burst.
    blocks = [bytearray(65536) for _ in range(800)]
    for b in blocks:
        b[::4096] = b"x" * len(b[::4096])  # touch every page
    survivors = blocks[::10]
    del blocks
    kept = malloc_figures()["malloc_free_kept_mb"]
    before = rss_parts_mb()["rss_anon_mb"]
    trimmed = heap.trim()
    after = rss_parts_mb()["rss_anon_mb"]
    print(json.dumps({"trimmed": trimmed, "kept_mb": kept, "before": before, "after": after,
                      "survivors": len(survivors)}))
""")


def test_trim_gives_a_bursts_free_memory_back_to_the_system() -> None:
    out = subprocess.run([sys.executable, "-c", TRIM_CHILD], capture_output=True, text=True,
                         timeout=60, check=True).stdout
    r = json.loads(out)
    print("FIGURES heap_trim:", r)
    assert r["trimmed"] and r["kept_mb"] > 40  # glibc: the burst's memory was kept
    assert r["before"] - r["after"] > 30, r  # and trim returned most of it

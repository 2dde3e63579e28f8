"""Load: 1000 WebSocket connect/disconnect cycles against a live server, and nothing left behind.

Each cycle opens a real WebSocket to ``/v1/stream`` and reads the version message; most then
subscribe (half of them rate-limited, so both fan-out paths are used: the hub's own
subscription, and the manager's pacing groups) and receive at least one estimate or frame.
Then the client goes, one of four ways in turn: a clean close handshake, an abort (the TCP
connection dropped, no close frame), or, before subscribing, a clean close or an abort.  Ten
cycles run at a time.

The server runs in this process (:class:`~live.LiveServer`, its own thread and loop), so its
resources are this process's.  Measured after 300 warm-up cycles and after the 1000 cycles
that follow, each time with no client connection open (one client event loop throughout, so
its own descriptors count in both) and after ``gc.collect()``:

* open file descriptors (``/proc/self/fd``): back to the warm-up count, exactly, once the server
  has processed the closes (polled for a few seconds);
* the service's own books: stream sessions, pacing groups and their index, hub subscriptions
  and listeners, tasks on the server's loop: back to their baseline;
* live objects of the classes a leak would keep (sessions, subscriptions, pacing groups, the
  server's WebSocket protocol objects, the client's connections), counted with ``gc``: back to
  the warm-up count;
* resident memory (``VmRSS``): less than 5 MB of growth over the 1000 cycles.

What RSS says needs a steady state first.  An idle server's RSS grows ~55 MB in its first
second (lazily loaded kernels, first fits), then ~6 MB while its 10 s counter windows fill,
then stays flat: the cycles start once it has run 12 s.  Then the cycles' own allocations
settle: RSS rose 2.3 MB from cycle 200 to 1000 and nothing more to 2000 (and
``sys.getallocatedblocks()`` flattened likewise): the allocator's pools and the bounded caches
(the encoder's text cache) filling, not a leak; hence 300 warm-up cycles rather than 100,
after which 1000 cycles grew RSS by 0.6 to 2.9 MB.  The Python heap, traced with
``tracemalloc`` in a trial run, stayed flat (2.05, 2.28, 2.24 MB after 300, 600, 900 cycles),
but tracing makes the run 40 times slower, so it is not done here.
"""

from __future__ import annotations

import asyncio
import gc
import json
import os
import time
from collections import Counter
from typing import Any

from live import LiveServer
from svc_helpers import http, recv_json, sim_settings, subscribe, wait_for, ws_connect
from websockets.asyncio.client import ClientConnection

from tactiled.pipeline import Subscription
from tactiled_service.stream import PaceGroup, Session

CYCLES = 1000  # measured, after the warm-up
WARM_UP = 300
CONCURRENCY = 10
#: Kinds of cycle, in turn: how the client leaves.
KINDS = ("clean", "abort", "early_clean", "early_abort")
PACED_RATE_HZ = 200.0  # max_rate of the rate-limited half: messages come at once anyway
MAX_RSS_GROWTH_MB = 5.0
SETTLE_S = 5.0  # how long the server may take to notice the last disconnections
CYCLE_TIMEOUT_S = 5.0  # a cycle takes ~30 ms; a close waiting for its handshake takes 10 s
STEADY_UPTIME_S = 12.0  # see the module docstring

#: Classes whose live instances are counted: what a leaked session would keep.
WATCHED = (Session, Subscription, PaceGroup, ClientConnection)
WATCHED_NAMES = ("StreamProtocol",)  # uvicorn's WebSocket protocol (a class made per server)


def figures(test: str, **values: Any) -> None:
    """One line of measured figures (``pytest -rP`` shows it), as tests/reliability prints."""
    print(f"FIGURES {test}: " + json.dumps(values, sort_keys=True, default=str))


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def rss_mb() -> float:
    with open("/proc/self/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS in /proc/self/status")


def live_objects() -> dict[str, int]:
    """Live instances of the :data:`WATCHED` classes, by class name (after a full collection)."""
    gc.collect()
    counts = Counter(type(o).__name__ for o in gc.get_objects()
                     if isinstance(o, WATCHED) or type(o).__name__ in WATCHED_NAMES)
    return {name: counts.get(name, 0)
            for name in [c.__name__ for c in WATCHED] + list(WATCHED_NAMES)}


def server_books(server: LiveServer) -> dict[str, int]:
    """The service's own counts, read on its loop."""
    def read() -> dict[str, int]:
        manager = server.service.ctx.manager
        hub = server.service.daemon.hub
        return {
            "sessions": len(manager.sessions),
            "pace_groups": len(manager.groups),
            "pace_index": len(manager._index),
            "hub_subscriptions": len(hub.subscriptions),
            "hub_listeners": len(hub._listeners),
            "loop_tasks": len(asyncio.all_tasks()),
        }

    return server.call(read)


async def cycle(url: str, index: int, kinds: Counter[str]) -> None:
    """One connection, left the way ``KINDS[index % 4]`` says; nothing of it is kept."""
    kind = KINDS[index % len(KINDS)]
    paced = (index // len(KINDS)) % 2 == 1
    # No client keepalive: its pings would only add a task per connection to wait for.  An
    # unbounded client queue: with the default (16 messages) the client stops reading the
    # socket once 16 wait unread, so a clean close never sees the server's close frame (queued
    # behind the stream) and ends, 10 s later, as an abort.
    ws = await ws_connect(url, ping_interval=None, max_queue=None)
    try:
        async with asyncio.timeout(CYCLE_TIMEOUT_S):
            try:
                if kind.startswith("early"):
                    assert (await recv_json(ws))["type"] == "version"
                else:
                    await subscribe(ws, streams=["estimates", "frames"],
                                    max_rate=PACED_RATE_HZ if paced else None)
                    assert (await recv_json(ws))["type"] in ("estimate", "frame")
            finally:
                if kind.endswith("abort"):
                    ws.transport.abort()  # no close frame, no FIN exchange: the socket goes
                else:
                    await ws.close()  # the close handshake, then the TCP connection's end
    except TimeoutError:
        ws.transport.abort()
        raise AssertionError(f"cycle {index} ({kind}) took more than {CYCLE_TIMEOUT_S} s "
                             f"(it takes ~30 ms)") from None
    kinds[kind] += 1


async def run_cycles(url: str, first: int, count: int, kinds: Counter[str]) -> None:
    for start in range(first, first + count, CONCURRENCY):
        await asyncio.gather(*(cycle(url, i, kinds)
                               for i in range(start, min(start + CONCURRENCY, first + count))))


def settle(server: LiveServer, books: dict[str, int], fds: int | None) -> None:
    """Wait until the server has processed every disconnection: its books back to ``books``
    and, if given, the open descriptors back to ``fds``."""
    def settled() -> bool:
        return server_books(server) == books and (fds is None or open_fds() <= fds)

    try:
        wait_for(settled, SETTLE_S, poll=0.1, what="server back to its baseline")
    except AssertionError:
        pass  # the asserts below say what is left


def wait_steady(server: LiveServer) -> None:
    def steady() -> bool:
        health = http(server.url, "GET", "/v1/health").json()
        return (health["uptime_s"] or 0.0) >= STEADY_UPTIME_S and all(
            s["published"] > 0 for s in health["sensors"].values())

    wait_for(steady, STEADY_UPTIME_S + 60, poll=0.5, what="server in its steady state")


def measure(server: LiveServer) -> dict[str, Any]:
    # The object count first: its scan (a list of every object) leaves ~1.5 MB in the
    # allocator the first two times it runs, which RSS must not count.
    objects = live_objects()
    return {"objects": objects, "fds": open_fds(), "rss_mb": round(rss_mb(), 2),
            "books": server_books(server)}


def test_1000_websocket_cycles_leave_nothing_behind(live_server, arun):
    server = live_server(sim_settings(1))
    kinds: Counter[str] = Counter()
    wait_steady(server)
    baseline_books = server_books(server)
    live_objects()  # see measure()

    async def main() -> tuple[dict[str, Any], dict[str, Any], float]:
        # One client loop throughout, so its own descriptors count the same in both
        # measurements; measuring blocks it, which is fine: no client connection is open.
        await run_cycles(server.ws_url, 0, WARM_UP, Counter())
        settle(server, baseline_books, None)
        warm = measure(server)
        t0 = time.monotonic()
        await run_cycles(server.ws_url, WARM_UP, CYCLES, kinds)
        seconds = time.monotonic() - t0
        settle(server, baseline_books, warm["fds"])
        return warm, measure(server), seconds

    warm, end, seconds = arun(main(), timeout=600)
    figures("ws_cycles", cycles=CYCLES, warm_up=WARM_UP, concurrency=CONCURRENCY,
            seconds=round(seconds, 1),
            kinds=dict(kinds), fds_warm=warm["fds"], fds_end=end["fds"],
            rss_mb_warm=warm["rss_mb"], rss_mb_end=end["rss_mb"],
            rss_growth_mb=round(end["rss_mb"] - warm["rss_mb"], 2),
            objects_warm=warm["objects"], objects_end=end["objects"], books=end["books"])
    assert sum(kinds.values()) == CYCLES
    assert end["books"] == baseline_books, (end["books"], baseline_books)
    assert warm["books"] == baseline_books, (warm["books"], baseline_books)
    assert end["fds"] <= warm["fds"], f"{end['fds'] - warm['fds']} file descriptors leaked"
    assert end["objects"] == warm["objects"], (end["objects"], warm["objects"])
    growth = end["rss_mb"] - warm["rss_mb"]
    assert growth < MAX_RSS_GROWTH_MB, f"RSS grew {growth:.1f} MB over {CYCLES} cycles"

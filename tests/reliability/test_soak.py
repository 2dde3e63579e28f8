"""Soak: three fingers at 1 kHz over ptys (``tactiled simulate --pty`` processes) into the
real service (daemon + uvicorn) with 50 WebSocket subscribers, 5 of which never read; run by
``python -m tactiled_bench.reliability`` in a process of its own so that its resident memory
is the service's, the subscribers in another (see that module).

Bars, all judged on every run whatever else the machine is doing:

* memory: the service's RSS over the second half of the window stays within 5 MB of its
  value after the warm-up (its least sample there:
  ``tactiled_bench.soak_meters.floor_growth_mb``); its open
  descriptors do not grow;
* acquisition: no frame lost through the daemon's fault.  Frames missing at the decoder are
  attributed by seq with what the simulators record: a simulator starved by other jobs for
  more than a second *skips* the frames it is late for (``skipped_by_simulator``), and one
  starved for a few tens of ms queues a catch-up batch bigger than its own pending limit and
  drops the excess before writing anything (``overflowed_in_simulator``): neither ever
  reached the wire, so neither is the daemon's fault.  One whose pty is full *drops* frames
  (``dropped_device_full``): the daemon did not read in time, its fault.  So ``daemon_lost =
  lost - skipped - overflowed`` must be 0, no frame may be dropped on a full pty, the decoder
  must have decoded every frame written in the window (``decoded == sent``, counted by the
  decoder, whose seqs bound the window: the pipeline may still hold frames of the last read,
  handled in slices), none rejected or duplicated, every frame accounted for by the pipeline,
  no disconnect;
* subscribers: every healthy subscriber gets >= 99 % of what the server owed it (server's own
  counters, after an ``unsubscribe`` flush), none is closed; the never-reading ones are
  closed (1013) and come back.

Memory, on the long runs (samples after the first 5 minutes spanning 10 or more): the RSS of
the service and of every fit worker grows less than 1 MB per hour (the slope of a line fitted
to the samples); each worker's heap figures (asked over the worker protocol) come with them.

The fingers play the ``busy`` scene (``SCENE``): contacts that never hold still, so nearly
every frame needs a fit and the workers are kept busy.

Worker restarts, the CPU used by other jobs, how long the service waited for a CPU and how
late its event loop woke are reported as figures (and in the failure message), not judged:
on a machine whose other jobs keep the service off the CPU for more than ~125 ms at a time,
the acquisition bar fails, and the message says so.  The short version (10 s at 500
frames/s per finger, after a 15 s warm-up, ~30 s in all) always runs; 25 s after a 60 s
warm-up (~1.5 min) and the 10-minute one with ``-m slow``; one hour with
``TACTILED_SOAK_SECONDS=3600 pytest -m slow tests/reliability/test_soak.py``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from rel_helpers import figures
from tactiled_bench.reliability import RSS_BAR_MB
from tactiled_bench.soak_meters import floor_growth_mb

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux ptys and /proc")

LONG = float(os.environ.get("TACTILED_SOAK_SECONDS", "600"))
SUBSCRIBERS, STALLED = 50, 5
#: The fingers' scene: contacts that press, roll, turn and change shape all the time, so the
#: fit workers are busy (tactiled_bench.scenes.busy_scene; the built-in ``moving`` scene of
#: tactiled.sim, once there, is meant for the same and may replace it).
SCENE = "busy"


def _soak(seconds: float, rate_hz: float = 1000.0, scene: str = SCENE,
          warmup: float | None = None) -> dict:
    extra = [] if warmup is None else ["--warmup", repr(warmup)]
    done = subprocess.run([sys.executable, "-m", "tactiled_bench.reliability", "--seconds",
                           repr(seconds), "--subscribers", str(SUBSCRIBERS), "--stalled",
                           str(STALLED), "--rate", repr(rate_hz), "--scene", scene, "--json",
                           *extra],
                          capture_output=True, text=True,
                          timeout=seconds + (warmup or 60.0) + 300, check=False)
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    assert lines, f"no result (exit {done.returncode}): {done.stderr[-2000:]}"
    return json.loads(lines[-1])


def _check(r: dict) -> None:
    rss = {k: v for k, v in r["rss_mb"].items() if k != "series"}
    workers = {pid: {k: v for k, v in w.items() if k != "heap_series"}
               for pid, w in r["workers_memory"].items()}
    figures(f"soak[{r['seconds']:g} s, {r['scene']}]", rss_mb=rss, fds=r["fds"],
            sensors=r["sensors"], subscribers=r["subscribers"],
            worker_restarts=r["worker_restarts_by_reason"], heap=r["heap"]["end"],
            workers_rss_growth_mb=r["workers_rss_growth_mb"], workers_memory=workers,
            simulators=r["simulators"],
            cpu_cores=r["cpu_cores"], service_loop_lag=r["service_loop_lag"],
            passed=r["passed"])
    problems = []
    if not r["rss_mb"]["floor_growth"] < RSS_BAR_MB:
        problems.append(f"service RSS: its least sample over the window's second half is "
                        f"{r['rss_mb']['floor_growth']} MB above the window's first (bar "
                        f"{RSS_BAR_MB:g} MB): {r['rss_mb']}")
    if r["passed"].get("rss_slope_under_1MB_per_h") is False:
        slopes = {"service": r["rss_mb"]["slope_after_settle_mb_per_h"],
                  **{pid: w["slope_after_settle_mb_per_h"]
                     for pid, w in r["workers_memory"].items()}}
        problems.append(f"RSS slope after {r['rss_mb']['settle_s']:g} s over 1 MB/h: {slopes}")
    if r["fds"]["end"] > r["fds"]["after_warmup"]:
        problems.append(f"descriptors grew: {r['fds']}")
    for name, s in r["sensors"].items():
        if not (s["connected"] and s["disconnects"] == 0):
            problems.append(f"{name}: disconnected {s}")
        if s["unaccounted"] or s["rejected"] or s["duplicated"]:
            problems.append(f"{name}: unaccounted {s['unaccounted']}, rejected "
                            f"{s['rejected']}, duplicated {s['duplicated']}")
        if s["daemon_lost"] != 0 or s["dropped_device_full"] != 0:
            problems.append(
                f"{name}: {s['daemon_lost']} frame(s) lost by the daemon ({s['lost']} lost, "
                f"{s['skipped_by_simulator']} of them skipped by the starved simulator, "
                f"{s['overflowed_in_simulator']} never written by it (catch-up batch over "
                f"its pending limit); {s['dropped_device_full']} dropped because the pty was "
                f"full); other jobs used {r['cpu_cores']['other_jobs']} cores, the service "
                f"waited for a CPU {r['cpu_cores']['runqueue_wait']['service']:.0%} of the "
                f"time; its loop woke > 125 ms "
                f"late {r['service_loop_lag']['over_125ms']} times, max "
                f"{r['service_loop_lag']['max_ms']} ms")
        if s["sent"] is None or s["decoded"] != s["sent"]:
            problems.append(f"{name}: decoded {s['decoded']} of {s['sent']} frames sent")
    sub = r["subscribers"]
    if sub is None:
        problems.append("no subscribers")
    else:
        if sub["healthy"] != SUBSCRIBERS - STALLED or sub["delivery_min"] < 0.99:
            problems.append(f"healthy subscribers: {sub['healthy']}, delivery min "
                            f"{sub['delivery_min']} (bar 0.99), median "
                            f"{sub['delivery_median']}, server dropped {sub['server_dropped']}")
        if sub["healthy_closed"]:
            problems.append(f"{sub['healthy_closed']} healthy subscriber(s) closed")
        if not (sub["stalled_closed"] > 0 and sub["stalled_reconnects"] > 0):
            problems.append(f"never-reading subscribers not closed and back: {sub}")
    assert not problems, "\n".join(problems)


def test_the_memory_bar_sees_a_leak_not_a_peak() -> None:
    """A leak of 1 MB/s fails the bar; a 9 MB peak given back, and caches that settle, pass."""
    leak = [(t, 100.0 + t) for t in range(11)]
    peak = [(t, 100.0 + (9.0 if 3 <= t <= 6 else 0.5 * (t > 0))) for t in range(11)]
    caches = [(t, 100.0 + min(t, 3) * 0.7) for t in range(11)]
    assert floor_growth_mb(leak) == 5.0 and not floor_growth_mb(leak) < RSS_BAR_MB
    assert floor_growth_mb(peak) == 0.5
    assert floor_growth_mb(caches) == pytest.approx(2.1)


@pytest.mark.parametrize("seconds, warmup", [
    (10.0, 15.0), pytest.param(25.0, None, marks=pytest.mark.slow)])
def test_soak_short(seconds: float, warmup: float | None) -> None:
    """The always-on version: 10 s at 500 frames/s per finger after a 15 s warm-up (several
    cycles of the never-reading subscribers; the service's caches, still filling, added
    2.2 MB in the run measured, under the 5 MB bar); with ``-m slow`` 25 s after the full 60 s warm-up.  At
    1 kHz the 2-core CI machine (its own load counted as 0.8 core of "other jobs") lost ~8 %
    of the frames on full ptys; half the rate doubles the time a pty can hold (270 ms)
    through a stalled loop, so every bar stays judged.  The 10-minute and 1-hour versions run
    at the issue's 1 kHz."""
    _check(_soak(seconds, rate_hz=500.0, warmup=warmup))


@pytest.mark.slow
@pytest.mark.timeout(LONG + 900)
def test_soak_long() -> None:
    _check(_soak(LONG))

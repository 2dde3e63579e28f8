"""The soak: three simulated fingers at 1 kHz over real ptys into the full service, with
WebSocket subscribers of which some never read, for minutes or hours (the bars and the runs:
docs/performance/reliability.md, "Soak").

    python -m tactiled_bench.reliability --quick          # 20 s (after a 60 s warm-up)
    python -m tactiled_bench.reliability --seconds 3600   # 1 h (the slope bar: after 5 min)
    python -m tactiled_bench.reliability --quick --json   # one JSON object (what the test reads)
"""
# This process runs the service and nothing else, so its resident memory is the service's; the
# simulators and the subscribers are child processes (tactiled_bench.soak_children), and what it
# samples is in tactiled_bench.soak_meters.  After --warmup s it measures for --seconds: the RSS
# and heap books of the service and of every fit worker (growth, and the slope after --settle
# s), open descriptors, per finger the frames lost by the daemon (told apart by seq from those a
# starved simulator never wrote), every subscriber's delivery and the never-reading ones'
# closes, CPU, and how late the event loop woke.  soak() returns the figures with each bar's
# verdict (passed).  More runs:
#   python -m tactiled_bench.reliability                  # 10 min
#   python -m tactiled_bench.reliability --scene demo     # the demo scene (mostly gated)
#   python -m tactiled_bench.reliability --subscribers 0  # acquisition only (the bare daemon)

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import statistics
import sys
import tempfile
import time
from array import array
from pathlib import Path
from typing import Any

from tactiled.heapstats import rss_mb, rss_parts_mb
from tactiled_bench.soak_children import FINGERS, Subscribers, in_range, start_simulators, stop_simulators
from tactiled_bench.soak_meters import (SERVICE_HEAP_KEYS, WORKER_HEAP_KEYS, LoopLag, Series, fd_peak,
                                        open_fds, proc_ticks, run_delay_s, seq_decoder,
                                        service_heap, slope_mb_per_h, total_busy_ticks, tree_ticks,
                                        floor_growth_mb)

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


# -- the soak -------------------------------------------------------------------------------------


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
        sources[name] = open_source(url, decoder=seq_decoder())
    settings = load_settings(None, {}, overrides)
    service: Any = None
    subs: Subscribers | None = None
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
                # Frames the decoder delivered: the seqs above are its, and the pipeline may
                # hold some of them still (a long read is handled in slices).
                "decoded": {n: daemon.sensors[n].source.decoder.stats.frames for n in FINGERS},
                # Most bytes the serial driver's reader thread held for the loop (whole run).
                "read_backlog": {n: getattr(daemon.sensors[n].source, "read_backlog", None)
                                 for n in FINGERS},
                "stalled_closed": manager.stalled if manager is not None else 0,
                "heap": service_heap()}

    lag = LoopLag()
    try:
        if subscribers:
            subs = await Subscribers.start(service.port, subscribers - stalled, stalled,
                                            max_rate)
        await asyncio.sleep(max(0.0, warmup - 1.0))
        fds_before = await fd_peak()
        before = marks()
        lag.start()
        t0 = time.monotonic()
        me = os.getpid()
        child = subs.proc.pid if subs is not None else None

        def cpu() -> dict[str, int]:
            return {"machine": total_busy_ticks(), "tree": tree_ticks(me),
                    "service": proc_ticks(me), "simulators": sum(map(proc_ticks, sim_pids)),
                    "subscribers": proc_ticks(child) if child else 0}

        cpu0, w0 = cpu(), time.monotonic()
        waits0 = [run_delay_s(me)] + [run_delay_s(p) for p in sim_pids]
        base = rss_mb()
        offset = t0 - started
        samples = Series(2)  # (t, rss)
        samples.append(0.0, base or 0.0)
        fds = array("i", [open_fds()])
        heaps = Series(1 + len(SERVICE_HEAP_KEYS))
        heaps.append(0.0, *(before["heap"].get(k) for k in SERVICE_HEAP_KEYS))
        # per worker pid: (t, rss, anon, file); its own heap answers (t, *WORKER_HEAP_KEYS),
        # with the whole answer kept twice only: the first after settling and the last
        workers: dict[int, Series] = {}
        worker_heaps: dict[int, Series] = {}
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
                        worker_heaps.setdefault(pid, Series(1 + len(WORKER_HEAP_KEYS))).append(
                            answered, *(mem.get(k) for k in WORKER_HEAP_KEYS))
                        ends = worker_ends.setdefault(pid, [None, None])
                        if ends[0] is None and answered + offset >= settle:
                            ends[0] = mem
                        ends[1] = mem
            for pid in pool.pids():
                if pid and (r := rss_mb(pid)) is not None:
                    parts = rss_parts_mb(pid)
                    workers.setdefault(pid, Series(4)).append(
                        t, r, parts.get("rss_anon_mb"), parts.get("rss_file_mb"))
            pool.request_memory()  # answered after the fit each holds: read next time

        sample_workers(0.0)
        while (elapsed := time.monotonic() - t0) < seconds:
            await asyncio.sleep(min(interval, seconds - elapsed))
            now = time.monotonic() - t0
            samples.append(now, rss_mb() or 0.0)
            fds.append(open_fds())
            heaps.append(now, *(service_heap().get(k) for k in SERVICE_HEAP_KEYS))
            sample_workers(now)
        await asyncio.sleep(min(interval, 1.0))
        sample_workers(time.monotonic() - t0)  # the last answers
        after = marks()
        lag.stop()
        elapsed = time.monotonic() - t0
        cpu1, w1 = cpu(), time.monotonic()
        waits1 = [run_delay_s(me)] + [run_delay_s(p) for p in sim_pids]
        fds_after = await fd_peak()
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
    skipped = in_range(runs["skipped"], first + 1, last)
    dropped = in_range(runs["dropped"], first + 1, last)
    overflowed = in_range(runs["overflowed"], first + 1, last)
    # Frames written to the pty in that range: all but those the simulator never offered.
    sent = (last - first) - skipped - overflowed - dropped
    s.update(skipped_by_simulator=skipped, overflowed_in_simulator=overflowed,
             dropped_device_full=dropped, daemon_lost=s["lost"] - skipped - overflowed,
             sent=sent,
             sent_rate_hz=round(sent / elapsed, 1),
             decoded_of_sent=round(s["decoded"] / sent, 6) if sent else None)


def default_warmup(seconds: float, subscribers: int) -> float:
    """Warm-up before measuring, s.  Without subscribers 5 s.  With them 60 s: the service's
    message and ellipse caches (``tactiled_service.json_messages.Encoder``: 1024 entries each,
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
    (``ends``; ``heaps`` rows are ``(t, *WORKER_HEAP_KEYS)``)."""
    late = [row for row in series if row[0] + offset >= settle]
    slope = slope_mb_per_h([(t, r) for t, r, _, _ in late])
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
        sims = start_simulators(tmp, rate, scene)
        try:
            run = asyncio.run(_soak(tmp, seconds, warmup, interval, subscribers, stalled,
                                    max_rate, [p.pid for p, _ in sims], fit_timeout, settle))
        finally:
            simulators = stop_simulators(sims)
    before, after, elapsed = run["before"], run["after"], run["elapsed"]
    sensors = {}
    for i, name in enumerate(FINGERS):
        s = _sensor_delta(after["stats"]["sensors"][name], before["stats"]["sensors"][name],
                          elapsed)
        s["decoded"] = after["decoded"][name] - before["decoded"][name]
        _attribute(s, simulators[i], before["last_seq"][name], after["last_seq"][name],
                   elapsed)
        s["read_backlog_bytes"] = after["read_backlog"][name]
        sensors[name] = s
    rss = run["rss"]
    base = rss[0][1]
    growth = max(v for _, v in rss) - base
    offset = run["offset"]
    settled = [(t, v) for t, v in rss if t + offset >= settle]
    slope_settled = slope_mb_per_h(settled)
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
                   "floor_growth": round(floor_growth_mb(rss), 2),
                   "slope_mb_per_h": (None if (s := slope_mb_per_h(rss)) is None
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
        "rss_floor_under_5MB": floor_growth_mb(rss) < RSS_BAR_MB,
        "no_frame_lost_by_the_daemon": all(
            s["daemon_lost"] == 0 and s["dropped_device_full"] == 0 for s in sensors.values()),
        "every_frame_sent_decoded": all(s["sent"] is not None and s["decoded"] == s["sent"]
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
              f"warm-up, max {m['max']:.1f} MB, growth {m['growth']:.2f} MB, least over the "
              f"second half {m['floor_growth']:+.2f} MB (bar {RSS_BAR_MB:g} MB), slope {m['slope_mb_per_h']} MB/h over {m['samples']} "
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

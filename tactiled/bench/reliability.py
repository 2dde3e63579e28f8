"""Acquisition soak: three simulated fingers at 1 kHz over real ptys, for minutes or hours.

Each finger is a ``tactiled simulate --pty`` process streaming a looping scene at ``--rate`` Hz;
this process runs the daemon (``serial://`` sensors with pyserial, the fit worker pool, the hub)
and nothing else, so its resident memory is the daemon's.  After ``--warmup`` seconds the run is
measured for ``--seconds``:

* memory: the daemon's RSS (and each fit worker's) sampled every ``--interval`` s; growth =
  the largest sample minus the one at the end of the warm-up, and a least-squares slope;
* acquisition: per finger, frames decoded, frames lost (gaps in seq seen by the decoder: the
  simulator skips frames when it is starved and drops them when the pty is full, so a daemon
  that falls behind shows here), chunks rejected, and frames not accounted for by the pipeline
  (``frames - published - superseded - ...``, corrected for a frame waiting or in flight).

Bars (docs/reliability.md): growth under 5 MB, no frame lost or rejected, none unaccounted.
The REST/WebSocket subscribers are not part of this run (the service has its own soak).

    python -m tactiled.bench.reliability --quick          # 20 s
    python -m tactiled.bench.reliability                  # 10 min
    python -m tactiled.bench.reliability --seconds 3600   # 1 h
    python -m tactiled.bench.reliability --quick --json   # one JSON object (what the test reads)
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

FINGERS = ("thumb", "index", "middle")
RSS_BAR_MB = 5.0
_SUMMARY = re.compile(r"sent (\d+) frame\(s\), dropped (\d+) \(device full\), skipped (\d+)")


def rss_mb(pid: int | str = "self") -> float | None:
    """Resident set size of a process in MiB (Linux /proc), None if it is gone."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None


def _total_busy_ticks() -> int:
    """Busy CPU time of the whole machine (all cores), in clock ticks (/proc/stat)."""
    with open("/proc/stat", encoding="ascii") as fh:
        fields = [int(x) for x in fh.readline().split()[1:]]
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)  # idle + iowait
    return sum(fields[:8]) - idle


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


def _start_simulators(tmp: Path, rate: float, scene: str) -> list[tuple[subprocess.Popen, Path]]:
    sims = []
    for i, _ in enumerate(FINGERS):
        log = tmp / f"sim{i}.log"
        with open(log, "w") as err:
            p = subprocess.Popen(
                [sys.executable, "-m", "tactiled.cli", "simulate", "--pty", "--link",
                 str(tmp / f"tty{i}"), "--scene", scene, "--rate", repr(rate), "--sensor-id",
                 str(i + 1), "--seed", str(i + 1)],
                stdout=subprocess.PIPE, stderr=err, text=True)
        sims.append((p, log))
    for i, (p, log) in enumerate(sims):
        line = p.stdout.readline() if p.stdout else ""
        if not line.startswith("pty:"):
            _stop_simulators(sims)
            raise RuntimeError(f"simulator {i} did not start: {line!r} {log.read_text()}")
    return sims


def _stop_simulators(sims: list[tuple[subprocess.Popen, Path]]) -> list[dict[str, int]]:
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
        m = _SUMMARY.search(log.read_text())
        out.append({"sent": int(m[1]), "dropped": int(m[2]), "skipped": int(m[3])} if m else {})
    return out


def _slope_mb_per_h(samples: list[tuple[float, float]]) -> float | None:
    if len(samples) < 3:
        return None
    t0 = samples[0][0]
    xs = [t - t0 for t, _ in samples]
    ys = [v for _, v in samples]
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    sxx = sum((x - mx) ** 2 for x in xs)
    return 3600.0 * sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx if sxx else None


async def _soak(tmp: Path, seconds: float, warmup: float, interval: float) -> dict[str, Any]:
    from tactiled.pipeline import Daemon
    from tactiled.settings import load_settings

    overrides: dict[str, Any] = {}
    for i, name in enumerate(FINGERS):
        overrides[f"sensor[{i}].name"] = name
        overrides[f"sensor[{i}].url"] = f"serial://{tmp / f'tty{i}'}"
        overrides[f"sensor[{i}].wire_id"] = i + 1
    daemon = Daemon(load_settings(None, {}, overrides))
    await daemon.start()
    try:
        await asyncio.sleep(warmup)
        before = daemon.stats()
        t0 = time.monotonic()
        cpu0 = (_total_busy_ticks(), _tree_ticks(os.getpid()), time.monotonic())
        base = rss_mb()
        samples: list[tuple[float, float]] = [(0.0, base or 0.0)]
        workers: dict[int, list[float]] = {}
        while (elapsed := time.monotonic() - t0) < seconds:
            await asyncio.sleep(min(interval, seconds - elapsed))
            samples.append((time.monotonic() - t0, rss_mb() or 0.0))
            for pid in daemon.pool.pids():
                if pid and (r := rss_mb(pid)) is not None:
                    workers.setdefault(pid, []).append(r)
        after = daemon.stats()
        elapsed = time.monotonic() - t0
        cpu1 = (_total_busy_ticks(), _tree_ticks(os.getpid()), time.monotonic())
    finally:
        await daemon.stop()
    hz = os.sysconf("SC_CLK_TCK")
    wall = cpu1[2] - cpu0[2]
    ours = (cpu1[1] - cpu0[1]) / hz / wall
    other = max(0.0, (cpu1[0] - cpu0[0]) / hz / wall - ours)
    return {"before": before, "after": after, "elapsed": elapsed, "rss": samples,
            "workers_rss": workers, "cpu_cores": {"soak": round(ours, 2),
                                                  "other_jobs": round(other, 2)}}


def _sensor_delta(a: dict[str, Any], b: dict[str, Any], elapsed: float) -> dict[str, Any]:
    def d(key: str, sub: str | None = None) -> int:
        return int(a[key][sub] if sub else a[key]) - int(b[key][sub] if sub else b[key])

    frames = d("frames")
    accounted = sum(d(k) for k in ("published", "superseded", "stale_dropped", "fit_failed",
                                   "fit_errors", "wrong_sensor", "bad_shape", "errors"))
    in_hand = (int(a["waiting"]) + int(a["in_flight"])) - (int(b["waiting"]) + int(b["in_flight"]))
    rejected = sum(d("decoder", k) for k in ("crc_errors", "length_errors", "version_errors",
                                             "cobs_errors", "truncated", "oversize"))
    return {"frames": frames, "frame_rate_hz": round(frames / elapsed, 1),
            "lost": d("decoder", "lost"), "rejected": rejected,
            "duplicated": d("decoder", "duplicated"), "unaccounted": frames - accounted - in_hand,
            "fits_per_s": round(d("fitted") / elapsed, 1),
            "superseded_per_s": round(d("superseded") / elapsed, 1),
            "disconnects": d("disconnects"), "connected": a["connected"]}


def soak(seconds: float, warmup: float = 5.0, rate: float = 1000.0, scene: str = "demo",
         interval: float | None = None) -> dict[str, Any]:
    """Run the soak; a JSON-ready result with ``passed`` and the figures."""
    interval = interval or (1.0 if seconds <= 120 else 5.0)
    with tempfile.TemporaryDirectory(prefix="tactiled-soak-") as d:
        tmp = Path(d)
        sims = _start_simulators(tmp, rate, scene)
        try:
            run = asyncio.run(_soak(tmp, seconds, warmup, interval))
        finally:
            simulators = _stop_simulators(sims)
    before, after, elapsed = run["before"], run["after"], run["elapsed"]
    sensors = {name: _sensor_delta(after["sensors"][name], before["sensors"][name], elapsed)
               for name in FINGERS}
    rss = run["rss"]
    base = rss[0][1]
    growth = max(v for _, v in rss) - base
    worker_growth = {str(pid): round(max(v) - v[0], 2) for pid, v in run["workers_rss"].items()}
    result = {
        "seconds": round(elapsed, 1), "warmup_s": warmup, "rate_hz": rate, "scene": scene,
        "cpus": os.cpu_count(), "cpu_cores": run["cpu_cores"],
        "fit_workers": after["workers"]["size"],
        "worker_restarts": after["workers"]["restarts"] - before["workers"]["restarts"],
        "worker_restarts_by_reason": {
            k: v - before["workers"]["restarts_by_reason"].get(k, 0)
            for k, v in after["workers"]["restarts_by_reason"].items()
            if v - before["workers"]["restarts_by_reason"].get(k, 0)},
        "rss_mb": {"after_warmup": round(base, 2), "max": round(max(v for _, v in rss), 2),
                   "last": round(rss[-1][1], 2), "growth": round(growth, 2),
                   "slope_mb_per_h": (None if (s := _slope_mb_per_h(rss)) is None
                                      else round(s, 2)),
                   "samples": len(rss), "interval_s": interval},
        "workers_rss_growth_mb": worker_growth,
        "sensors": sensors,
        "simulators": simulators,
    }
    result["passed"] = {
        "rss_growth_under_5MB": growth < RSS_BAR_MB,
        "no_frame_lost": all(s["lost"] == 0 and s["rejected"] == 0 for s in sensors.values()),
        "every_frame_accounted": all(s["unaccounted"] == 0 for s in sensors.values()),
        "no_worker_restart": result["worker_restarts"] == 0,
    }
    return result


def _markdown(r: dict[str, Any]) -> str:
    lines = [f"Soak: {len(FINGERS)} fingers (`tactiled simulate --pty --scene {r['scene']} --rate "
             f"{r['rate_hz']:g}`), {r['seconds']:g} s measured after {r['warmup_s']:g} s of "
             f"warm-up; {r['fit_workers']} fit workers on {r['cpus']} cores.", "",
             "| finger | frames/s | lost | rejected | duplicated | unaccounted | fits/s | "
             "superseded/s |", "|---|---|---|---|---|---|---|---|"]
    for name, s in r["sensors"].items():
        lines.append(f"| {name} | {s['frame_rate_hz']:g} | {s['lost']} | {s['rejected']} | "
                     f"{s['duplicated']} | {s['unaccounted']} | {s['fits_per_s']:g} | "
                     f"{s['superseded_per_s']:g} |")
    m = r["rss_mb"]
    lines += ["", f"Daemon RSS: {m['after_warmup']:.1f} MB after warm-up, max {m['max']:.1f} MB, "
              f"growth {m['growth']:.2f} MB (bar {RSS_BAR_MB:g} MB), slope "
              f"{m['slope_mb_per_h']} MB/h over {m['samples']} samples; worker RSS growth (MB): "
              f"{r['workers_rss_growth_mb']}; worker restarts {r['worker_restarts']} "
              f"{r['worker_restarts_by_reason']}.",
              f"CPU (cores, average): this soak {r['cpu_cores']['soak']}, other jobs on the "
              f"machine {r['cpu_cores']['other_jobs']}.",
              f"Simulators: {r['simulators']}", f"Passed: {r['passed']}"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="20 s instead of 10 min")
    p.add_argument("--seconds", type=float, default=None, help="measured duration, s")
    p.add_argument("--warmup", type=float, default=5.0, help="warm-up before measuring, s")
    p.add_argument("--rate", type=float, default=1000.0, help="frames/s per finger")
    p.add_argument("--scene", default="demo", help="simulator scene (looped)")
    p.add_argument("--interval", type=float, default=None, help="RSS sampling period, s")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    args = p.parse_args(argv)
    seconds = args.seconds if args.seconds is not None else (20.0 if args.quick else 600.0)
    result = soak(seconds, args.warmup, args.rate, args.scene, args.interval)
    print(json.dumps(result) if args.json else _markdown(result))
    return 0 if all(result["passed"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())

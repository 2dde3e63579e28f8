"""ROS 2 topics against the JSON on Zenoh: estimates delivered, and the daemon's CPU per frame.

    python -m tactiled_bench.ros2_fanout [--quick] [--sensors 3] [--rate 1000] [--seconds 10]

Starts ``tactiled run --ros2`` (simulated fingers on Zenoh, peer mode on loopback) and
alternates four phases over ``--rounds``, one Zenoh client session of this process
subscribing: idle, json, ros2, both.  Per phase: delivered/s against published/s, ROS gaps,
latency p50/p99, and the daemon's CPU per frame over the idle phase's (what publishing costs).
"""
# Phases:
# * idle: no subscriber (the bus and the ROS node skip a topic no one matches): the baseline;
# * json: every sensor's JSON estimates (<prefix>/*/estimate);
# * ros2: every sensor's tactiled_msgs/Contact (one per estimate, rmw_zenoh's key expressions);
# * both: the JSON estimates and every ROS topic of the estimates (wrench, contact, contacts,
#   markers).
# delivered/s counts Contact messages for ROS; published/s is the pipeline's counters over the
# phase.  ROS gaps: rmw_zenoh attachment sequence numbers (consecutive per publisher) never seen
# (the JSON has no such number: an estimate's seq skips frames superseded while waiting for a
# fit).  Latency: frame arrival -> received (JSON: host_time, monotonic; ROS: header.stamp,
# wall clock, same machine).  Daemon CPU per frame: the daemon process's CPU time (not its fit
# workers) over the frames it processed; "added" is that minus the idle phase's.
# Samples queue in Zenoh's own channel (Rust, no GIL) and are counted by a thread, so the
# subscriber keeps up; a ROS message's stamp is the two integers after the CDR encapsulation
# header (builtin_interfaces/Time is the first field of every stamped message).

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tactiled_bench.websocket_fanout import _number_after, cpu_seconds, health
from tactiled_bench.zenoh_fanout import CONFIG, PREFIX, SENSOR, free_port

PHASES = ("idle", "json", "ros2", "both")
ROS2_CONFIG = """
[ros2]
enabled = true
"""
_STAMP = struct.Struct("<iI")  # builtin_interfaces/Time: int32 sec, uint32 nanosec


@dataclass
class Seen:
    """What the subscriber received in one phase."""

    json: int = 0
    contacts: int = 0
    ros_other: int = 0
    ros_seqs: dict[str, list[int]] = field(default_factory=lambda: defaultdict(list))
    latency_ms: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))


class Subscriber:
    """One client session; :meth:`phase` declares the phase's subscribers and counts."""

    def __init__(self, endpoint: str) -> None:
        import zenoh  # the zenoh extra: main() says so when it is missing

        self.zenoh = zenoh
        cfg = zenoh.Config()
        cfg.insert_json5("mode", '"client"')
        cfg.insert_json5("scouting/multicast/enabled", "false")
        cfg.insert_json5("connect/endpoints", json.dumps([endpoint]))
        self.session = zenoh.open(cfg)

    def phase(self, name: str, seconds: float, settle: float,
              mark: Callable[[], None]) -> Seen:
        """Subscribe, wait ``settle`` s, count for ``seconds`` s; ``mark()`` is called when
        counting starts and when it stops (to read the daemon's counters and CPU)."""
        keys = {"idle": [], "json": [f"{PREFIX}/*/estimate"],
                "ros2": ["0/tactiled/*/contact/**"],
                "both": [f"{PREFIX}/*/estimate", "0/tactiled/*/*/**"]}[name]
        subs = [self.session.declare_subscriber(k, self.zenoh.handlers.FifoChannel(1_000_000))
                for k in keys]
        seen = Seen()
        stop = threading.Event()
        counting = threading.Event()

        def drain(sub: Any) -> None:
            while not stop.is_set():
                sample = sub.try_recv()
                if sample is None:
                    time.sleep(0.002)
                    continue
                if counting.is_set():
                    self._count(seen, sample)

        threads = [threading.Thread(target=drain, args=(s,), daemon=True) for s in subs]
        for t in threads:
            t.start()
        time.sleep(settle)  # matching reaches the daemon; queues fill to steady state
        mark()
        counting.set()
        time.sleep(seconds)
        counting.clear()
        mark()
        stop.set()
        for t in threads:
            t.join()
        for s in subs:
            s.undeclare()
        return seen

    @staticmethod
    def _count(seen: Seen, sample: Any) -> None:
        key = str(sample.key_expr)
        data = sample.payload.to_bytes()
        if key.endswith("/estimate"):
            seen.json += 1
            host = _number_after(data, b'"host_time":')
            if host is not None:
                seen.latency_ms["json"].append((time.monotonic() - host) * 1e3)
            return
        sec, nanosec = _STAMP.unpack_from(data, 4)
        att = sample.attachment.to_bytes() if sample.attachment is not None else b""
        seen.ros_seqs[key].append(struct.unpack_from("<q", att)[0] if len(att) >= 8 else 0)
        if "/contact/" in key:
            seen.contacts += 1
            seen.latency_ms["ros2"].append((time.time() - sec - nanosec * 1e-9) * 1e3)
        else:
            seen.ros_other += 1

    def close(self) -> None:
        self.session.close()


def missing(seqs: dict[str, list[int]]) -> int:
    """Sequence numbers skipped within each key's span."""
    return sum(max(0, (s[-1] - s[0] + 1) - len(set(s))) for s in seqs.values() if s)


def pct(values: list[float], q: float) -> float:
    if not values:
        return math.nan
    return statistics.quantiles(values, n=100)[q - 1] if len(values) > 1 else values[0]


@dataclass
class Result:
    name: str
    seconds: float = 0.0
    frames: int = 0
    published: int = 0
    cpu_s: float = 0.0
    seen: list[Seen] = field(default_factory=list)

    @property
    def cpu_us_per_frame(self) -> float:
        return 1e6 * self.cpu_s / max(self.frames, 1)


def counters(base: str) -> tuple[int, int]:
    h = health(base)
    sensors = h["sensors"].values()
    return sum(s["frames"] for s in sensors), sum(s["published"] for s in sensors)


def bench(args: argparse.Namespace) -> int:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    results = {name: Result(name) for name in PHASES}
    with tempfile.TemporaryDirectory(prefix="tactiled-bench-ros2-") as tmp:
        cfg = Path(tmp) / "bench.toml"
        text = CONFIG.format(workers=args.workers, endpoint=endpoint, prefix=PREFIX,
                             max_subscribers=10) + ROS2_CONFIG
        for i in range(args.sensors):
            text += SENSOR.format(i=i, seed=i + 1, rate=args.rate, scene="demo")
        cfg.write_text(text)
        env = {k: v for k, v in os.environ.items() if not k.startswith("TACTILED_")}
        proc = subprocess.Popen([sys.executable, "-m", "tactiled.cli", "run", "--config",
                                 str(cfg)], env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.DEVNULL, text=True)
        assert proc.stdout is not None
        base = proc.stdout.readline().strip()
        if not base.startswith("http://"):
            proc.kill()
            raise SystemExit(f"tactiled run did not start (printed {base!r})")
        sub = Subscriber(endpoint)
        try:
            time.sleep(args.settle)
            for _ in range(args.rounds):
                for name in PHASES:
                    marks: list[tuple[float, float, int, int]] = []

                    def mark() -> None:
                        marks.append((time.monotonic(), cpu_seconds(proc.pid),
                                      *counters(base)))

                    seen = sub.phase(name, args.seconds, 1.0, mark)
                    (t0, c0, f0, p0), (t1, c1, f1, p1) = marks
                    r = results[name]
                    r.cpu_s += c1 - c0
                    r.seconds += t1 - t0
                    r.frames += f1 - f0
                    r.published += p1 - p0
                    r.seen.append(seen)
        finally:
            sub.close()
            proc.terminate()
            try:
                proc.wait(15)
            except subprocess.TimeoutExpired:
                proc.kill()
    print(report(results, args))
    return 0


def report(results: dict[str, Result], args: argparse.Namespace) -> str:
    idle = results["idle"].cpu_us_per_frame
    lines = [
        f"ROS 2 against JSON on Zenoh: {args.sensors} simulated sensor(s) (demo scene) at "
        f"{args.rate:g} Hz, {args.workers} fit worker(s), {os.cpu_count()} CPUs; "
        f"{args.rounds} round(s) of {args.seconds:g} s per phase (+1 s settling each).",
        "",
        "| phase | frames/s | published/s | delivered/s JSON | delivered/s ROS 2 (Contact) | "
        "ROS gaps | latency p50 / p99, ms | daemon CPU per frame | added per frame |",
        "|---|---|---|---|---|---|---|---|---|"]
    for name in PHASES:
        r = results[name]
        js = sum(s.json for s in r.seen) / r.seconds
        ros = sum(s.contacts for s in r.seen) / r.seconds
        miss = sum(missing(s.ros_seqs) for s in r.seen)
        lat = [v for s in r.seen for k in ("json", "ros2") for v in s.latency_ms[k]]
        lat_txt = (f"{pct(lat, 50):.1f} / {pct(lat, 99):.1f}" if lat else "-")
        lines.append(
            f"| {name} | {r.frames / r.seconds:,.0f} | {r.published / r.seconds:,.0f} | "
            f"{js:,.0f} | {ros:,.0f} | {miss} | "
            f"{lat_txt} | {r.cpu_us_per_frame:.0f} µs | "
            f"{r.cpu_us_per_frame - idle:+.0f} µs |")
    added = {n: results[n].cpu_us_per_frame - idle for n in PHASES}
    both = results["both"].seen
    ros_n, json_n = sum(s.contacts for s in both), sum(s.json for s in both)
    sent = sum(len(seqs) + missing({k: seqs}) for s in both for k, seqs in s.ros_seqs.items())
    gaps = sum(missing(s.ros_seqs) for s in both)
    lines += ["", f"Ratios (one run): in the both phase (the two subscribers side by side, the "
              f"same estimates), ROS 2 Contact / JSON delivered = {ros_n / max(json_n, 1):.4f} "
              f"({ros_n} / {json_n}), ROS messages missing {gaps} of {sent}; added CPU per frame, "
              f"ROS 2 Contact / JSON = {added['ros2'] / added['json']:.2f}, "
              f"both (JSON + wrench, contact, contacts, markers) / JSON = "
              f"{added['both'] / added['json']:.2f}."
              if added["json"] > 0 else "", ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tactiled_bench.ros2_fanout",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--sensors", type=int, default=3)
    p.add_argument("--rate", type=float, default=1000.0, help="frames per second per sensor")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--seconds", type=float, default=10.0, help="measured seconds per phase")
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--settle", type=float, default=5.0, help="s after start before measuring")
    p.add_argument("--quick", action="store_true", help="1 sensor, 1 round of 3 s")
    args = p.parse_args(argv)
    try:
        import zenoh  # noqa: F401
        import rosbags  # noqa: F401
    except ImportError:
        print("ros2_fanout: error: needs the zenoh and ros2 extras: pip install "
              "'tactiled[zenoh,ros2]'", file=sys.stderr)
        return 2
    if args.quick:
        args.sensors, args.rounds, args.seconds, args.settle = 1, 1, 3.0, 3.0
    return bench(args)


if __name__ == "__main__":
    sys.exit(main())

"""Zenoh against the WebSocket stream: the same daemon, the same estimates, 1, 10 and 50 readers.

    python -m tactiled_bench.zenoh_fanout [--quick] [--subscribers 1,10,50]

Starts ``tactiled run`` (three simulated fingers at 1 kHz, publishing on Zenoh in peer mode on
loopback) and, per reader count, alternates a Zenoh phase and a WebSocket phase on every
estimate: delivery, latency, daemon and reader CPU, what the daemon dropped, frames lost.
"""
# Phases: zenoh, N client-mode sessions connected to the daemon's endpoint, each subscribed to
# <prefix>/*/estimate; websocket, N stream connections each subscribed to every estimate without
# max_rate (the same data: about 3000 messages a second per reader).  Each phase measures the
# same stretch of the looping demo scene (a whole number of periods after the first).
# Zenoh readers run in processes of their own (at most 10 sessions each: one process's GIL could
# not take the callbacks of 50), with plain callbacks (what an application would write);
# WebSocket readers are websocket_fanout's raw-socket clients on one selector thread.
# * delivery: per reader, estimates received over those published in the measured span of
#   sequence numbers.  Published = the union of what every reader of the phase received plus a
#   reference reader in every phase: a Zenoh session whose samples queue in Zenoh's own channel
#   (Rust, no GIL), so it keeps up whatever Python does.  The daemon's counters (zenoh.dropped;
#   the stream's per-client dropped) say whether it dropped any, printed beside.  "Readers that
#   keep up" are those at >= 99.9 %.
# * latency: receive time minus the estimate's host_time (CLOCK_MONOTONIC, shared by one
#   machine's processes): frame -> subscriber, the fit included.
# * daemon CPU: the daemon's process (not its fit workers: the simulators, pipeline, web server
#   and Zenoh's threads), % of one core; reader CPU: the readers' processes (Zenoh) or the
#   selector thread (WebSocket).
# * published/s: estimates published (health counters), all sensors; dropped by the daemon:
#   Zenoh, the bus's zenoh.dropped; WebSocket, what the stream dropped for these readers; frames
#   lost: frames the simulated fingers skipped because the daemon's process did not get the CPU
#   in time (everything shares the machine, readers too).

from __future__ import annotations

import argparse
import array
import json
import math
import os
import resource
import selectors
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tactiled_bench.websocket_fanout import (
    Client,
    Readers,
    _number_after,
    client_frame,
    cpu_seconds,
    handshake,
    health,
)

PREFIX = "tactiled/bench"
SESSIONS_PER_PROCESS = 10
SETTLE_S = 3.0  # s between connecting and measuring
CONFIG = """\
[server]
host = "127.0.0.1"
port = 0
max_subscribers = {max_subscribers}

[fit]
workers = {workers}

[zenoh]
enabled = true
mode = "peer"
multicast_scouting = false
listen = ["{endpoint}"]
prefix = "{prefix}"
"""
SENSOR = """
[[sensor]]
name = "finger{i}"
url = "sim://?scene={scene}&seed={seed}&rate={rate}&sensor_id={i}"
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# -- what one reader saw ------------------------------------------------------------------------


@dataclass
class Tally:
    """Seqs per sensor and latencies (ms) of one reader within the measured window."""

    seqs: dict[str, array.array] = field(default_factory=dict)
    latencies: array.array = field(default_factory=lambda: array.array("f"))

    def add(self, payload: bytes, now: float) -> None:
        i = payload.find(b'"sensor":"')
        if i < 0:
            return
        i += 10
        sensor = payload[i:payload.find(b'"', i)].decode()
        seq = _number_after(payload, b'"seq":')
        host = _number_after(payload, b'"host_time":')
        if seq is None:
            return
        bucket = self.seqs.get(sensor)
        if bucket is None:
            bucket = self.seqs[sensor] = array.array("q")
        bucket.append(int(seq))
        if host is not None:
            self.latencies.append((now - host) * 1e3)

    def to_json(self) -> dict[str, Any]:
        return {"seqs": {k: v.tolist() for k, v in self.seqs.items()},
                "latencies": self.latencies.tolist()}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Tally:
        t = cls()
        t.seqs = {k: array.array("q", v) for k, v in data["seqs"].items()}
        t.latencies = array.array("f", data["latencies"])
        return t


# -- Zenoh readers (child processes) ------------------------------------------------------------


def reader_main(argv: list[str]) -> int:
    """``reader ENDPOINT SESSIONS MODE KEY OUT``: open SESSIONS client sessions subscribed to
    KEY; MODE ``callback`` (plain callbacks) or ``fifo`` (Zenoh's channel, drained by a
    thread: the reference).  stdin: ``start`` / ``stop``; then writes the tallies to OUT."""
    import zenoh

    endpoint, count, mode, key, out = argv[0], int(argv[1]), argv[2], argv[3], argv[4]
    state = {"measuring": False}
    tallies = [Tally() for _ in range(count)]
    sessions, subs, threads = [], [], []
    mono = time.monotonic
    for tally in tallies:
        cfg = zenoh.Config()
        cfg.insert_json5("mode", '"client"')
        cfg.insert_json5("scouting/multicast/enabled", "false")
        cfg.insert_json5("connect/endpoints", json.dumps([endpoint]))
        session = zenoh.open(cfg)
        sessions.append(session)
        if mode == "fifo":
            sub = session.declare_subscriber(key, zenoh.handlers.FifoChannel(1 << 20))

            def drain(sub: Any = sub, tally: Tally = tally) -> None:
                for sample in sub.handler:
                    if state["measuring"]:
                        tally.add(sample.payload.to_bytes(), mono())

            thread = threading.Thread(target=drain, daemon=True)
            thread.start()
            threads.append(thread)
        else:
            def on_sample(sample: Any, tally: Tally = tally) -> None:
                if state["measuring"]:
                    tally.add(sample.payload.to_bytes(), mono())

            sub = session.declare_subscriber(key, zenoh.handlers.Callback(on_sample))
        subs.append(sub)
    print("ready", flush=True)
    assert sys.stdin.readline().strip() == "start"
    r0 = resource.getrusage(resource.RUSAGE_SELF)
    state["measuring"] = True
    assert sys.stdin.readline().strip() == "stop"
    state["measuring"] = False
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    time.sleep(0.5)  # callbacks already running finish
    cpu = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
    Path(out).write_text(json.dumps({"cpu_s": cpu, "tallies": [t.to_json() for t in tallies]}))
    print("done", flush=True)
    os._exit(0)  # closing 10 sessions gracefully would only add time


class ReaderProcess:
    def __init__(self, endpoint: str, count: int, mode: str, key: str, out: Path) -> None:
        self.out = out
        env = {k: v for k, v in os.environ.items() if not k.startswith("TACTILED_")}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tactiled_bench.zenoh_fanout", "reader", endpoint,
             str(count), mode, key, str(out)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)

    def wait_ready(self) -> None:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline().strip()
        if line != "ready":
            raise SystemExit(f"a Zenoh reader did not start (printed {line!r})")

    def send(self, line: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def result(self) -> tuple[float, list[Tally]]:
        assert self.proc.stdout is not None
        self.proc.stdout.readline()
        self.proc.wait(30)
        data = json.loads(self.out.read_text())
        return data["cpu_s"], [Tally.from_json(t) for t in data["tallies"]]


# -- WebSocket readers (threads of this process) ------------------------------------------------


@dataclass
class WsClient(Client):
    tally: Tally = field(default_factory=Tally)

    def on_message(self, payload: bytes, now: float, measuring: bool) -> None:
        if payload.startswith(b'{"type":"estimate"'):
            if measuring:
                self.tally.add(payload, now)
        elif payload.startswith(b'{"type":"unsubscribed"'):
            self.unsubscribed = True


class WsReaders(Readers):
    def add(self, port: int, subscribe: bytes) -> None:
        sock = handshake(port)
        client = WsClient(sock, sock.getsockname()[1])
        sock.sendall(client_frame(subscribe))
        sock.setblocking(False)
        self.clients.append(client)
        self.selector.register(sock, selectors.EVENT_READ, client)

    def _run(self) -> None:
        t0 = time.thread_time()
        super()._run()
        self.cpu_s = time.thread_time() - t0


# -- phases -------------------------------------------------------------------------------------


@dataclass
class Phase:
    transport: str
    readers: int
    seconds: float
    tallies: list[Tally]
    reference: Tally
    daemon_cpu_s: float
    reader_cpu_s: float
    bus_dropped: int
    ws_dropped: int
    frames_lost: int
    published: int  # estimates the pipeline published meanwhile (all sensors)
    delivery: list[float] = field(default_factory=list)
    span: int = 0  # estimates published in the measured seq span (all sensors)

    def judge(self) -> None:
        """Delivery of each reader against the union (see the module docstring)."""
        everyone = self.tallies + [self.reference]
        sensors = sorted(set().union(*(t.seqs for t in everyone)))
        spans = {}
        for s in sensors:
            firsts = [min(t.seqs[s]) for t in everyone if t.seqs.get(s)]
            lasts = [max(t.seqs[s]) for t in everyone if t.seqs.get(s)]
            if not firsts:
                continue
            lo, hi = max(firsts), min(lasts)
            union = set()
            for t in everyone:
                union.update(x for x in t.seqs.get(s, ()) if lo <= x <= hi)
            spans[s] = (lo, hi, len(union))
        self.span = sum(n for _, _, n in spans.values())
        self.delivery = []
        for t in self.tallies:
            got = sum(len({x for x in t.seqs.get(s, ()) if lo <= x <= hi})
                      for s, (lo, hi, _) in spans.items())
            self.delivery.append(got / self.span if self.span else 0.0)

    def pct(self, q: float) -> float:
        xs = sorted(x for t in self.tallies for x in t.latencies)
        return xs[min(len(xs) - 1, int(q / 100 * len(xs)))] if xs else float("nan")


def run_phase(args: argparse.Namespace, transport: str, n: int, endpoint: str, base: str,
              ws_port: int, pid: int, start: float, tmp: Path) -> Phase:
    key = f"{PREFIX}/*/estimate"
    procs: list[ReaderProcess] = []
    ws = WsReaders()
    reference = ReaderProcess(endpoint, 1, "fifo", key, tmp / f"ref-{transport}-{n}.json")
    try:
        if transport == "zenoh":
            left, k = n, 0
            while left > 0:
                count = min(SESSIONS_PER_PROCESS, left)
                procs.append(ReaderProcess(endpoint, count, "callback", key,
                                           tmp / f"z-{n}-{k}.json"))
                left -= count
                k += 1
        else:
            sub = json.dumps({"type": "subscribe", "streams": ["estimates"]}).encode()
            for _ in range(n):
                ws.add(ws_port, sub)
            ws.start()
        for p in procs + [reference]:
            p.wait_ready()
        time.sleep(max(0.0, start - time.monotonic()))
        before = health(base)
        cpu0 = cpu_seconds(pid)
        t0 = time.monotonic()
        for p in procs + [reference]:
            p.send("start")
        ws.measuring = True
        time.sleep(args.seconds)
        ws.measuring = False
        for p in procs + [reference]:
            p.send("stop")
        seconds = time.monotonic() - t0
        cpu = cpu_seconds(pid) - cpu0
        after = health(base)
        reader_cpu = 0.0
        tallies: list[Tally] = []
        for p in procs:
            c, ts = p.result()
            reader_cpu += c
            tallies += ts
        _, (ref,) = reference.result()
        ws_dropped = 0
        if transport == "websocket":
            # Messages the stream dropped for these readers while measuring (queue overflow).
            first = {c["peer"]: c["dropped"] for c in before["subscribers"]["clients"]}
            for c in after["subscribers"]["clients"]:
                ws_dropped += c["dropped"] - first.get(c["peer"], 0)
            ws.unsubscribe_all(30.0)
            tallies = [c.tally for c in ws.clients]
    finally:
        ws.stop()
        for p in procs + [reference]:
            if p.proc.poll() is None:
                p.proc.kill()
    if transport == "websocket":
        reader_cpu = getattr(ws, "cpu_s", 0.0)
    def total(doc: dict[str, Any], key: str) -> int:
        return sum(s[key] for s in doc["sensors"].values())

    phase = Phase(transport, n, seconds, tallies, ref, cpu, reader_cpu,
                  after["zenoh"]["dropped"] - before["zenoh"]["dropped"], ws_dropped,
                  total(after, "lost_frames") - total(before, "lost_frames"),
                  total(after, "published") - total(before, "published"))
    phase.judge()
    return phase


# -- report -------------------------------------------------------------------------------------


def table(phases: list[Phase], args: argparse.Namespace) -> str:
    lines = [
        f"Zenoh against WebSocket: {args.sensors} simulated sensors (demo scene) at "
        f"{args.rate:g} Hz, {args.workers} fit worker(s), {os.cpu_count()} CPUs; every reader "
        f"takes every estimate of every sensor; {args.seconds:g} s measured per phase.",
        "",
        "| transport | readers | published/s | delivery min / mean | readers >= 99.9 % "
        "| frame→subscriber p50 / p99 ms | daemon CPU | reader CPU | dropped by the daemon "
        "| frames lost |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for p in phases:
        keep_up = sum(d >= 0.999 for d in p.delivery)
        dropped = p.bus_dropped if p.transport == "zenoh" else p.ws_dropped
        lines.append(
            f"| {p.transport} | {p.readers} | {p.published / p.seconds:,.0f} "
            f"| {100 * min(p.delivery, default=0):.2f} % / "
            f"{100 * statistics.fmean(p.delivery) if p.delivery else 0:.2f} % "
            f"| {keep_up} of {p.readers} | {p.pct(50):.2f} / {p.pct(99):.2f} "
            f"| {100 * p.daemon_cpu_s / p.seconds:.0f} % "
            f"| {100 * p.reader_cpu_s / p.seconds:.0f} % | {dropped} | {p.frames_lost} |")
    return "\n".join(lines)


def start_daemon(args: argparse.Namespace, workdir: Path,
                 endpoint: str) -> tuple[subprocess.Popen[str], str]:
    cfg = workdir / "bench.toml"
    text = CONFIG.format(workers=args.workers, endpoint=endpoint, prefix=PREFIX,
                         max_subscribers=max(args.subscribers) + 10)
    for i in range(args.sensors):
        text += SENSOR.format(i=i, seed=i + 1, rate=args.rate, scene="demo")
    cfg.write_text(text)
    env = {k: v for k, v in os.environ.items() if not k.startswith("TACTILED_")}
    proc = subprocess.Popen([sys.executable, "-m", "tactiled.cli", "run", "--config", str(cfg)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True)
    assert proc.stdout is not None
    url = proc.stdout.readline().strip()
    if not url.startswith("http://"):
        proc.kill()
        raise SystemExit(f"tactiled run did not start (printed {url!r})")
    return proc, url


def bench(args: argparse.Namespace) -> int:
    from tactiled.sim import named_scene

    period = named_scene("demo").duration
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    phases: list[Phase] = []
    with tempfile.TemporaryDirectory(prefix="tactiled-bench-zenoh-") as tmp:
        proc, base = start_daemon(args, Path(tmp), endpoint)
        try:
            ws_port = int(base.rstrip("/").rsplit(":", 1)[1])
            time.sleep(args.warmup)
            first = time.monotonic() + SETTLE_S
            for n in args.subscribers:
                for transport in ("zenoh", "websocket"):
                    start = time.monotonic() + SETTLE_S
                    if period <= 60.0:
                        start = first + math.ceil((start - first) / period) * period
                    print(f"{transport} x {n} ...", file=sys.stderr, flush=True)
                    phases.append(run_phase(args, transport, n, endpoint, base, ws_port,
                                            proc.pid, start, Path(tmp)))
        finally:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
    print(table(phases, args))
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "reader":
        return reader_main(argv[1:])
    p = argparse.ArgumentParser(prog="python -m tactiled_bench.zenoh_fanout",
                                description="Zenoh against the WebSocket stream, same daemon.")
    p.add_argument("--quick", action="store_true",
                   help="4 s phases, 1 and 10 readers (default: one scene period, 1, 10, 50)")
    p.add_argument("--subscribers", default=None, metavar="N,N,...",
                   help="reader counts (default 1,10,50)")
    p.add_argument("--sensors", type=int, default=3, help="simulated sensors (default 3)")
    p.add_argument("--rate", type=float, default=1000.0, help="frames/s per sensor (1000)")
    p.add_argument("--workers", type=int, default=1, help="fit worker processes (default 1)")
    p.add_argument("--seconds", type=float, default=None,
                   help="measuring time per phase (default one scene period, 18.5 s)")
    args = p.parse_args(argv)
    try:
        import zenoh  # noqa: F401  (the readers need it: say so before starting anything)
    except ImportError:
        print("zenoh_fanout: error: needs the zenoh extra: pip install 'tactiled[zenoh]'",
              file=sys.stderr)
        return 2
    if args.subscribers is None:
        args.subscribers = "1,10" if args.quick else "1,10,50"
    args.subscribers = [int(x) for x in args.subscribers.split(",") if x.strip()]
    if args.seconds is None:
        from tactiled.sim import named_scene

        args.seconds = 4.0 if args.quick else min(named_scene("demo").duration, 60.0)
    args.warmup = 2.0 if args.quick else 5.0
    return bench(args)


if __name__ == "__main__":
    sys.exit(main())

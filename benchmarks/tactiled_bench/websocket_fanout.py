"""Fan-out benchmark: many WebSocket subscribers, some of which never read.

    python -m tactiled_bench.websocket_fanout [--quick] [--clients 100] [--stalled 10]

Starts ``tactiled run`` (three simulated fingers at 1 kHz) and measures the healthy
subscribers' delivery and latency without, then with, ``--stalled`` never-reading ones.  Pass:
every healthy subscriber >= 99 % delivery in both phases, and frame -> client p99 with the
stalled ones at most 5 ms above the baseline's.
"""
# Phases: 1. baseline: clients - stalled healthy subscribers, all reading; 2. with
# never-reading: as many healthy subscribers plus `stalled` that subscribe the same way but
# never read (a 4 KiB receive buffer).  Once their socket buffers are full the server closes
# them (1013) when a send has been stuck for its send timeout (2 s); they reconnect and stall
# again, so some are always filling, stuck or being closed.  They connect 4 s before measuring.
# --stalled-want everything makes them ask for estimates and frames of every sensor without a
# rate limit (each then costs the server a few hundred messages per reconnection, and a frame
# encoding the healthy subscribers do not need).
# Both phases measure the same stretch of the looping demo scene (a whole number of scene
# periods after the first), so they see the same mix of fitted and unchanged estimates;
# --rounds alternates several pairs and pools them, so noise from other work falls on both
# alike.  Healthy subscribers ask for every sensor's estimates with max_rate (default 30 Hz, as
# the dashboard) and are measured for:
# * delivery: estimates received / (messages the server sent it + messages it dropped for it),
#   from the server's per-subscriber counters once an unsubscribe has flushed the pipe;
#   estimates skipped by max_rate are the subscription's contract, not losses;
# * latency: receive time minus the estimate's host_time (the frame's bytes reaching the
#   daemon), both CLOCK_MONOTONIC, shared by processes on one Linux machine: frame arrival ->
#   client, the fit included.  Also publication -> client (host_time + latency_ms), the part
#   the fan-out owns.
# The healthy subscribers are minimal raw-socket WebSocket clients on one selector thread (a
# few microseconds per message), so on a small machine the client side does not eat the CPU
# the daemon needs and the numbers describe the server.

from __future__ import annotations

import argparse
import base64
import json
import math
import os
import selectors
import signal
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


CONFIG = """\
[server]
host = "127.0.0.1"
port = 0

[fit]
workers = {workers}
"""
SENSOR = """
[[sensor]]
name = "finger{i}"
url = "sim://?scene={scene}&seed={seed}&rate={rate}&sensor_id={i}"
"""


# -- the daemon ---------------------------------------------------------------------------------


def start_daemon(args: argparse.Namespace, workdir: Path) -> tuple[subprocess.Popen[str], str]:
    """``tactiled run`` on a free port; returns the process and its address."""
    cfg = workdir / "bench.toml"
    text = CONFIG.format(workers=args.workers)
    for i in range(args.sensors):
        text += SENSOR.format(i=i, seed=i + 1, rate=args.rate, scene=args.scene)
    cfg.write_text(text)
    env = {k: v for k, v in os.environ.items() if not k.startswith("TACTILED_")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "tactiled.cli", "run", "--config", str(cfg),
         "--max-subscribers", str(args.clients + 2 * args.stalled + 10)],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    assert proc.stdout is not None
    url = proc.stdout.readline().strip()
    if not url.startswith("http://"):
        proc.kill()
        raise SystemExit(f"tactiled run did not start (printed {url!r})")
    return proc, url


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of process ``pid`` so far (Linux /proc), seconds."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def health(base: str) -> dict[str, Any]:
    """The daemon's ``/v1/health`` (the standard library's client: what ships runs with the
    package's own dependencies)."""
    try:
        with urllib.request.urlopen(base + "v1/health", timeout=10) as resp:
            return json.load(resp)
    except urllib.error.HTTPError as err:  # a status other than 200 still carries the body
        with err:
            return json.load(err)


# -- a minimal WebSocket client -----------------------------------------------------------------


def client_frame(payload: bytes, opcode: int = 0x1) -> bytes:
    """A masked client frame (clients must mask; an all-zero mask leaves the bytes as is)."""
    n = len(payload)
    if n < 126:
        head = struct.pack("!BB", 0x80 | opcode, 0x80 | n)
    elif n < 65536:
        head = struct.pack("!BBH", 0x80 | opcode, 0x80 | 126, n)
    else:
        head = struct.pack("!BBQ", 0x80 | opcode, 0x80 | 127, n)
    return head + b"\0\0\0\0" + payload


def handshake(port: int, rcvbuf: int | None = None) -> socket.socket:
    """A connected socket past the WebSocket handshake (blocking)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    if rcvbuf is not None:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    sock.connect(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall((f"GET /v1/stream HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                  f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                  "Sec-WebSocket-Version: 13\r\n\r\n").encode())
    head = b""
    while b"\r\n\r\n" not in head:
        chunk = sock.recv(1)  # byte by byte: nothing after the headers may be swallowed
        if not chunk:
            raise ConnectionError("handshake refused")
        head += chunk
    if not head.startswith(b"HTTP/1.1 101"):
        raise ConnectionError(head.split(b"\r\n", 1)[0].decode())
    return sock


def _number_after(text: bytes, key: bytes) -> float | None:
    """The JSON number after ``"key":`` (no full parse: a few microseconds per message)."""
    i = text.find(key)
    if i < 0:
        return None
    i += len(key)
    j = i
    while j < len(text) and text[j] not in b",}":
        j += 1
    try:
        return float(text[i:j])
    except ValueError:
        return None  # null


@dataclass
class Client:
    """A reading subscriber and its tally."""

    sock: socket.socket
    port: int
    buf: bytearray = field(default_factory=bytearray)
    total: int = 0  # estimates received over the whole connection
    received: int = 0  # ... within the measuring window
    latencies_ms: list[float] = field(default_factory=list)  # frame arrival -> received
    fanout_ms: list[float] = field(default_factory=list)  # publication -> received
    unsubscribed: bool = False
    closed: bool = False

    def on_message(self, payload: bytes, now: float, measuring: bool) -> None:
        if payload.startswith(b'{"type":"estimate"'):
            self.total += 1
            if measuring:
                self.received += 1
                host = _number_after(payload, b'"host_time":')
                if host is not None:
                    lat = (now - host) * 1e3
                    self.latencies_ms.append(lat)
                    self.fanout_ms.append(lat - (_number_after(payload, b'"latency_ms":') or 0))
        elif payload.startswith(b'{"type":"unsubscribed"'):
            self.unsubscribed = True

    def feed(self, data: bytes, now: float, measuring: bool) -> None:
        buf = self.buf
        buf += data
        pos = 0
        while len(buf) - pos >= 2:
            b0, b1 = buf[pos], buf[pos + 1]
            n, head = b1 & 0x7F, 2
            if n == 126:
                if len(buf) - pos < 4:
                    break
                n, head = struct.unpack_from("!H", buf, pos + 2)[0], 4
            elif n == 127:
                if len(buf) - pos < 10:
                    break
                n, head = struct.unpack_from("!Q", buf, pos + 2)[0], 10
            if len(buf) - pos < head + n:
                break
            payload = bytes(buf[pos + head:pos + head + n])
            pos += head + n
            opcode = b0 & 0x0F
            if opcode == 0x1:
                self.on_message(payload, now, measuring)
            elif opcode == 0x9:  # ping: answer, or the server drops us
                self.sock.sendall(client_frame(payload, 0xA))
            elif opcode == 0x8:
                self.closed = True
        del buf[:pos]


class Readers:
    """Healthy clients read by one selector thread."""

    def __init__(self) -> None:
        self.selector = selectors.DefaultSelector()
        self.clients: list[Client] = []
        self.measuring = False
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="bench-readers", daemon=True)

    def add(self, port: int, subscribe: bytes) -> None:
        sock = handshake(port)
        client = Client(sock, sock.getsockname()[1])
        sock.sendall(client_frame(subscribe))
        sock.setblocking(False)
        self.clients.append(client)
        self.selector.register(sock, selectors.EVENT_READ, client)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        monotonic = time.monotonic
        while not self._stop:
            for key, _ in self.selector.select(0.05):
                client: Client = key.data
                try:
                    data = client.sock.recv(262144)
                except BlockingIOError:
                    continue
                except OSError:
                    data = b""
                if not data:
                    client.closed = True
                    self.selector.unregister(client.sock)
                    continue
                client.feed(data, monotonic(), self.measuring)

    def unsubscribe_all(self, timeout: float = 30.0) -> bool:
        """Send every open client an ``unsubscribe`` and wait until each has its confirmation
        (everything the server sent before it has then been read) or is closed; False if
        some did not within ``timeout`` s."""
        unsubscribe = client_frame(b'{"type":"unsubscribe"}')
        for c in self.clients:
            if not c.closed:
                c.sock.setblocking(True)
                c.sock.sendall(unsubscribe)
                c.sock.setblocking(False)
        deadline = time.monotonic() + timeout
        while not all(c.unsubscribed or c.closed for c in self.clients):
            if time.monotonic() > deadline:
                return False
            time.sleep(0.05)
        return True

    def stop(self) -> None:
        self._stop = True
        if self._thread.is_alive():
            self._thread.join(5)
        for c in self.clients:
            c.sock.close()


class Staller:
    """A subscriber that never reads; reconnects whenever the server has dropped it."""

    def __init__(self, port: int, subscribe: bytes) -> None:
        self.subscribe = subscribe
        self.server_port = port
        self.sock: socket.socket | None = None
        self.local_port = 0
        self.connects = 0

    def connect(self) -> None:
        self.close()
        sock = handshake(self.server_port, rcvbuf=4096)
        sock.sendall(client_frame(self.subscribe))
        self.sock = sock
        self.local_port = sock.getsockname()[1]
        self.connects += 1

    def alive(self) -> bool:
        """True while the connection is established (the server has not reset it)."""
        if self.sock is None:
            return False
        try:
            state = self.sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 1)[0]
        except OSError:
            return False
        return state == 1  # TCP_ESTABLISHED

    def close(self) -> None:
        if self.sock is not None:
            # RST, not FIN: a closed staller must not wait for its unread backlog either.
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            self.sock.close()
            self.sock = None


class Restaller:
    """A thread that reconnects every :class:`Staller` the server has cut (it resets them),
    so it stalls again.  Watched through the local TCP state, not the server's health
    endpoint: polling that would cost the server CPU the baseline does not pay."""

    def __init__(self, stallers: list[Staller], name: str = "bench-stallers") -> None:
        self.stallers = stallers
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._run, name=name, daemon=True)

    def _run(self) -> None:
        while not self.done.wait(0.2):
            for s in self.stallers:
                if not s.alive():
                    s.connect()

    def start(self) -> None:
        self.thread.start()

    def stop(self) -> None:
        self.done.set()
        if self.thread.is_alive():
            self.thread.join(5)


# -- phases -------------------------------------------------------------------------------------

STALL_LEAD = 4.0  # s: never-reading subscribers connect this long before measuring starts
SETTLE = 3.0  # s: healthy subscribers connect this long before it


@dataclass
class PhaseResult:
    name: str
    healthy: int
    stalled: int
    received: int
    delivery: list[float]
    latencies_ms: list[float]
    fanout_ms: list[float]
    dropped: int
    stalled_closed: int
    seconds: float
    daemon_cpu_s: float = 0.0  # CPU time of the daemon's process (not its workers) meanwhile

    def pct(self, q: float, fanout: bool = False) -> float:
        xs = sorted(self.fanout_ms if fanout else self.latencies_ms)
        if not xs:
            return float("nan")
        return xs[min(len(xs) - 1, int(q / 100.0 * len(xs)))]


def run_phase(name: str, base: str, port: int, args: argparse.Namespace, stalled: int,
              start: float, pid: int) -> PhaseResult:
    """Connect (the never-reading ones ``STALL_LEAD`` s early, the others ``SETTLE`` s), then
    measure from monotonic time ``start`` for ``args.seconds``."""
    sub = json.dumps({"type": "subscribe", "streams": ["estimates"],
                      "max_rate": args.max_rate}).encode()
    everything = json.dumps({"type": "subscribe", "streams": ["estimates", "frames"]}).encode()
    stallers = [Staller(port, everything if args.stalled_want == "everything" else sub)
                for _ in range(stalled)]
    readers = Readers()
    restaller = Restaller(stallers)
    try:
        time.sleep(max(0.0, start - STALL_LEAD - time.monotonic()))
        for s in stallers:
            s.connect()
        if stallers:
            restaller.start()
        time.sleep(max(0.0, start - SETTLE - time.monotonic()))
        for _ in range(args.clients - args.stalled):
            readers.add(port, sub)
        readers.start()
        time.sleep(max(0.0, start - time.monotonic()))
        before = health(base)
        cpu0 = cpu_seconds(pid)
        readers.measuring = True
        t0 = time.monotonic()
        time.sleep(args.seconds)
        readers.measuring = False
        seconds = time.monotonic() - t0
        cpu = cpu_seconds(pid) - cpu0
        stall_count = health(base)["subscribers"]["stalled"] - before["subscribers"]["stalled"]
        if not readers.unsubscribe_all(30.0):
            raise SystemExit("clients did not see their unsubscribe confirmed in 30 s")
        after = health(base)
    finally:
        restaller.stop()
        for s in stallers:
            s.close()
        readers.stop()
    by_peer = {c["peer"]: c for c in after["subscribers"]["clients"]}
    delivery, dropped = [], 0
    for c in readers.clients:
        srv = by_peer.get(f"127.0.0.1:{c.port}")
        if srv is None or c.closed:
            delivery.append(0.0)  # the server dropped a healthy client: a failure
            continue
        # The server's "sent" also counts version, subscribed and unsubscribed.
        owed = srv["sent"] - 3 + srv["dropped"]
        dropped += srv["dropped"]
        delivery.append(c.total / owed if owed else 1.0)
    return PhaseResult(
        name=name, healthy=len(readers.clients), stalled=stalled,
        received=sum(c.received for c in readers.clients), delivery=delivery,
        latencies_ms=[x for c in readers.clients for x in c.latencies_ms],
        fanout_ms=[x for c in readers.clients for x in c.fanout_ms], dropped=dropped,
        stalled_closed=stall_count, seconds=seconds, daemon_cpu_s=cpu)


# -- report -------------------------------------------------------------------------------------


def table(results: list[PhaseResult], args: argparse.Namespace) -> str:
    lines = [
        f"Fan-out: {args.sensors} simulated sensors ({args.scene} scene) at {args.rate:g} Hz, "
        f"{args.workers} fit worker(s), {os.cpu_count()} CPUs; healthy subscribers ask for "
        f"estimates of every sensor at max_rate {args.max_rate:g} Hz; never-reading ones ask "
        f"for {'the same' if args.stalled_want == 'same' else 'everything at full rate'}; "
        f"{args.rounds} x {args.seconds:g} s per phase, alternated.",
        "",
        "| phase | healthy | never reading | healthy msgs/s | delivery min | delivery mean "
        "| frame→client p50 / p99 / max ms | publish→client p50 / p99 ms | dropped "
        "| closed 1013 | daemon CPU |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {r.name} | {r.healthy} | {r.stalled} | {r.received / r.seconds:,.0f} "
            f"| {100 * min(r.delivery):.2f} % | {100 * statistics.fmean(r.delivery):.2f} % "
            f"| {r.pct(50):.2f} / {r.pct(99):.2f} / {max(r.latencies_ms, default=0):.2f} "
            f"| {r.pct(50, True):.2f} / {r.pct(99, True):.2f} "
            f"| {r.dropped} | {r.stalled_closed} | {100 * r.daemon_cpu_s / r.seconds:.0f} % |")
    return "\n".join(lines)


def verdict(results: list[PhaseResult]) -> tuple[bool, list[str]]:
    base, stall = results
    notes = []
    ok = True
    for r in results:
        good = min(r.delivery) >= 0.99
        ok &= good
        notes.append(f"{'PASS' if good else 'FAIL'}: {r.name}: every healthy subscriber got "
                     f">= 99 % (min {100 * min(r.delivery):.2f} %)")
    extra = stall.pct(99) - base.pct(99)
    good = extra <= 5.0
    ok &= good
    notes.append(f"{'PASS' if good else 'FAIL'}: frame->client p99 with never-reading "
                 f"subscribers is {extra:+.2f} ms from the baseline's (limit +5 ms)")
    return ok, notes


def merge(name: str, parts: list[PhaseResult]) -> PhaseResult:
    """Rounds of one phase pooled into one result."""
    return PhaseResult(
        name=name, healthy=parts[0].healthy, stalled=parts[0].stalled,
        received=sum(p.received for p in parts),
        delivery=[d for p in parts for d in p.delivery],
        latencies_ms=[x for p in parts for x in p.latencies_ms],
        fanout_ms=[x for p in parts for x in p.fanout_ms],
        dropped=sum(p.dropped for p in parts),
        stalled_closed=sum(p.stalled_closed for p in parts),
        seconds=sum(p.seconds for p in parts),
        daemon_cpu_s=sum(p.daemon_cpu_s for p in parts))


def bench(args: argparse.Namespace) -> int:
    from tactiled.sim import named_scene

    period = named_scene(args.scene).duration  # s: the simulated scene loops
    parts: dict[str, list[PhaseResult]] = {"baseline": [], "with never-reading": []}
    with tempfile.TemporaryDirectory(prefix="tactiled-bench-") as tmp:
        proc, base = start_daemon(args, Path(tmp))
        try:
            port = int(base.rstrip("/").rsplit(":", 1)[1])
            time.sleep(args.warmup)
            first = time.monotonic() + STALL_LEAD
            for k in range(2 * args.rounds):
                # Alternate the phases (machine noise hits both alike); each starts on the
                # same stretch of a scene that loops soon, a whole number of periods later,
                # leaving time to connect (and for never-reading subscribers to fill up).
                start = time.monotonic() + STALL_LEAD
                if period <= 60.0:
                    start = first + math.ceil((start - first) / period) * period
                name, stalled = (("baseline", 0) if k % 2 == 0
                                 else ("with never-reading", args.stalled))
                parts[name].append(run_phase(name, base, port, args, stalled, start, proc.pid))
        finally:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
    results = [merge(name, rounds) for name, rounds in parts.items()]
    print(table(results, args))
    ok, notes = verdict(results)
    print()
    for note in notes:
        print(note)
    return 0 if ok else 1


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tactiled_bench.websocket_fanout",
                                description="Fan-out benchmark of the WebSocket stream.")
    p.add_argument("--quick", action="store_true",
                   help="one pair of 4 s phases (default: 3 pairs of one scene period)")
    p.add_argument("--clients", type=int, default=100, help="subscribers in all (default 100)")
    p.add_argument("--stalled", type=int, default=10,
                   help="of which never read in the second phase (default 10)")
    p.add_argument("--sensors", type=int, default=3, help="simulated sensors (default 3)")
    p.add_argument("--scene", default="demo",
                   help="simulated scene (default demo: presses, rolls, turns; 'hold' keeps "
                        "one contact still, so few fits run)")
    p.add_argument("--rate", type=float, default=1000.0, help="frames/s per sensor (1000)")
    p.add_argument("--max-rate", type=float, default=30.0,
                   help="healthy subscribers' max_rate, Hz per sensor (default 30)")
    p.add_argument("--stalled-want", choices=("same", "everything"), default="same",
                   help="what the never-reading subscribers ask for: the same as the healthy "
                        "ones (default), or every estimate and frame with no rate limit")
    p.add_argument("--workers", type=int, default=1, help="fit worker processes (default 1)")
    p.add_argument("--rounds", type=int, default=None,
                   help="baseline / never-reading phase pairs, alternated and pooled "
                        "(default 3; 1 with --quick)")
    p.add_argument("--seconds", type=float, default=None,
                   help="measuring time per phase (default: one scene period, at most 30 s; "
                        "4 with --quick)")
    args = p.parse_args(argv)
    if args.seconds is None:
        from tactiled.sim import named_scene

        args.seconds = 4.0 if args.quick else min(named_scene(args.scene).duration, 30.0)
    if args.rounds is None:
        args.rounds = 1 if args.quick else 3
    args.warmup = 2.0 if args.quick else 5.0
    if not 0 <= args.stalled < args.clients:
        p.error("--stalled must be at least 0 and less than --clients")
    return bench(args)


if __name__ == "__main__":
    sys.exit(main())

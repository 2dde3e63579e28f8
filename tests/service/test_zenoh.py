"""Zenoh publishing (issue 14) with real Zenoh sessions and real `tactiled run` processes.

Everything stays on loopback: multicast scouting is off in every session, and every endpoint
is ``tcp/127.0.0.1:<port>``.  Two daemons (module-scoped, separate processes, prefixes
``tactiled/zt-a`` and ``tactiled/zt-b``) connect as peers to a Zenoh router opened in this
process; each also listens on a port of its own, so a subscriber can talk to a daemon
directly.  Simulated fingers run at 500 Hz to leave the 2 cores room for the readers.

What is checked: one subscriber sees both daemons' estimates complete, in sequence order and
byte for byte the WebSocket stream's; the queryables answer the newest estimate and the
health; ``tactiled watch --zenoh`` prints and lists both; with ``zenoh.reliable`` estimates are
put with congestion control BLOCK (no node drops one for a full queue, whatever the load),
frames with DROP (without it, everything with DROP); a
subscriber that never reads is cut off by Zenoh and costs the other subscribers no estimate; a
daemon whose ``connect`` peer is absent keeps
acquiring, joins when it appears, and vanishes from ``--list`` when killed; bad configuration
is refused naming the key.  Waits have deadlines; nothing here asserts a speed.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

zenoh = pytest.importorskip(
    "zenoh", reason="the zenoh extra is not installed: pip install -e '.[test,zenoh]'")

from svc_helpers import http, subscribe, wait_for, ws_connect  # noqa: E402

from tactiled_service.bus import prefix_of, tagged  # noqa: E402

PYTHON = sys.executable
RATE_HZ = 500  # simulated frames per second per finger
SIM = f"sim://?scene=demo&seed={{seed}}&rate={RATE_HZ}"
FRAME_RATE_HZ = 50  # zenoh.frame_rate_hz of daemon A


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def zconfig(mode: str, *, listen: list[str] | None = None,
            connect: list[str] | None = None, extra: dict[str, Any] | None = None) -> Any:
    """A loopback Zenoh configuration: multicast scouting off, explicit endpoints only."""
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("listen/endpoints", json.dumps(listen or []))
    cfg.insert_json5("connect/endpoints", json.dumps(connect or []))
    for key, value in (extra or {}).items():
        cfg.insert_json5(key, json.dumps(value))
    return cfg


def loopback_env(**extra: str) -> dict[str, str]:
    """The environment of a `tactiled` child: no stray TACTILED_*, multicast scouting off."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("TACTILED_")}
    env["TACTILED_ZENOH_MULTICAST_SCOUTING"] = "false"
    env.update(extra)
    return env


def daemon_env(prefix: str, seed: int, connect: str, listen: str,
               frame_rate_hz: float = 0, reliable: bool = False) -> dict[str, str]:
    return {
        "TACTILED_ZENOH_ENABLED": "true",
        "TACTILED_ZENOH_MULTICAST_SCOUTING": "false",
        "TACTILED_ZENOH_PREFIX": prefix,
        "TACTILED_ZENOH_CONNECT": connect,
        "TACTILED_ZENOH_LISTEN": listen,
        "TACTILED_ZENOH_FRAME_RATE_HZ": str(frame_rate_hz),
        "TACTILED_ZENOH_RELIABLE": "true" if reliable else "false",
        "TACTILED_FIT_WORKERS": "1",
        "TACTILED_SENSOR_0_URL": SIM.format(seed=seed),
    }


def run_cli(*args: str, env: dict[str, str] | None = None,
            timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run([PYTHON, "-m", "tactiled.cli", *args], env=env or loopback_env(),
                          capture_output=True, text=True, timeout=timeout)


class Collector:
    """A subscriber that keeps up whatever this process does: samples queue in Zenoh's own
    channel (Rust, no GIL: a test thread busy elsewhere never makes Zenoh drop for this
    subscriber) and are read out as (key, payload text) by :meth:`of`."""

    CAPACITY = 1_000_000

    def __init__(self, session: Any, key: str) -> None:
        self.sub = session.declare_subscriber(key, zenoh.handlers.FifoChannel(self.CAPACITY))
        self.samples: list[tuple[str, str]] = []
        self.closed = False

    def drain(self) -> None:
        if self.closed:
            return
        while (sample := self.sub.try_recv()) is not None:
            self.samples.append((str(sample.key_expr), sample.payload.to_string()))

    def close(self) -> None:
        self.drain()
        self.sub.undeclare()
        self.closed = True

    def of(self, prefix: str, kind: str = "estimate") -> list[dict[str, Any]]:
        self.drain()
        out = []
        for key, text in self.samples:
            p, _sensor, k = prefix_of(key)
            if p == prefix and k == kind:
                msg = json.loads(text)
                msg["_text"] = text
                out.append(msg)
        return out


# --------------------------------------------------------------------------------------------
# Fixtures: a router in this process, two daemons around it


@pytest.fixture(scope="module")
def router() -> Iterator[tuple[Any, str]]:
    """A Zenoh router session listening on a loopback port: (session, endpoint)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = zenoh.open(zconfig("router", listen=[endpoint]))
    try:
        yield session, endpoint
    finally:
        session.close()


class Daemon:
    def __init__(self, proc: Any, prefix: str, listen: str) -> None:
        self.proc = proc
        self.prefix = prefix
        self.listen = listen
        self.url = ""

    @property
    def ws_url(self) -> str:
        return self.url.replace("http://", "ws://") + "v1/stream"

    def health(self) -> dict[str, Any]:
        return http(self.url, "GET", "/v1/health").json()


@pytest.fixture(scope="module")
def daemons(router: tuple[Any, str], daemon_process: Callable[..., Any]) -> Iterator[list[Daemon]]:
    """Daemons A (frames at FRAME_RATE_HZ too) and B, peers of the router, started together,
    both with ``zenoh.reliable`` (estimates put with BLOCK: complete whatever the load)."""
    _, endpoint = router
    started = []
    try:
        for name, seed, frames in (("a", 1, FRAME_RATE_HZ), ("b", 2, 0)):
            listen = f"tcp/127.0.0.1:{free_port()}"
            prefix = f"tactiled/zt-{name}"
            proc = daemon_process(["--port", "0"],
                                  env=daemon_env(prefix, seed, endpoint, listen, frames, True))
            started.append(Daemon(proc, prefix, listen))
        for d in started:
            d.url = d.proc.wait_url()
        def publishing(d: Daemon) -> bool:
            # OK, or WARN on a machine so loaded that the simulator skips frames.
            h = d.health()
            return (h["status"] in ("OK", "WARN") and h["zenoh"]["state"] == "open"
                    and h["sensors"]["finger0"]["published"] > 0)

        for d in started:
            wait_for(lambda d=d: publishing(d), 90, what=f"{d.prefix} publishing")
        yield started
    finally:
        for d in started:
            d.proc.proc.send_signal(signal.SIGTERM)
        codes = []
        for d in started:
            try:
                codes.append(d.proc.proc.wait(15))
            except subprocess.TimeoutExpired:
                d.proc.kill()
                codes.append(None)
        # A graceful stop with the bus open is still a clean exit.
        assert codes == [0] * len(started), codes


def client_of(endpoint: str, **extra: Any) -> Any:
    return zenoh.open(zconfig("client", connect=[endpoint], extra=extra))


def ws_collect(daemon: Daemon, stop: threading.Event, out: list[str],
               subscribed: threading.Event) -> None:
    """Every estimate text of ``daemon``'s WebSocket stream until ``stop`` (a thread)."""

    async def main() -> None:
        async with ws_connect(daemon.ws_url) as ws:
            await subscribe(ws, streams=["estimates"])
            subscribed.set()
            while not stop.is_set():
                try:
                    text = await asyncio.wait_for(ws.recv(), 0.2)
                except TimeoutError:
                    continue
                if text.startswith('{"type":"estimate"'):
                    out.append(text)

    asyncio.run(main())


def compare_with_ws(zmsgs: list[dict[str, Any]], ws_texts: list[str], what: str) -> int:
    """Zenoh's estimates against the WebSocket stream's over the span both saw: the same
    seqs, in order, byte for byte.  Returns how many were compared."""
    assert zmsgs and ws_texts, f"{what}: zenoh {len(zmsgs)}, websocket {len(ws_texts)} estimates"
    wmsgs = [json.loads(t) | {"_text": t} for t in ws_texts]
    zseq = [m["seq"] for m in zmsgs]
    assert all(b > a for a, b in zip(zseq, zseq[1:])), f"{what}: zenoh seqs out of order"
    lo = max(zmsgs[0]["seq"], wmsgs[0]["seq"])
    hi = min(zmsgs[-1]["seq"], wmsgs[-1]["seq"])
    zin = [(m["seq"], m["_text"]) for m in zmsgs if lo <= m["seq"] <= hi]
    win = [(m["seq"], m["_text"]) for m in wmsgs if lo <= m["seq"] <= hi]
    assert [s for s, _ in zin] == [s for s, _ in win], (
        f"{what}: zenoh and websocket disagree on seqs {lo}..{hi}: zenoh has "
        f"{len(zin)}, websocket {len(win)}; missing from zenoh "
        f"{sorted(set(s for s, _ in win) - set(s for s, _ in zin))[:10]}")
    assert zin == win, f"{what}: same seqs but different bytes"
    return len(zin)


def collect_both(session: Any, targets: list[Daemon], seconds: float,
                 key: str = "tactiled/**") -> tuple[Collector, dict[str, list[str]]]:
    """Subscribe on ``session`` and to each target's WebSocket stream at once, for
    ``seconds`` of data once all are subscribed."""
    col = Collector(session, key)
    stop = threading.Event()
    texts: dict[str, list[str]] = {d.prefix: [] for d in targets}
    ready = {d.prefix: threading.Event() for d in targets}
    threads = [threading.Thread(target=ws_collect, args=(d, stop, texts[d.prefix],
                                                          ready[d.prefix]), daemon=True)
               for d in targets]
    try:
        for t in threads:
            t.start()
        for d in targets:
            assert ready[d.prefix].wait(15), f"websocket to {d.prefix} not subscribed"
        time.sleep(seconds)
    finally:
        stop.set()
        for t in threads:
            t.join(10)
        time.sleep(0.2)  # the last zenoh samples in flight
        col.close()
    return col, texts


# --------------------------------------------------------------------------------------------
# Publishing


def test_one_subscriber_sees_both_daemons_complete_in_order_and_byte_for_byte(daemons, router):
    _, endpoint = router
    session = client_of(endpoint)
    try:
        col, texts = collect_both(session, daemons, 3.0)
    finally:
        session.close()
    for d in daemons:
        compared = compare_with_ws(col.of(d.prefix), texts[d.prefix], d.prefix)
        assert compared > 200, f"{d.prefix}: only {compared} estimates in common"
        h = d.health()
        assert h["zenoh"]["dropped"] == 0 and h["zenoh"]["put_errors"] == 0, h["zenoh"]
        assert h["zenoh"]["published"]["estimate"] > compared
        assert h["zenoh"]["routers"] == 1, h["zenoh"]
        for msg in col.of(d.prefix)[:5]:
            assert msg["type"] == "estimate" and msg["sensor"] == "finger0"
        for msg in col.of(d.prefix):  # every contact listed, with its id
            assert len(msg["contacts"]) == int(msg["contact"])
            assert [c["contact_id"] for c in msg["contacts"][:1]] == ([msg["contact_id"]] if msg["contact"] else [])
    # Frames: daemon A only (B's frame_rate_hz is 0), every one a frame message, at most
    # FRAME_RATE_HZ by the daemon's own clock.
    frames = col.of("tactiled/zt-a", "frame")
    assert len(frames) > 20 and not col.of("tactiled/zt-b", "frame")
    assert all(f["type"] == "frame" and len(f["strain"]) == f["rows"] == 8 for f in frames)
    span = frames[-1]["host_time"] - frames[0]["host_time"]
    assert len(frames) - 1 <= FRAME_RATE_HZ * span + 2, (len(frames), span)
    # The health document, once a second, is the /v1/health one.
    health = col.of("tactiled/zt-a", "health")
    assert health and health[-1]["zenoh"]["prefix"] == "tactiled/zt-a"
    assert set(health[-1]) >= {"status", "sensors", "workers", "subscribers", "zenoh"}


def test_samples_carry_the_json_encoding_and_their_congestion_control(daemons, router):
    # Estimates wait for room in a full queue (BLOCK) at every node; frames may be dropped.
    _, endpoint = router
    session = client_of(endpoint)
    got: dict[str, Any] = {}
    done = threading.Event()

    def on_sample(sample: Any) -> None:
        kind = prefix_of(str(sample.key_expr))[2]
        got.setdefault(kind, (str(sample.encoding), sample.congestion_control,
                              sample.payload.to_bytes()))
        if {"estimate", "frame"} <= set(got):
            done.set()

    try:
        sub = session.declare_subscriber("tactiled/zt-a/finger0/*",
                                         zenoh.handlers.Callback(on_sample))
        assert done.wait(15), f"only {sorted(got)} from tactiled/zt-a"
        sub.undeclare()
    finally:
        session.close()
    for kind, congestion in (("estimate", zenoh.CongestionControl.BLOCK),
                             ("frame", zenoh.CongestionControl.DROP)):
        encoding, control, payload = got[kind]
        assert encoding == "application/json" and control == congestion, (kind, control)
        assert json.loads(payload.decode("utf-8"))["type"] == kind


def test_queryables_answer_the_newest_estimate_and_the_health(daemons, router):
    _, endpoint = router
    a = daemons[0]
    session = client_of(endpoint)
    try:
        before = http(a.url, "GET", "/v1/sensors/finger0/estimate").json()["seq"]
        replies = list(session.get(f"{a.prefix}/finger0/latest", timeout=5))
        after = http(a.url, "GET", "/v1/sensors/finger0/estimate").json()["seq"]
        assert len(replies) == 1 and replies[0].ok is not None, replies
        sample = replies[0].ok
        assert str(sample.key_expr) == f"{a.prefix}/finger0/latest"
        assert str(sample.encoding) == "application/json"
        latest = json.loads(sample.payload.to_bytes())
        assert latest["type"] == "estimate" and latest["sensor"] == "finger0"
        assert before <= latest["seq"] <= after, (before, latest["seq"], after)
        # A late joiner asks every daemon at once.
        keys = sorted(str(r.ok.key_expr) for r in session.get("tactiled/*/*/latest", timeout=5)
                      if r.ok)
        assert keys == ["tactiled/zt-a/finger0/latest", "tactiled/zt-b/finger0/latest"]
        health = [r.ok for r in session.get(f"{a.prefix}/health", timeout=5) if r.ok]
        assert len(health) == 1
        doc = json.loads(health[0].payload.to_bytes())
        assert doc["status"] in ("OK", "WARN") and doc["zenoh"]["queries"] >= 2
        assert set(doc["sensors"]) == {"finger0"}
    finally:
        session.close()


def test_watch_prints_every_daemon_tagged_and_lists_them(daemons, router):
    _, endpoint = router
    env = loopback_env(TACTILED_ZENOH_MODE="client")
    done = run_cli("watch", "--zenoh", "--connect", endpoint, "--count", "400", env=env)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert len(lines) == 400
    seen = set()
    for line in lines:
        assert line.startswith('{"prefix":"tactiled/zt-')
        msg = json.loads(line)
        assert msg["type"] == "estimate"
        seen.add(msg["prefix"])
    assert seen == {"tactiled/zt-a", "tactiled/zt-b"}
    listed = run_cli("watch", "--zenoh", "--connect", endpoint, "--list", env=env)
    assert listed.returncode == 0, listed.stderr
    entries = [json.loads(line) for line in listed.stdout.splitlines()]
    assert [e["prefix"] for e in entries] == ["tactiled/zt-a", "tactiled/zt-b"]
    for e in entries:
        # WARN is possible on a machine loaded by others (a fit lost to a timeout).
        assert e["status"] in ("OK", "WARN") and list(e["sensors"]) == ["finger0"], e
    one = run_cli("watch", "--zenoh", "--connect", endpoint, "--key", "tactiled/zt-b/**",
                  "--count", "20", env=env)
    assert one.returncode == 0, one.stderr
    assert {json.loads(line)["prefix"] for line in one.stdout.splitlines()} == {"tactiled/zt-b"}


STALLER = textwrap.dedent("""
    import json, os, sys, zenoh
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"client"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("listen/endpoints", "[]")
    cfg.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
    # A tiny receive buffer: once stopped, its link is full within a few messages.
    cfg.insert_json5("transport/link/tcp/so_rcvbuf", "4096")
    session = zenoh.open(cfg)
    count = [0]
    def on_sample(sample):
        count[0] += 1
    sub = session.declare_subscriber("tactiled/**", zenoh.handlers.Callback(on_sample))
    print("ready", flush=True)
    sys.stdin.readline()
    print(count[0], flush=True)
    os._exit(0)  # not a graceful close: its link may still be full
""")


def test_a_subscriber_that_never_reads_costs_the_daemon_and_the_others_nothing(daemons):
    a = daemons[0]
    staller = subprocess.Popen([PYTHON, "-c", STALLER, a.listen], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, text=True, env=loopback_env())
    session = None
    try:
        assert staller.stdout.readline().strip() == "ready"
        time.sleep(0.5)
        staller.send_signal(signal.SIGSTOP)  # connected, subscribed, and now never reading
        before = a.health()
        # A healthy subscriber connected to the same daemon directly, over the stall.
        session = client_of(a.listen)
        col, texts = collect_both(session, [a], 4.0)
        after = a.health()
    finally:
        staller.send_signal(signal.SIGCONT)
        if session is not None:
            session.close()
    staller.stdin.write("\n")
    staller.stdin.flush()
    stalled_got = int(staller.stdout.readline().strip() or 0)
    staller.wait(10)
    compared = compare_with_ws(col.of(a.prefix), texts[a.prefix], "next to a stalled one")
    assert compared > 200
    healthy_got = len(col.samples)  # estimates, frames and health
    # The stall really happened (its link's queue filled: an estimate's put waited for it,
    # up to Zenoh's wait_before_close, then Zenoh closed that link) ...
    assert stalled_got < healthy_got, (stalled_got, healthy_got)
    # ... and cost the daemon nothing: its publishing queue absorbed the wait, no put failed,
    # the sensor stayed OK and the healthy subscriber saw every estimate.
    z0, z1 = before["zenoh"], after["zenoh"]
    assert z1["dropped"] == z0["dropped"] == 0 and z1["put_errors"] == 0, z1
    assert after["status"] in ("OK", "WARN"), after["sensors"]  # WARN: the machine's load
    assert after["sensors"]["finger0"]["lost_frames"] == before["sensors"]["finger0"]["lost_frames"]


# --------------------------------------------------------------------------------------------
# Joining late, leaving abruptly


def test_daemon_without_its_peer_keeps_acquiring_joins_later_and_vanishes_when_killed(
        daemon_process):
    rendezvous = f"tcp/127.0.0.1:{free_port()}"
    prefix = "tactiled/zt-late"
    proc = daemon_process(["--port", "0"], env=daemon_env(prefix, 3, rendezvous,
                                                           "tcp/127.0.0.1:0"))
    url = proc.wait_url()
    try:
        def acquiring() -> bool:
            # OK, or WARN on a machine so loaded that the simulator skips frames.
            h = http(url, "GET", "/v1/health").json()
            return (h["status"] in ("OK", "WARN") and h["zenoh"]["state"] == "open"
                    and h["sensors"]["finger0"]["published"] > RATE_HZ)

        wait_for(acquiring, 60, what="acquiring with the zenoh peer absent")
        h = http(url, "GET", "/v1/health").json()
        assert h["zenoh"]["peers"] == 0 and h["zenoh"]["routers"] == 0
        # The peer appears: a router on the endpoint the daemon was told to connect to.
        router = zenoh.open(zconfig("router", listen=[rendezvous]))
        try:
            col = Collector(router, f"{prefix}/**")
            wait_for(lambda: col.of(prefix), 30, what="the daemon joining its peer")
            gone = threading.Event()

            def on_token(sample: Any) -> None:
                if sample.kind == zenoh.SampleKind.DELETE and str(sample.key_expr) == prefix:
                    gone.set()

            tokens = router.liveliness().declare_subscriber(
                prefix, zenoh.handlers.Callback(on_token))
            env = loopback_env(TACTILED_ZENOH_MODE="client")
            listed = run_cli("watch", "--zenoh", "--connect", rendezvous, "--list", env=env)
            assert [json.loads(line)["prefix"] for line in listed.stdout.splitlines()] == [
                prefix], listed.stderr
            proc.kill()  # SIGKILL, the daemon and its worker: no goodbye
            assert gone.wait(15), "the liveliness token outlived the daemon by 15 s"
            listed = run_cli("watch", "--zenoh", "--connect", rendezvous, "--list", env=env)
            assert listed.returncode == 0 and listed.stdout == "", listed.stdout
            tokens.undeclare()
            col.close()
        finally:
            router.close()
    finally:
        proc.kill()


# --------------------------------------------------------------------------------------------
# Configuration refused before anything starts


@pytest.mark.parametrize("env, words", [
    ({"TACTILED_ZENOH_CONNECT": "tcp/127.0.0.1"}, "zenoh.connect[0]: 'tcp/127.0.0.1': the "
                                                  "address must be host:port"),
    ({"TACTILED_ZENOH_LISTEN": "tcp/127.0.0.1:7447,bogus"}, "zenoh.listen[1]: 'bogus' is not "
                                                            "an endpoint"),
    ({"TACTILED_ZENOH_PREFIX": "tactiled/*"}, "zenoh.prefix: must be a plain key"),
    ({"TACTILED_ZENOH_MODE": "router"}, "zenoh.mode: must be one of peer, client"),
])
def test_bad_zenoh_configuration_is_refused_naming_the_key(env, words):
    done = run_cli("run", "--port", "0", "--zenoh",
                   env=loopback_env(TACTILED_FIT_WORKERS="1", **env), timeout=60)
    assert done.returncode == 2, done.stderr
    assert words in done.stderr, done.stderr
    assert done.stdout == ""


def test_a_listen_endpoint_in_use_is_refused_before_the_sensors_start(tmp_path):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        done = run_cli("run", "--port", "0", "--zenoh", "--zenoh-listen",
                       f"tcp/127.0.0.1:{port}", env=loopback_env(TACTILED_FIT_WORKERS="1"))
    assert done.returncode == 2, done.stderr
    assert "zenoh.listen: cannot open a session" in done.stderr and str(port) in done.stderr


def test_enabled_without_the_extra_says_what_to_install(tmp_path):
    fake = tmp_path / "zenoh"
    fake.mkdir()
    (fake / "__init__.py").write_text("raise ImportError(\"No module named 'zenoh'\")\n")
    env = loopback_env(PYTHONPATH=str(tmp_path), TACTILED_ZENOH_ENABLED="true")
    done = run_cli("run", "--port", "0", env=env)
    assert done.returncode == 2
    assert "pip install 'tactiled[zenoh]'" in done.stderr and "zenoh.enabled" in done.stderr
    watch = run_cli("watch", "--zenoh", "--list", env=env)
    assert watch.returncode == 2 and "pip install 'tactiled[zenoh]'" in watch.stderr


@pytest.mark.parametrize("args, words", [
    (["--zenoh", "--connect", "udp/host"], "zenoh.connect[0]: 'udp/host': the address"),
    (["--zenoh", "--key", "tactiled//x"], "--key 'tactiled//x' is not a key expression"),
    (["--list"], "--list, --connect and --key go with --zenoh"),
    (["--zenoh", "ws://127.0.0.1:1/v1/stream"], "--zenoh reads Zenoh, not a WebSocket"),
])
def test_watch_refuses_bad_zenoh_arguments(args, words):
    done = run_cli("watch", *args, "--count", "1", timeout=30)
    assert done.returncode == 2, (done.stdout, done.stderr)
    assert words in done.stderr, done.stderr


def test_reliable_blocks_estimates_and_slip_events_alone():
    from tactiled.settings.sections import ZenohSettings
    from tactiled_service.bus import congestion

    assert ZenohSettings().reliable is False  # the default: every publication on DROP
    drop, block = zenoh.CongestionControl.DROP, zenoh.CongestionControl.BLOCK
    for kind in ("estimate", "slip", "frame", "health"):
        assert congestion(kind, False) == drop
        assert congestion(kind, True) == (block if kind in ("estimate", "slip") else drop)


def test_the_sender_queue_outlasts_a_put_blocked_by_a_stalled_link():
    from tactiled_service.bus import RELIABLE_QUEUE_SIZE as BUS_QUEUE_SIZE

    # Zenoh closes a link that blocks a put for wait_before_close (us); meanwhile three 1 kHz
    # sensors keep queueing estimates, which must not be dropped.
    wait_us = json.loads(zenoh.Config().get_json(
        "transport/link/tx/queue/congestion_control/block/wait_before_close"))
    assert BUS_QUEUE_SIZE > 3 * 1000 * wait_us / 1e6


def test_prefix_and_tag_helpers():
    assert prefix_of("tactiled/host/finger0/estimate") == ("tactiled/host", "finger0",
                                                          "estimate")
    assert prefix_of("lab/hand1/thumb/frame") == ("lab/hand1", "thumb", "frame")
    assert prefix_of("tactiled/host/health") == ("tactiled/host", "", "health")
    assert prefix_of("tactiled/host/finger0/latest") == ("", "", "")
    text = '{"type":"estimate","seq":3}'
    assert tagged("tactiled/h", text) == '{"prefix":"tactiled/h","type":"estimate","seq":3}'
    assert json.loads(tagged("p", "{}")) == {"prefix": "p"}


def test_example_configuration_and_docs_show_every_zenoh_key():
    from tactiled.settings import load_settings, settings_to_dict

    root = Path(__file__).resolve().parents[2]
    example = root / "deploy" / "tactiled.toml"
    keys = list(settings_to_dict(load_settings(example, {}, {}))["zenoh"])
    text = example.read_text()
    assert [k for k in keys if f"{k} =" not in text and f"# {k} =" not in text] == []
    docs = (root / "docs" / "howto" / "zenoh.md").read_text()
    pipeline = (root / "docs" / "reference" / "configuration.md").read_text()
    for key in keys:
        assert f"`{key}`" in docs and f"`zenoh.{key}`" in pipeline, key
    for key in ("/estimate", "/frame", "/health", "/latest", "liveliness"):
        assert key in docs, key

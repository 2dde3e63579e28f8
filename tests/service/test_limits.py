"""Limits: subscriber count, stalled subscribers (closed 1013 while the others keep receiving,
and their sockets do not linger), TCP_USER_TIMEOUT on accepted sockets."""

from __future__ import annotations

import asyncio
import socket
import time

import pytest
from live import LiveServer
from svc_helpers import http, recv_json, sim_settings, subscribe, ws_connect
from websockets.exceptions import ConnectionClosed

from tactiled_service.options import ServiceOptions
from tactiled_service.server import listen_socket


def test_accepted_sockets_inherit_tcp_user_timeout_and_send_buffer():
    server = listen_socket("127.0.0.1", 0, tcp_user_timeout_s=2.5, send_buffer=65536)
    try:
        server.setblocking(True)
        with socket.create_connection(server.getsockname()[:2], timeout=5):
            conn, _ = server.accept()
            with conn:
                ms = conn.getsockopt(socket.IPPROTO_TCP, socket.TCP_USER_TIMEOUT)
                sndbuf = conn.getsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF)
        assert ms == 2500
        assert sndbuf == 2 * 65536  # Linux doubles it (bookkeeping overhead)
    finally:
        server.close()


def test_listen_socket_errors_name_the_key():
    from tactiled.errors import ConfigError

    busy = listen_socket("127.0.0.1", 0, 1.0)
    try:
        with pytest.raises(ConfigError, match=r"^server\.port: cannot listen on 127\.0\.0\.1"):
            listen_socket("127.0.0.1", busy.getsockname()[1], 1.0)
    finally:
        busy.close()
    with pytest.raises(ConfigError, match=r"^server\.host: cannot resolve"):
        listen_socket("no-such-host.invalid", 0, 1.0)


def test_subscriber_limit(live_server, arun):
    server = live_server(sim_settings(1), ServiceOptions(max_subscribers=2))

    async def main() -> None:
        async with ws_connect(server.ws_url) as a, ws_connect(server.ws_url) as b:
            await recv_json(a)
            await recv_json(b)
            async with ws_connect(server.ws_url) as c:
                with pytest.raises(ConnectionClosed) as info:
                    await recv_json(c)
                assert info.value.rcvd.code == 1013
                assert info.value.rcvd.reason == "too many subscribers (limit 2)"
        # Both gone: there is room again.
        for _ in range(100):
            if not server.call(lambda: len(server.service.ctx.manager.sessions)):
                break
            await asyncio.sleep(0.02)
        async with ws_connect(server.ws_url) as d:
            assert (await recv_json(d))["type"] == "version"

    arun(main())
    assert http(server.url, "GET", "/v1/health").json()["subscribers"]["refused"]["limit"] == 1


def server_side_sockets(server_port: int, client_port: int) -> list[str]:
    """TCP states (hex, /proc/net/tcp) of the server's end of one loopback connection."""
    states = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = open(table, encoding="ascii").read().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            local, remote, state = fields[1], fields[2], fields[3]
            if (int(local.rsplit(":", 1)[1], 16) == server_port
                    and int(remote.rsplit(":", 1)[1], 16) == client_port):
                states.append(state)
    return states


async def stalled_client(url: str, port: int):
    """A client that subscribes to everything and then stops reading: a tiny receive buffer,
    and a client library that stops reading the socket after one queued message."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", port))
    ws = await ws_connect(url, sock=sock, max_queue=1)
    await subscribe(ws, streams=["estimates", "frames"])
    return ws, sock.getsockname()[1]


def test_stalled_subscriber_is_closed_1013_and_others_keep_receiving(arun):
    # TCP_USER_TIMEOUT must exceed the time the server needs to notice (buffers filling, then
    # the send timeout), or the kernel cuts the connection first and no 1013 is ever sent.
    options = ServiceOptions(send_timeout_s=1.0, close_timeout_s=3.0, tcp_user_timeout_s=4.0)
    server = LiveServer(sim_settings(1), options).start()
    try:
        arun(_stall_scenario(server, options), timeout=90)
    finally:
        server.stop()


async def _stall_scenario(server: LiveServer, options: ServiceOptions) -> None:
    manager = server.service.ctx.manager
    healthy = await ws_connect(server.ws_url)
    await subscribe(healthy, streams=["estimates", "frames"])
    arrivals: list[float] = []

    async def read_healthy() -> None:
        async for _ in healthy:
            arrivals.append(time.monotonic())

    reader = asyncio.create_task(read_healthy())
    a, _ = await stalled_client(server.ws_url, server.port)
    b, b_port = await stalled_client(server.ws_url, server.port)
    try:
        t0 = time.monotonic()
        while server.call(lambda: manager.stalled) < 2:
            assert time.monotonic() - t0 < 30, "stalled clients were never closed"
            await asyncio.sleep(0.02)
        stalled_at = time.monotonic()
        # A resumes reading at once: behind its backlog it finds the close frame, 1013.
        with pytest.raises(ConnectionClosed) as info:
            async with asyncio.timeout(options.close_timeout_s):
                while True:
                    await a.recv()
        assert info.value.rcvd is not None, "no close frame: the backlog was cut too soon"
        assert info.value.rcvd.code == 1013 and "too slow" in info.value.rcvd.reason
        # The healthy subscriber never noticed: no gap in what it received.
        during = [t for t in arrivals if t0 - 0.5 <= t <= stalled_at]
        assert len(during) > 50, "the healthy client got almost nothing"
        gaps = [y - x for x, y in zip(during, during[1:])]
        # Held up behind a stalled peer would mean a gap of the send timeout (1 s); a loaded
        # 2-core machine alone has given gaps up to 0.6 s.
        assert max(gaps) < 0.9 * options.send_timeout_s, f"healthy client waited {max(gaps):.2f} s"
        assert server.call(lambda: len(manager.sessions)) == 1
        # B never reads: the server's end of its socket is gone after the linger (abort)
        # plus TCP_USER_TIMEOUT, instead of waiting for ever on a zero window.
        limit = options.close_timeout_s + options.tcp_user_timeout_s + 5.0
        while server_side_sockets(server.port, b_port):
            assert time.monotonic() - stalled_at < limit, (
                f"server socket to the stalled client still there after {limit} s: "
                f"{server_side_sockets(server.port, b_port)}")
            await asyncio.sleep(0.1)
        count = len(arrivals)
        waited = time.monotonic()
        while len(arrivals) <= count:
            assert time.monotonic() - waited < 10, "the healthy client stopped receiving"
            await asyncio.sleep(0.02)
    finally:
        reader.cancel()
        await asyncio.gather(reader, return_exceptions=True)
        for ws in (a, b):
            ws.transport.abort()
        await healthy.close()


def test_stall_close_counts_in_health(arun):
    """The stalled count and the refusals are visible in /v1/health (same server type)."""
    options = ServiceOptions(send_timeout_s=0.5, close_timeout_s=0.5)
    server = LiveServer(sim_settings(1), options).start()
    try:
        async def main() -> None:
            ws, _ = await stalled_client(server.ws_url, server.port)
            try:
                t0 = time.monotonic()
                while True:
                    h = await asyncio.to_thread(
                        lambda: http(server.url, "GET", "/v1/health").json())
                    if h["subscribers"]["stalled"] >= 1:
                        break
                    assert time.monotonic() - t0 < 30
                    await asyncio.sleep(0.1)
                assert h["subscribers"]["count"] == 0
            finally:
                ws.transport.abort()

        arun(main())
    finally:
        server.stop()

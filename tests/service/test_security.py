"""Security: bearer token at the handshake (refused before accept), REST 401/403, dashboard
session cookie, Origin allow-list, Host check in open mode, non-loopback needs a token."""

from __future__ import annotations

import json
import socket
import subprocess
import sys

import httpx
import pytest
from live import LiveServer
from svc_helpers import http, recv_json, sim_settings, subscribe, ws_connect
from websockets.exceptions import InvalidStatus

from tactiled_service.options import ServiceOptions

TOKEN = "t0k3n-for-tests-only"
#: The servers' frame rate (Hz; SHARED_RATE_HZ: the module's shared_server): what is checked is
#: who may connect, not the frame path, which shares the test's interpreter.
RATE_HZ = SHARED_RATE_HZ = 100.0


@pytest.fixture(scope="module")
def token_server():
    server = LiveServer(sim_settings(1, rate_hz=RATE_HZ, **{"server.token": TOKEN}),
                        ServiceOptions(allowed_origins=("http://console.example:8080",)),
                        shared=True).start()
    try:
        yield server
    finally:
        server.stop()


def handshake_status(url: str, arun, **kwargs) -> int:
    async def main() -> int:
        try:
            async with ws_connect(url, **kwargs) as ws:
                await recv_json(ws)
                return 101
        except InvalidStatus as err:
            body = json.loads(err.response.body or b"{}")
            assert body.get("detail"), "a refusal says why"
            return err.response.status_code

    return arun(main())


def raw_handshake_status(port: int, host: str) -> int:
    """The status of a WebSocket handshake sent with ``Host: host``."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall((f"GET /v1/stream HTTP/1.1\r\nHost: {host}\r\nUpgrade: websocket\r\n"
                      "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                      "Sec-WebSocket-Version: 13\r\n\r\n").encode())
        return int(sock.recv(4096).split(b" ", 2)[1])


def test_stream_needs_the_token_before_accept(token_server, arun):
    url = token_server.ws_url
    assert handshake_status(url, arun) == 401
    assert handshake_status(url, arun, additional_headers={"Authorization": "Bearer nope"}) == 403
    assert handshake_status(url, arun, additional_headers={"Authorization": "Basic xyz"}) == 401
    ok = {"Authorization": f"Bearer {TOKEN}"}
    assert handshake_status(url, arun, additional_headers=ok) == 101
    refused = token_server.call(lambda: dict(token_server.service.ctx.manager.refused))
    assert refused["auth"] >= 3  # refused at the handshake: never a session


def test_authorised_stream_delivers(token_server, arun):
    async def main() -> dict:
        async with ws_connect(token_server.ws_url,
                              additional_headers={"Authorization": f"Bearer {TOKEN}"}) as ws:
            await subscribe(ws, streams=["estimates"])
            return await recv_json(ws)

    assert arun(main())["type"] == "estimate"


@pytest.mark.parametrize("method,path", [
    ("GET", "/v1/sensors"), ("GET", "/v1/sensors/finger0/estimate"),
    ("GET", "/v1/sensors/finger0/frame"), ("POST", "/v1/sensors/finger0/tare"),
    ("GET", "/v1/config"), ("PATCH", "/v1/config"), ("GET", "/metrics"),
])
def test_rest_needs_the_token(token_server, method, path):
    kw = {"json": {}} if method == "PATCH" else {}
    r = http(token_server.url, method, path, **kw)
    assert r.status_code == 401 and "Bearer" in r.headers["www-authenticate"]
    assert "authentication required" in r.json()["detail"]
    r = http(token_server.url, method, path, headers={"Authorization": "Bearer wrong"}, **kw)
    assert r.status_code == 403 and r.json()["detail"] == "invalid token"
    r = http(token_server.url, method, path, headers={"Authorization": f"Bearer {TOKEN}"}, **kw)
    assert r.status_code in (200, 503), r.text


def test_health_and_version_stay_public(token_server):
    assert http(token_server.url, "GET", "/v1/health").status_code == 200
    assert http(token_server.url, "GET", "/v1/version").status_code == 200


def test_dashboard_session_cookie(token_server, arun):
    base = token_server.url
    assert http(base, "GET", "/").status_code == 401
    assert http(base, "GET", "/?token=wrong").status_code == 403
    with httpx.Client(base_url=base, timeout=10) as client:
        r = client.get(f"/?token={TOKEN}", follow_redirects=False)
        assert r.status_code == 303 and r.headers["location"] == "/"
        cookie = r.headers["set-cookie"]
        assert "HttpOnly" in cookie and "SameSite=strict" in cookie.replace("Strict", "strict")
        assert TOKEN not in cookie
        page = client.get("/")
        assert page.status_code == 200 and "<canvas" in page.text
        assert client.get("/v1/sensors").status_code == 200
        session = client.cookies.get("tactiled_session")
    # The same cookie opens the stream from the page's origin, and only from there.
    headers = {"Cookie": f"tactiled_session={session}"}
    assert handshake_status(token_server.ws_url, arun, additional_headers=headers,
                            origin=base) == 101
    assert handshake_status(token_server.ws_url, arun, additional_headers=headers,
                            origin="http://evil.example") == 403
    bad = {"Cookie": "tactiled_session=forged"}
    assert handshake_status(token_server.ws_url, arun, additional_headers=bad) == 401


def test_allowed_origin_from_options(token_server, arun):
    ok = {"Authorization": f"Bearer {TOKEN}"}
    assert handshake_status(token_server.ws_url, arun, additional_headers=ok,
                            origin="http://console.example:8080") == 101
    assert handshake_status(token_server.ws_url, arun, additional_headers=ok,
                            origin="http://console.example:8081") == 403


def test_open_mode_checks_origin_and_host(shared_server, arun):
    url = shared_server.ws_url
    assert handshake_status(url, arun) == 101  # no credentials needed on loopback
    assert handshake_status(url, arun, origin=shared_server.url) == 101
    assert handshake_status(url, arun, origin="http://evil.example") == 403
    # A page of another site rebinding its name to 127.0.0.1 (DNS rebinding).
    r = http(shared_server.url, "GET", "/v1/health", headers={"Host": "evil.example"})
    assert r.status_code == 403 and "Host" in r.json()["detail"]
    assert raw_handshake_status(shared_server.port, "evil.example:80") == 403
    assert raw_handshake_status(shared_server.port, f"localhost:{shared_server.port}") == 101
    # Cross-site form posts cannot tare or reconfigure (CSRF).
    r = http(shared_server.url, "POST", "/v1/sensors/finger0/tare",
             headers={"Origin": "http://evil.example"})
    assert r.status_code == 403 and "Origin" in r.json()["detail"]
    r = http(shared_server.url, "GET", "/", headers={"Host": "localhost"})
    assert r.status_code == 200


def test_non_loopback_without_token_exits_2():
    env = {"PATH": "/usr/bin:/bin", "HOME": "/tmp"}
    done = subprocess.run([sys.executable, "-m", "tactiled.cli", "run", "--host", "0.0.0.0",
                           "--port", "0"], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert "server.token" in done.stderr and "loopback" in done.stderr
    assert done.stdout == ""

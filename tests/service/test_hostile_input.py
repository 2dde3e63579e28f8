"""Hostile input against `tactiled run` on loopback (a real daemon process, real sockets, real
WebSocket clients): what a careless or hostile local client can send gets a 4xx or an
``error`` reply naming the problem, never a 5xx, a 1011 or a traceback in the log.

* JSON the daemon cannot represent (lone surrogates in keys and values, ``NaN``, ``1e999``,
  5,000-digit integers), in a ``PATCH /v1/config`` body and in stream messages (the connection
  answers a ping afterwards);
* a 150 MB chunked body: refused (413) when it crosses 64 KiB, the rest never read, the
  daemon's resident memory grows by at most 40 MB (its peak, ``VmHWM`` reset first);
* clients that leave mid-body: counted (``tactiled_http_client_disconnects_total``), one log
  line a minute;
* slow-drip sockets: answered 408 and closed after ``server.read_timeout``;
* CORS: a preflight from an allow-listed origin is answered, from any other it is not.

The daemon's stderr is read all along; every test ends by checking it holds no traceback.
"""

from __future__ import annotations

import json
import re
import signal
import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
from svc_helpers import http, wait_for
from websockets.sync.client import connect

ALLOWED = "http://console.example:8080"
READ_TIMEOUT_S = 2.0
MAX_BODY = 64 * 1024
BAR_RSS_MB = 40.0


class Daemon:
    """`tactiled run` with its stderr collected by a thread (so it never blocks on a full pipe)."""

    def __init__(self, proc: Any) -> None:
        self.proc = proc
        self.url = proc.wait_url()
        self.port = int(self.url.rstrip("/").rsplit(":", 1)[1])
        self.ws_url = self.url.replace("http://", "ws://") + "v1/stream"
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.proc.stderr:
            self.lines.append(line)

    @property
    def log(self) -> str:
        return "".join(self.lines)

    def assert_clean_log(self) -> None:
        """No traceback, no uvicorn "Exception in ASGI application", no internal error."""
        text = self.log
        for mark in ("Traceback", "Exception in ASGI", "internal error", "stream session"):
            assert mark not in text, f"{mark!r} in the daemon's log:\n{text[-3000:]}"

    def metric(self, name: str) -> float:
        text = http(self.url, "GET", "/metrics").text
        found = re.search(rf"^{re.escape(name)} (\S+)$", text, re.MULTILINE)
        assert found, f"{name} not served"
        return float(found.group(1))


@pytest.fixture(scope="module")
def daemon(daemon_process: Any) -> Iterator[Daemon]:
    proc = daemon_process(["--port", "0", "--allow-origin", ALLOWED],
                          env={"TACTILED_SERVER_READ_TIMEOUT": str(READ_TIMEOUT_S)})
    try:
        yield Daemon(proc)
    finally:
        proc.terminate()


def patch(daemon: Daemon, body: bytes, **headers: str) -> Any:
    return http(daemon.url, "PATCH", "/v1/config", content=body,
                headers={"Content-Type": "application/json", **headers})


# --------------------------------------------------------------------------------------------
# JSON the daemon cannot represent


DIGITS = "7" * 5000

REST_CASES = [
    # (body, status, words the detail must hold)
    (r'{"sensors": {"\ud800": {"model": "auto"}}}', 400,
     r"sensors: the key '\ud800' holds a lone UTF-16 surrogate"),
    (r'{"sensors": {"finger0": {"\udfff": "auto"}}}', 400,
     r"sensors.finger0: the key '\udfff' holds a lone UTF-16 surrogate"),
    (r'{"sensors": {"finger0": {"model": "a\ud800"}}}', 400,
     r"sensors.finger0.model: 'a\ud800' holds a lone UTF-16 surrogate"),
    ('{"fit": {"timeout": %s}}' % DIGITS, 400, "fit.timeout: an integer of 5000 digits"),
    ('{"fit": {"timeout": %s}}' % ("7" * 4000), 422,
     "fit.timeout: expected a finite number, got an integer too large for a double"),
    ('{"sensors": {"finger0": {"window": %s}}}' % ("7" * 4000), 422, "sensors.finger0.window"),
    ('{"fit": {"timeout": NaN}}', 400, "fit.timeout: NaN is not a JSON number"),
    ('{"fit": {"timeout": Infinity}}', 400, "fit.timeout: Infinity is not a JSON number"),
    ('{"fit": {"timeout": -Infinity}}', 400, "fit.timeout: -Infinity is not a JSON number"),
    ('{"fit": {"timeout": 1e999}}', 400, "fit.timeout: '1e999' is beyond the range of a double"),
    ("[" * 100 + "]" * 100, 400, "body: nested deeper than 64 levels"),
    ("[" * 50000, 400, "body: not valid JSON"),
]


@pytest.mark.parametrize("body,status,words", REST_CASES, ids=range(len(REST_CASES)))
def test_config_patch_refuses_what_it_cannot_represent(daemon, body, status, words):
    before = http(daemon.url, "GET", "/v1/config").json()
    r = patch(daemon, body.encode())
    assert r.status_code == status, r.text
    assert words in r.json()["detail"], r.json()
    assert http(daemon.url, "GET", "/v1/config").json() == before
    daemon.assert_clean_log()


def test_config_patch_refuses_bytes_that_are_not_utf8(daemon):
    r = patch(daemon, b'{"fit": {"timeout": "\xff"}}')
    assert r.status_code == 400 and r.json()["detail"] == (
        "body: not UTF-8: byte 0xff at offset 21"), r.text
    daemon.assert_clean_log()


STREAM_CASES = [
    ('{"type": "ping", "id": NaN}', "id: NaN is not a JSON number"),
    ('{"type": "ping", "id": 1e999}', "id: '1e999' is beyond the range of a double"),
    ('{"type": "ping", "id": -Infinity}', "id: -Infinity is not a JSON number"),
    ('{"type": "ping", "id": %s}' % DIGITS, "id: an integer of 5000 digits"),
    ('{"type": %s}' % DIGITS, "type: an integer of 5000 digits"),
    (r'{"type": "ping", "id": "\ud800"}', r"id: '\ud800' holds a lone UTF-16 surrogate"),
    (r'{"type": "\udc00"}', r"type: '\udc00' holds a lone UTF-16 surrogate"),
    (r'{"\ud800": 1, "type": "ping"}', r"message: the key '\ud800' holds a lone"),
    (r'{"type": "subscribe", "sensors": ["\ud800"]}', "sensors.0: '\\ud800' holds"),
    ('{"type": "subscribe", "max_rate": %s}' % ("9" * 4000), "max_rate"),
    ('{"type": "subscribe", "max_rate": Infinity}', "max_rate: Infinity is not"),
    ('{"type": "ping", "id": ' + "[" * 80 + "]" * 80 + "}", "nested deeper than 64"),
]


def test_stream_answers_every_bad_message_and_stays_open(daemon):
    with connect(daemon.ws_url, compression=None, open_timeout=10, max_size=2**22) as ws:
        assert json.loads(ws.recv(10))["type"] == "version"
        for n, (text, words) in enumerate(STREAM_CASES):
            ws.send(text)
            reply = json.loads(ws.recv(10))
            assert reply["type"] == "error" and reply["code"] == "bad_message", (text, reply)
            assert words in reply["message"], (text[:80], reply["message"])
            ws.send(json.dumps({"type": "ping", "id": n}))
            assert json.loads(ws.recv(10)) == {"type": "pong", "v": 2, "seq": None, "id": n}
        # A long integer within the limit is echoed as it came.
        ws.send('{"type": "ping", "id": %s}' % ("9" * 4000))
        assert json.loads(ws.recv(10))["id"] == int("9" * 4000)
    daemon.assert_clean_log()


# --------------------------------------------------------------------------------------------
# Bodies bounded as they arrive


def _kib(pid: int, key: str) -> int:
    with open(f"/proc/{pid}/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    raise AssertionError(f"no {key} for pid {pid}")


def send_chunked(port: int, total: int, request: str = "PATCH /v1/config") -> tuple[int, bytes]:
    """``request`` with ``total`` bytes of a JSON array as a chunked body (no Content-Length) while
    reading the answer; stops sending at the first error (the server closed).  Returns the
    bytes sent and the answer."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=30)
    sock.sendall(f"{request} HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: "
                 "application/json\r\nTransfer-Encoding: chunked\r\n\r\n".encode())
    chunk = b"[" + b"1," * 32767 + b"1"  # 64 KiB
    frame = f"{len(chunk):x}\r\n".encode() + chunk + b"\r\n"
    sent = [0]

    def sender() -> None:
        try:
            while sent[0] < total:
                sock.sendall(frame)
                sent[0] += len(chunk)
            sock.sendall(b"0\r\n\r\n")
        except OSError:
            pass  # the server answered and closed: what is wanted

    thread = threading.Thread(target=sender, daemon=True)
    thread.start()
    answer = b""
    try:
        while True:
            data = sock.recv(65536)
            if not data:
                break
            answer += data
    except OSError:
        pass
    thread.join(30)
    sock.close()
    return sent[0], answer


def test_chunked_body_is_refused_at_the_limit_and_never_buffered(daemon):
    pid = daemon.proc.proc.pid
    total = 150 * 2**20
    before_kib = _kib(pid, "VmRSS")
    with open(f"/proc/{pid}/clear_refs", "w", encoding="ascii") as fh:
        fh.write("5")  # VmHWM := VmRSS: the peak from here on
    sent, answer = send_chunked(daemon.port, total)
    growth_mb = (_kib(pid, "VmHWM") - before_kib) / 1024
    print(f"FIGURES chunked_150MB: sent_mb={sent / 2**20:.1f} peak_rss_growth_mb="
          f"{growth_mb:.1f} rss_before_mb={before_kib / 1024:.0f}")
    head, _, body = answer.partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 413 "), answer[:300]
    assert b"connection: close" in head.lower()
    assert json.loads(body) == {"detail": f"body larger than {MAX_BODY} bytes"}
    # Refused when it crossed the limit: what was sent beyond it sat in socket buffers.
    assert sent < 32 * 2**20, f"the server read {sent / 2**20:.0f} MB of a refused body"
    assert growth_mb <= BAR_RSS_MB, f"the daemon grew by {growth_mb:.0f} MB"
    assert http(daemon.url, "GET", "/v1/health").status_code == 200
    daemon.assert_clean_log()


def test_unread_body_closes_the_connection_after_the_answer(daemon):
    """A chunked body to an endpoint that takes none (tare): answered, then disconnected
    rather than read to its end."""
    sent, answer = send_chunked(daemon.port, 150 * 2**20, "POST /v1/sensors/finger0/tare")
    assert answer.startswith(b"HTTP/1.1 200 "), answer[:300]
    assert b'"status":"scheduled"' in answer
    assert sent < 32 * 2**20, f"the server read {sent / 2**20:.0f} MB of an unwanted body"
    daemon.assert_clean_log()


# --------------------------------------------------------------------------------------------
# Clients that leave mid-body, slow drips


def test_clients_leaving_mid_body_are_counted_and_logged_once(daemon):
    before = daemon.metric("tactiled_http_client_disconnects_total")
    leavers = 20
    for _ in range(leavers):
        with socket.create_connection(("127.0.0.1", daemon.port), timeout=10) as sock:
            sock.sendall(b"PATCH /v1/config HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: "
                         b"application/json\r\nContent-Length: 1000\r\n\r\n{\"fit\": ")
    wait_for(lambda: daemon.metric("tactiled_http_client_disconnects_total")
             >= before + leavers, 20, what="every disconnect counted")
    lines = [line for line in daemon.lines if "left before sending the whole body" in line]
    assert len(lines) == 1, lines  # all within a minute: one line
    assert "PATCH '/v1/config'" in lines[0]
    assert http(daemon.url, "GET", "/v1/health").status_code == 200
    daemon.assert_clean_log()


def test_slow_drip_sockets_are_answered_408_and_closed(daemon):
    request = b"GET /v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
    socks = [socket.create_connection(("127.0.0.1", daemon.port), timeout=10)
             for _ in range(20)]
    for sock in socks:
        sock.setblocking(False)
    start = time.monotonic()
    closed: dict[int, float] = {}
    answers = {i: b"" for i in range(len(socks))}
    step = rounds = 0
    try:
        # A byte every 0.2 s from each (the request would take 9 s to arrive), for at most
        # the read timeout and 8 s more.
        while len(closed) < len(socks) and time.monotonic() - start < READ_TIMEOUT_S + 8:
            for i, sock in enumerate(socks):
                if i in closed:
                    continue
                try:
                    data = sock.recv(4096)
                    if not data:
                        closed[i] = time.monotonic() - start
                        continue
                    answers[i] += data
                except BlockingIOError:
                    pass
                except OSError:
                    closed[i] = time.monotonic() - start
                    continue
                try:
                    sock.send(request[step:step + 1])
                except OSError:
                    closed[i] = time.monotonic() - start
            step = min(step + 1, len(request) - 1)
            rounds += 1
            if rounds % 5 == 0:  # meanwhile the server answers others

                assert http(daemon.url, "GET", "/v1/health").status_code == 200
            time.sleep(0.2)
    finally:
        for sock in socks:
            sock.close()
    assert len(closed) == len(socks), f"{len(socks) - len(closed)} slow sockets still open"
    assert min(closed.values()) >= READ_TIMEOUT_S - 0.1, closed
    for i, answer in answers.items():
        assert answer.startswith(b"HTTP/1.1 408 "), (i, answer[:200])
        assert b"server.read_timeout" in answer
    assert daemon.metric('tactiled_http_refused_total{reason="read_timeout"}') >= len(socks)
    daemon.assert_clean_log()


def test_slow_body_is_answered_408_and_a_stream_outlives_the_read_timeout(daemon):
    """Headers in, then a body dripping: 408 once ``read_timeout`` has passed since the
    headers.  A WebSocket session is not a request being read: it stays open past it."""
    with connect(daemon.ws_url, compression=None, open_timeout=10) as ws:
        assert json.loads(ws.recv(10))["type"] == "version"
        with socket.create_connection(("127.0.0.1", daemon.port), timeout=10) as sock:
            sock.sendall(b"PATCH /v1/config HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: "
                         b"application/json\r\nContent-Length: 100\r\n\r\n")
            start = time.monotonic()
            answer = b""
            sock.setblocking(False)
            n = 0
            while time.monotonic() - start < READ_TIMEOUT_S + 8:
                try:
                    data = sock.recv(4096)
                    if not data:
                        break
                    answer += data
                except BlockingIOError:
                    pass
                except OSError:
                    break
                try:
                    sock.send(b" ")  # a byte every 0.2 s: 100 would take 20 s
                except OSError:
                    break
                # The stream answers all along.
                ws.send(json.dumps({"type": "ping", "id": n}))
                assert json.loads(ws.recv(10))["id"] == n
                n += 1
                time.sleep(0.2)
            took = time.monotonic() - start
        assert answer.startswith(b"HTTP/1.1 408 "), answer[:300]
        assert b"body not received within 2 s (server.read_timeout)" in answer
        assert took >= READ_TIMEOUT_S - 0.1
        ws.send(json.dumps({"type": "ping", "id": "after"}))
        assert json.loads(ws.recv(10))["id"] == "after"
    daemon.assert_clean_log()


# --------------------------------------------------------------------------------------------
# CORS


@pytest.mark.parametrize("path,methods", [("/v1/config", "GET, PATCH"),
                                          ("/v1/sensors/finger0/tare", "POST")])
def test_preflight_answered_for_an_allowed_origin_only(daemon, path, methods):
    ask = {"Access-Control-Request-Method": methods.split(", ")[-1],
           "Access-Control-Request-Headers": "authorization, content-type"}
    r = http(daemon.url, "OPTIONS", path, headers={"Origin": ALLOWED, **ask})
    assert r.status_code == 204, r.text
    assert r.headers["access-control-allow-origin"] == ALLOWED
    assert r.headers["access-control-allow-methods"] == methods
    assert r.headers["access-control-allow-headers"] == "Authorization, Content-Type"
    assert r.headers["vary"] == "Origin"
    for origin in ("http://evil.example", "http://console.example:8081"):
        r = http(daemon.url, "OPTIONS", path, headers={"Origin": origin, **ask})
        assert r.status_code == 405, r.text
        assert not any(k.startswith("access-control-") for k in r.headers), r.headers
    daemon.assert_clean_log()


def test_allowed_origin_reads_the_answer_and_others_are_refused(daemon):
    r = patch(daemon, b"{}", Origin=ALLOWED)
    assert r.status_code == 200 and r.headers["access-control-allow-origin"] == ALLOWED
    r = patch(daemon, b"{}", Origin="http://evil.example")
    assert r.status_code == 403 and "access-control-allow-origin" not in r.headers
    r = http(daemon.url, "GET", "/v1/health", headers={"Origin": "http://evil.example"})
    assert r.status_code == 200 and "access-control-allow-origin" not in r.headers
    daemon.assert_clean_log()


def test_openapi_names_the_configured_sensors(daemon):
    spec = http(daemon.url, "GET", "/v1/openapi.json").json()
    body = spec["paths"]["/v1/config"]["patch"]["requestBody"]["content"]["application/json"]
    sensors = body["schema"]["properties"]["sensors"]
    assert sensors["propertyNames"] == {"enum": ["finger0"]}
    assert list(sensors["properties"]) == ["finger0"] and sensors["additionalProperties"] is False
    assert "408" in spec["paths"]["/v1/config"]["patch"]["responses"]


def test_the_log_holds_no_traceback_after_a_graceful_stop(daemon):
    """Last: everything above against one daemon, then SIGTERM; exit 0, a clean log."""
    daemon.proc.proc.send_signal(signal.SIGTERM)
    assert daemon.proc.proc.wait(15) == 0
    daemon._reader.join(5)
    daemon.assert_clean_log()

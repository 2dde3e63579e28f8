"""`tactiled run` as a subprocess: the address line, health, SIGTERM (exit 0 within 5 s,
subscribers get 1001), a second SIGINT forcing the exit, configuration errors (exit 2), and
the precedence of flags over environment over file."""

from __future__ import annotations

import argparse
import json
import re
import signal
import socket
import threading
import time
from pathlib import Path

import pytest
from svc_helpers import http, recv_json, subscribe, ws_connect
from websockets.exceptions import ConnectionClosed

from tactiled.settings import DEFAULT_PORT, load_settings


class NotifySocket:
    """A stand-in for systemd's notification socket: collects the datagrams sent to it."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.settimeout(0.05)
        self.messages: list[str] = []

    def drain(self) -> list[str]:
        while True:
            try:
                self.messages.append(self.sock.recv(4096).decode())
            except (TimeoutError, BlockingIOError):
                return self.messages

    def close(self) -> None:
        self.sock.close()


def test_run_prints_the_address_serves_and_stops_on_sigterm(daemon_process, arun, tmp_path):
    notify = NotifySocket(tmp_path / "notify")
    record = tmp_path / "finger0.tact"
    proc = daemon_process(["--port", "0"], env={
        "NOTIFY_SOCKET": str(notify.path), "WATCHDOG_USEC": "200000",
        "TACTILED_RECORD_PATH": str(record)})
    url = proc.wait_url()
    assert re.fullmatch(r"http://127\.0\.0\.1:\d+/", url), url
    t = time.monotonic()
    while sum("WATCHDOG=1" in m for m in notify.drain()) < 2:  # pings while frames flow
        assert time.monotonic() - t < 10, notify.messages
    health = http(url, "GET", "/v1/health")
    assert health.status_code == 200 and health.json()["state"] == "running"
    assert "<canvas" in http(url, "GET", "/").text

    async def main() -> tuple[int, float]:
        ws_url = url.replace("http://", "ws://") + "v1/stream"
        async with ws_connect(ws_url) as ws:
            await subscribe(ws, streams=["estimates"], max_rate=50)
            assert (await recv_json(ws))["type"] == "estimate"
            t0 = time.monotonic()
            proc.proc.send_signal(signal.SIGTERM)
            with pytest.raises(ConnectionClosed) as info:
                while True:
                    await recv_json(ws, timeout=10)
            return info.value.rcvd.code if info.value.rcvd else None, t0

    code, t0 = arun(main())
    assert code == 1001, "subscribers get 'going away' on shutdown"
    rc = proc.proc.wait(10)
    took = time.monotonic() - t0
    assert rc == 0, proc.proc.stderr.read()
    assert took < 5.0, f"graceful shutdown took {took:.2f} s"
    assert proc.proc.stdout.read() == "", "the address is the only line on stdout"
    # sd_notify: READY once serving, watchdog pings while frames flow, STOPPING at the end.
    fields = [line for msg in notify.drain() for line in msg.split("\n")]
    notify.close()
    assert fields[0] == "READY=1", fields[:3]
    assert fields.count("WATCHDOG=1") >= 2
    assert "STOPPING=1" in fields and fields.index("STOPPING=1") > fields.index("READY=1")
    assert any(f.startswith("STATUS=") for f in fields)
    # The recording was flushed and closed: complete records, none cut short.
    from tactiled.io.recording import RecordingReader

    with RecordingReader(record) as reader:
        count = sum(1 for _ in reader)
        assert count > 100 and not reader.truncated


def test_second_sigint_forces_exit(daemon_process):
    proc = daemon_process(["--port", "0"])
    proc.wait_url()
    lines: list[str] = []
    started = threading.Event()

    def watch_stderr() -> None:
        for line in proc.proc.stderr:
            lines.append(line)
            if "shutting down" in line:
                started.set()

    threading.Thread(target=watch_stderr, daemon=True).start()
    proc.proc.send_signal(signal.SIGINT)
    assert started.wait(10), "no sign of a graceful stop after SIGINT"
    t0 = time.monotonic()
    proc.proc.send_signal(signal.SIGINT)
    rc = proc.proc.wait(10)
    assert rc == 130, f"exit code {rc}: {''.join(lines)}"
    assert time.monotonic() - t0 < 2.0
    assert any("second interrupt" in line for line in lines)


@pytest.mark.parametrize("config,words", [
    ("[server]\nport = \"eighty\"\n", "server.port: expected an integer"),
    ("[server]\nprot = 80\n", "server.prot: unknown key"),
    ("[[sensor]]\nurl = \"ftp://x\"\n", "sensor[0].url: unknown scheme"),
    ("[server\n", "not valid TOML"),
])
def test_invalid_configuration_exits_2_naming_the_key(daemon_process, tmp_path, config, words):
    path = tmp_path / "bad.toml"
    path.write_text(config)
    proc = daemon_process(["--config", str(path)])
    rc = proc.proc.wait(60)
    err = proc.proc.stderr.read()
    assert rc == 2, err
    assert words in err and err.count("\n") == 1, err
    assert proc.proc.stdout.read() == ""


def test_busy_port_exits_2(daemon_process):
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        proc = daemon_process(["--port", str(busy.getsockname()[1])])
        rc = proc.proc.wait(60)
    assert rc == 2 and "server.port: cannot listen" in proc.proc.stderr.read()


def run_args(*argv: str) -> argparse.Namespace:
    from tactiled.cli import build_parser

    return build_parser(only="run").parse_args(["run", *argv])


def settings_for(args: argparse.Namespace, env: dict[str, str]):
    from tactiled.commands import run

    saved = dict(run.os.environ)
    try:
        run.os.environ.clear()
        run.os.environ.update(env)
        return load_settings(args.config, env, run._overrides(args))
    finally:
        run.os.environ.clear()
        run.os.environ.update(saved)


def test_flags_win_over_environment_over_file(tmp_path: Path):
    cfg = tmp_path / "t.toml"
    cfg.write_text("[server]\nport = 1111\ntoken = \"from-file\"\nhost = \"127.0.0.1\"\n")
    env = {"TACTILED_SERVER_PORT": "2222", "TACTILED_TOKEN": "from-env"}
    s = settings_for(run_args("--config", str(cfg)), {})
    assert (s.server.port, s.server.token) == (1111, "from-file")
    s = settings_for(run_args("--config", str(cfg)), env)
    assert (s.server.port, s.server.token) == (2222, "from-env")
    s = settings_for(run_args("--config", str(cfg), "--port", "3333", "--token", "flag"), env)
    assert (s.server.port, s.server.token) == (3333, "flag")


def test_run_accepts_verbose_after_the_command():
    assert run_args("-v", "-v").verbose == 2
    assert run_args().port is None


def test_defaults_are_the_demo_finger_on_the_documented_port():
    s = settings_for(run_args(), {})
    assert (s.server.host, s.server.port) == ("127.0.0.1", DEFAULT_PORT)
    assert [x.url for x in s.sensors] == ["sim://?scene=demo&seed=1"]
    doc = (Path(__file__).resolve().parents[2] / "docs" / "reference" / "api.md").read_text()
    assert f"127.0.0.1:{DEFAULT_PORT}" in doc
    assert json.dumps(DEFAULT_PORT) == "8765"


def test_server_limits_in_the_config_file_reach_the_service(daemon_process, arun, tmp_path):
    """``[server] max_subscribers`` and ``allow_origins`` from the file are what ``tactiled
    run`` serves with: a second stream connection is closed 1013, the listed origin is let in
    and another one refused (403 before accept)."""
    config = tmp_path / "tactiled.toml"
    config.write_text('[server]\nport = 0\nmax_subscribers = 1\n'
                      'allow_origins = ["http://console.local:8080"]\n', encoding="utf-8")
    proc = daemon_process(["--config", str(config)])
    ws_url = proc.wait_url().replace("http://", "ws://") + "v1/stream"

    async def main() -> tuple[int | None, int]:
        from websockets.exceptions import InvalidStatus

        async with ws_connect(ws_url, origin="http://console.local:8080") as first:
            await subscribe(first, streams=["estimates"], max_rate=10)
            async with ws_connect(ws_url) as second:
                with pytest.raises(ConnectionClosed) as closed:
                    while True:
                        await recv_json(second)
            code = closed.value.rcvd.code if closed.value.rcvd else None
        with pytest.raises(InvalidStatus) as refused:
            async with ws_connect(ws_url, origin="http://elsewhere.local:8080"):
                pass
        return code, refused.value.response.status_code

    code, status = arun(main())
    proc.proc.send_signal(signal.SIGTERM)
    assert proc.proc.wait(10) == 0
    assert code == 1013 and status == 403

"""`tactiled run` speaks the notification protocol as tactiled.service expects (Type=notify,
NotifyAccess=main, WatchdogSec=): started the way systemd starts it, with $NOTIFY_SOCKET,
$WATCHDOG_USEC and $WATCHDOG_PID (= the daemon's own pid) pointing at a test socket."""

from __future__ import annotations

import http.client
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from deploy_helpers import ROOT, NotifySocket

RUN_MODULE = ROOT / "tactiled" / "commands" / "run.py"
WATCHDOG_USEC = 2_000_000  # pings expected every 1 s
GRACEFUL_STOP_S = 5.0  # tactiled.service's comment promises this (TimeoutStopSec=10s)
START_TIMEOUT_S = 40.0  # worker warm-up on a loaded machine


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _http_answers(port: int) -> bool:
    """Any HTTP response (even 404) on GET / means the server is serving."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=2)
    try:
        conn.request("GET", "/")
        return conn.getresponse().status > 0
    except OSError:
        return False
    finally:
        conn.close()


def _fields(data: bytes) -> dict[str, str]:
    return dict(line.split("=", 1) for line in data.decode().split("\n") if "=" in line)


def daemon_command() -> list[str]:
    exe = Path(sys.executable).with_name("tactiled")
    cli = [str(exe)] if exe.exists() else [sys.executable, "-m", "tactiled.cli"]
    # systemd sets WATCHDOG_PID to the main pid before exec; `exec` keeps the shell's pid.
    return ["/bin/sh", "-c", 'WATCHDOG_PID=$$ exec "$@"', "sh", *cli, "run"]


def watch_daemon(cmd: list[str], sock: NotifySocket, tmp_path: Path) -> None:
    """Start ``cmd`` as systemd would and check READY / WATCHDOG / STOPPING."""
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("TACTILED_", "NOTIFY_",
                                                                   "WATCHDOG_"))}
    env.update(NOTIFY_SOCKET=sock.address, WATCHDOG_USEC=str(WATCHDOG_USEC),
               TACTILED_SERVER_HOST="127.0.0.1", TACTILED_SERVER_PORT=str(port),
               TACTILED_FIT_WORKERS="1")
    out, err = open(tmp_path / "stdout", "wb"), open(tmp_path / "stderr", "wb")
    proc = subprocess.Popen(cmd, env=env, stdout=out, stderr=err, start_new_session=True)

    def log_tail() -> str:
        return (tmp_path / "stderr").read_text(errors="replace")[-3000:]

    try:
        # 1. READY=1, and only once the HTTP port answers.
        deadline = time.monotonic() + START_TIMEOUT_S
        before_ready = []
        while True:
            msg = sock.recv(timeout=0.2)
            if msg is not None:
                assert msg.pid == proc.pid, (
                    f"notification {msg.data!r} came from pid {msg.pid}, not the main process "
                    f"{proc.pid}: NotifyAccess=main would ignore it")
                if _fields(msg.data).get("READY") == "1":
                    assert _http_answers(port), (
                        "READY=1 arrived before the HTTP port answered: systemctl start would "
                        "return while the API is not yet up")
                    break
                before_ready.append(msg.data)
            assert proc.poll() is None, f"tactiled run exited ({proc.returncode}):\n{log_tail()}"
            assert time.monotonic() < deadline, (
                f"no READY=1 within {START_TIMEOUT_S} s (got {before_ready}):\n{log_tail()}")

        # 2. WATCHDOG=1 every WATCHDOG_USEC/2 while the simulated sensor streams frames (three
        # pings, two gaps, are enough: no need to sit out the whole window).
        pings: list[float] = []
        end = time.monotonic() + 3.6
        while time.monotonic() < end and len(pings) < 3:
            msg = sock.recv(timeout=max(0.01, end - time.monotonic()))
            if msg is None:
                continue
            assert msg.pid == proc.pid
            f = _fields(msg.data)
            assert "READY" not in f, "READY=1 sent twice"
            if f.get("WATCHDOG") == "1":
                pings.append(msg.at)
        assert len(pings) >= 2, f"expected WATCHDOG=1 about every 1 s, got {len(pings)} in " \
                                f"3.6 s:\n{log_tail()}"
        gaps = [b - a for a, b in zip(pings, pings[1:])]
        assert max(gaps) < WATCHDOG_USEC / 1e6, f"watchdog gaps {gaps} would trip WatchdogSec"

        # 3. SIGTERM (KillSignal=): STOPPING=1, then a clean exit in time.
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        stopping = False
        while proc.poll() is None or not stopping:
            msg = sock.recv(timeout=0.2)
            if msg is not None and _fields(msg.data).get("STOPPING") == "1":
                assert msg.pid == proc.pid
                stopping = True
            if time.monotonic() - t0 > GRACEFUL_STOP_S:
                break
        elapsed = time.monotonic() - t0
        assert stopping, f"no STOPPING=1 after SIGTERM:\n{log_tail()}"
        assert proc.poll() is not None, (
            f"still running {GRACEFUL_STOP_S} s after SIGTERM (TimeoutStopSec margin)")
        assert proc.returncode == 0, f"exit status {proc.returncode} after SIGTERM:\n{log_tail()}"
        assert elapsed < GRACEFUL_STOP_S
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)  # our own session: the daemon and its workers
            proc.wait(5)
        out.close()
        err.close()


@pytest.mark.timeout(90)
def test_tactiled_run_notifies_systemd(notify_socket, tmp_path):
    if not RUN_MODULE.exists():
        pytest.fail(f"{RUN_MODULE.relative_to(ROOT)} does not exist yet: `tactiled run` (the "
                    "daemon that deploy/tactiled.service starts with Type=notify) is not "
                    "written, so its READY/WATCHDOG/STOPPING notifications cannot be checked")
    watch_daemon(daemon_command(), notify_socket, tmp_path)

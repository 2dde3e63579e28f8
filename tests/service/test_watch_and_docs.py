"""`tactiled watch` against a live server, and the Python client example of docs/reference/api.md run
exactly as written."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

from svc_helpers import FIT_LINE_KEYS

ROOT = Path(__file__).resolve().parents[2]


def run_cli(*args: str, env: dict[str, str] | None = None,
            timeout: float = 60) -> subprocess.CompletedProcess[str]:
    full_env = {k: v for k, v in os.environ.items() if not k.startswith("TACTILED_")}
    full_env.update(env or {})
    return subprocess.run([sys.executable, "-m", "tactiled.cli", *args], env=full_env,
                          capture_output=True, text=True, timeout=timeout)


def test_watch_prints_estimates_one_json_per_line(shared_server):
    done = run_cli("watch", shared_server.ws_url, "--count", "5")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert len(lines) == 5
    for line in lines:
        msg = json.loads(line)
        assert msg["type"] == "estimate" and FIT_LINE_KEYS <= set(msg)


def test_watch_sensor_filter_and_frames(shared_server):
    host_port = shared_server.url.removeprefix("http://")
    done = run_cli("watch", host_port, "--sensor", "finger1", "--frames", "--count", "30")
    assert done.returncode == 0, done.stderr
    msgs = [json.loads(line) for line in done.stdout.splitlines()]
    assert {m["sensor"] for m in msgs} == {"finger1"}
    assert {m["type"] for m in msgs} == {"estimate", "frame"}


def test_watch_errors(shared_server):
    done = run_cli("watch", shared_server.ws_url, "--sensor", "nope", "--count", "1")
    assert done.returncode == 2 and "unknown sensor(s) 'nope'" in done.stderr
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        free = s.getsockname()[1]
    done = run_cli("watch", f"ws://127.0.0.1:{free}/v1/stream", "--count", "1")
    assert done.returncode == 1 and "cannot connect" in done.stderr


def python_example() -> str:
    text = (ROOT / "docs" / "reference" / "api.md").read_text()
    section = text.split("## Python client example", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert len(blocks) == 1, "one python block in the section"
    return blocks[0]


def test_docs_python_client_example_runs_as_written(shared_server, tmp_path):
    script = tmp_path / "client.py"
    script.write_text(python_example())
    env = {k: v for k, v in os.environ.items() if not k.startswith("TACTILED_")}
    env["TACTILED_URL"] = shared_server.ws_url
    done = subprocess.run([sys.executable, str(script)], env=env, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("tactiled ") and "finger0" in lines[0]
    assert len(lines) == 11
    assert all(re.match(r"finger[01] #\d+: ", line) for line in lines[1:]), lines


def test_docs_name_every_endpoint_and_message():
    text = (ROOT / "docs" / "reference" / "api.md").read_text()
    for needle in ("GET /v1/health", "GET /v1/sensors", "GET /v1/sensors/{name}/estimate",
                   "GET /v1/sensors/{name}/frame", "POST /v1/sensors/{name}/tare",
                   "GET /v1/config", "PATCH /v1/config", "GET /v1/version", "/v1/stream",
                   '"type": "version"', '"type": "subscribed"', '"type": "estimate"',
                   '"type": "frame"', '"type": "error"', '"type": "pong"', "1001", "1009",
                   "1013", "TCP_USER_TIMEOUT", "Origin", "Bearer"):
        assert needle in text, needle

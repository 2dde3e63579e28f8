"""A real ``tactiled run`` heard by ROS 2 subscribers that are not ours, on each middleware.

* **DDS**: ``[ros2]`` on and no ``[zenoh]``, so DDS by default (``middleware = "dds"``
  resolves the same: tests/ros2/test_ros2_settings.py); the subscriber is a plain Cyclone DDS
  reader in another process with its own IDL types (``dds_wrench_reader.py``), on a private
  ``ROS_DOMAIN_ID`` with discovery on the loopback interface only (``CYCLONEDDS_URI``), so
  nothing leaves the machine.  One daemon serves the three DDS tests (a reader on its domain,
  one on another and ``tactiled watch --ros2``, at once).
* **Zenoh**: ``--ros2`` on a loopback Zenoh port, multicast scouting off; the subscriber is
  zenoh-ros2-sdk's ``ROS2Subscriber``, which computes rmw_zenoh's key expression itself.

Either way, in 5 s: at least 200 ``WrenchStamped`` (the simulated finger runs at 200 Hz),
``frame_id`` the sensor's name, stamps strictly increasing and never repeated, forces finite.
Waits have deadlines; nothing here asserts a speed beyond the 200-in-5-s bar.
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

HERE = Path(__file__).resolve().parent
PYTHON = sys.executable
RATE_HZ = 200
SECONDS = 5.0
#: Cyclone DDS on the loopback interface only (multicast there for discovery).
LOOPBACK = ('<CycloneDDS><Domain id="any"><General><Interfaces>'
            '<NetworkInterface name="lo" multicast="true"/></Interfaces>'
            '<AllowMulticast>spdp</AllowMulticast></General></Domain></CycloneDDS>')


def private_domain() -> int:
    """A ROS_DOMAIN_ID of this test run alone (0..232; 0 and the common low ids avoided)."""
    return 100 + os.getpid() % 120


@contextmanager
def daemon(args: list[str], env: dict[str, str]) -> Iterator[subprocess.Popen[str]]:
    full = {k: v for k, v in os.environ.items() if not k.startswith(("TACTILED_", "ROS_"))}
    full.update({"TACTILED_FIT_WORKERS": "1",
                 "TACTILED_SENSOR_0_URL": f"sim://?scene=demo&seed=3&rate={RATE_HZ}"}, **env)
    proc = subprocess.Popen([PYTHON, "-m", "tactiled.cli", "run", "--port", "0", *args],
                            env=full, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line: list[str] = []
        reader = threading.Thread(target=lambda: line.append(proc.stdout.readline()),
                                  daemon=True)
        reader.start()
        reader.join(90)
        if not line or not line[0]:
            proc.kill()
            pytest.fail(f"tactiled run did not start; stderr:\n{proc.stderr.read()}")
        yield proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)


def check(samples: list[tuple[str, int, int, list[float]]]) -> None:
    """The bar: >= 200 in 5 s, the sensor's frame_id, stamps strictly increasing, finite."""
    assert len(samples) >= 200, len(samples)
    assert {frame_id for frame_id, *_ in samples} == {"finger0"}
    stamps = [sec * 1_000_000_000 + nanosec for _, sec, nanosec, _ in samples]
    repeats = sum(a == b for a, b in zip(stamps, stamps[1:]))
    assert repeats == 0, f"{repeats} of {len(stamps)} consecutive stamps repeated"
    assert all(b > a for a, b in zip(stamps, stamps[1:])), "stamps went back"
    assert abs(stamps[-1] * 1e-9 - time.time()) < 60, "stamps are not Unix time"
    assert all(math.isfinite(v) for *_, values in samples for v in values)


def _dds_reader(domain: int, seconds: float, wait_s: float,
                env: dict[str, str]) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [PYTHON, str(HERE / "dds_wrench_reader.py"), str(domain), "rt/tactiled/finger0/wrench",
         str(seconds), str(wait_s)], env={**os.environ, **env}, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True)


@pytest.fixture(scope="module")
def dds_heard() -> dict[str, tuple[int, str, str]]:
    """One ``tactiled run`` with ``[ros2]`` on and no ``[zenoh]`` (so DDS, by default) on a
    private domain, and, started together once it is up, two plain DDS readers (one on its
    domain; one on the next, which listens for 8 s while the first hears the stream) and
    ``tactiled watch --ros2`` on its domain.  Each one's (exit code, stdout, stderr), by
    "same", "other" and "watch"."""
    domain = private_domain()
    env = {"CYCLONEDDS_URI": LOOPBACK}
    readers: dict[str, subprocess.Popen[str]] = {}
    heard: dict[str, tuple[int, str, str]] = {}
    try:
        with daemon([], {**env, "TACTILED_ROS2_ENABLED": "true",
                         "TACTILED_ROS2_DOMAIN_ID": str(domain)}):
            readers["same"] = _dds_reader(domain, SECONDS, 90, env)
            readers["other"] = _dds_reader(domain + 1, 1, 8, env)
            full = {k: v for k, v in os.environ.items()
                    if not k.startswith(("TACTILED_", "ROS_"))}
            readers["watch"] = subprocess.Popen(
                [PYTHON, "-m", "tactiled.cli", "watch", "--ros2", "--ros2-middleware", "dds",
                 "--domain-id", str(domain), "--count", "20"], env={**full, **env},
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for name, reader in readers.items():
                out, err = reader.communicate(timeout=150)
                heard[name] = (reader.returncode, out, err)
    finally:
        for reader in readers.values():
            if reader.poll() is None:
                reader.kill()
                reader.wait(5)
    return heard


def test_dds_reader_of_its_own_hears_tactiled_run(dds_heard) -> None:
    code, out, err = dds_heard["same"]
    assert code == 0, err
    samples = [(s[0], s[1], s[2], s[3:]) for s in json.loads(out)["samples"]]
    check(samples)


def test_dds_other_domain_hears_nothing(dds_heard) -> None:
    """The domain id separates graphs: a reader on another domain, listening while the
    daemon's own domain hears the stream, gets no sample."""
    code, out, err = dds_heard["other"]
    assert code == 0, err
    assert json.loads(dds_heard["same"][1])["samples"], "the daemon's own domain heard nothing"
    assert json.loads(out)["samples"] == []


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_zenoh_sdk_subscriber_hears_no_repeated_stamp(tmp_path: Path) -> None:
    from zenoh_ros2_sdk import ROS2Subscriber
    from zenoh_ros2_sdk.message_registry import get_registry
    from zenoh_ros2_sdk.session import ZenohSession

    definitions = {
        "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
        "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
        "geometry_msgs/msg/Wrench": "Vector3 force\nVector3 torque\n",
        "geometry_msgs/msg/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
        "geometry_msgs/msg/WrenchStamped": "std_msgs/Header header\nWrench wrench\n",
    }
    for typename, text in definitions.items():
        path = tmp_path.joinpath(*typename.split("/")).with_suffix(".msg")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    get_registry(str(tmp_path))  # local definitions, never a download
    port = free_port()
    heard: list[Any] = []
    with daemon(["--ros2"], {"TACTILED_ZENOH_MULTICAST_SCOUTING": "false",
                             "TACTILED_ZENOH_LISTEN": f"tcp/127.0.0.1:{port}"}):
        sdk = ZenohSession.get_instance("127.0.0.1", port)
        for typename in ("builtin_interfaces/msg/Time", "std_msgs/msg/Header",
                         "geometry_msgs/msg/Vector3", "geometry_msgs/msg/Wrench"):
            sdk.register_message_type(definitions[typename], typename)
        sub = ROS2Subscriber("/tactiled/finger0/wrench", "geometry_msgs/msg/WrenchStamped",
                             lambda m: heard.append((time.monotonic(), m)),
                             msg_definition=definitions["geometry_msgs/msg/WrenchStamped"],
                             router_ip="127.0.0.1", router_port=port)
        try:
            deadline = time.monotonic() + 90
            while not heard and time.monotonic() < deadline:
                time.sleep(0.05)
            assert heard, "no WrenchStamped within 90 s"
            first = heard[0][0]
            while time.monotonic() < first + SECONDS:
                time.sleep(0.05)
        finally:
            sub.close()
            sdk.close()
    window = [m for t, m in list(heard) if t <= first + SECONDS]
    check([(m.header.frame_id, m.header.stamp.sec, m.header.stamp.nanosec,
            [m.wrench.force.x, m.wrench.force.y, m.wrench.force.z, m.wrench.torque.x,
             m.wrench.torque.y, m.wrench.torque.z]) for m in window])


def test_watch_ros2_reads_dds(dds_heard) -> None:
    code, out, err = dds_heard["watch"]
    assert code == 0, err
    lines = [json.loads(line) for line in out.splitlines()]
    assert len(lines) == 20
    kinds = {line["topic"] for line in lines}
    assert kinds <= {f"/tactiled/finger0/{k}" for k in ("wrench", "contact", "contacts",
                                                         "markers")} | {"/diagnostics"}
    wrenches = [x for x in lines if x["type"] == "geometry_msgs/msg/WrenchStamped"]
    assert wrenches and all(w["message"]["header"]["frame_id"] == "finger0" for w in wrenches)
    assert all(x["source_timestamp_ns"] > 0 for x in lines)

"""`tactiled run --ros2`: a real daemon's ROS 2 topics, heard by code that is not ours.

One daemon (a separate process, simulated finger at 200 Hz) listens on a loopback Zenoh port
with multicast scouting off, and records to ``.tact`` and MCAP (``[record] format = "both"``).
Three readers:

* zenoh-ros2-sdk's ``ROS2Subscriber`` -- an independent client library that follows
  rmw_zenoh's layout, computing the key expression and type hash itself from local message
  definitions (no network) -- subscribes to ``/tactiled/finger0/contact`` and ``.../wrench``
  and must receive every estimate the daemon publishes as JSON on Zenoh over the same span,
  with the same values;
* a plain Zenoh subscriber on ``0/**`` decodes every payload with the MCAP project's ROS 2
  decoder and every attachment with Zenoh's deserializer (sequence numbers from 1 without a
  gap, the publisher's GID);
* a liveliness query reads the node's and publishers' tokens, checked against rmw_zenoh's
  documented layout.

Waits have deadlines; nothing here asserts a speed.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from mcap.reader import make_reader
from mcap_ros2._dynamic import generate_dynamic
from mcap_ros2.decoder import DecoderFactory
from zenoh.ext import Int64, z_deserialize

from tactiled_service.ros2 import messages, rmw

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "ros2"))
from test_ros2_rmw import parse_token  # noqa: E402  (rmw_zenoh's token rules)

PYTHON = sys.executable
RATE_HZ = 200
FRAME_RATE_HZ = 20  # [zenoh] frame_rate_hz: strain images per second, at most
PREFIX = "tactiled/ros2-test"
#: Local message definitions for the SDK (what a ROS install has in share/*/msg).
DEFINITIONS = {
    "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
    "geometry_msgs/msg/Wrench": "Vector3 force\nVector3 torque\n",
    "geometry_msgs/msg/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/WrenchStamped": "std_msgs/Header header\nWrench wrench\n",
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(check: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.1)


def client(endpoint: str) -> Any:
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"client"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return zenoh.open(cfg)


class Node:
    def __init__(self, proc: Any, port: int, record: Path, url: str) -> None:
        self.proc, self.port, self.record, self.url = proc, port, record, url
        self.endpoint = f"tcp/127.0.0.1:{port}"


@pytest.fixture(scope="module")
def node(daemon_process: Callable[..., Any],
         tmp_path_factory: pytest.TempPathFactory) -> Iterator[Node]:
    port = free_port()
    record = tmp_path_factory.mktemp("ros2rec") / "{sensor}.tact"
    env = {"TACTILED_ZENOH_MULTICAST_SCOUTING": "false", "TACTILED_ZENOH_PREFIX": PREFIX,
           "TACTILED_ZENOH_LISTEN": f"tcp/127.0.0.1:{port}",
           "TACTILED_ZENOH_FRAME_RATE_HZ": str(FRAME_RATE_HZ), "TACTILED_FIT_WORKERS": "1",
           "TACTILED_SENSOR_0_URL": f"sim://?scene=demo&seed=3&rate={RATE_HZ}",
           "TACTILED_RECORD_PATH": str(record), "TACTILED_RECORD_FORMAT": "both"}
    proc = daemon_process(["--port", "0", "--ros2"], env=env)
    try:
        url = proc.wait_url()
        yield Node(proc, port, record, url)
    finally:
        proc.terminate()


@pytest.fixture(scope="module")
def heard(node: Node, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The SDK's contacts and wrenches, the raw ROS samples and the JSON estimates, heard
    until every topic has spoken and a contact is under way (and how many seconds that was)."""
    from zenoh_ros2_sdk import ROS2Subscriber
    from zenoh_ros2_sdk.message_registry import get_registry
    from zenoh_ros2_sdk.session import ZenohSession

    msgdir = tmp_path_factory.mktemp("msgs")
    for typename, text in DEFINITIONS.items():
        path = msgdir.joinpath(*typename.split("/")).with_suffix(".msg")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    get_registry(str(msgdir))  # the SDK's registry: these local files, never a download
    sdk = ZenohSession.get_instance("127.0.0.1", node.port)
    for typename in ("builtin_interfaces/msg/Time", "std_msgs/msg/Header",
                     "geometry_msgs/msg/Vector3", "geometry_msgs/msg/Wrench"):
        sdk.register_message_type(DEFINITIONS[typename], typename)
    contacts: list[Any] = []
    wrenches: list[Any] = []
    subs = [ROS2Subscriber("/tactiled/finger0/contact", messages.CONTACT_TYPE, contacts.append,
                           msg_definition=messages.contact_definition(),
                           router_ip="127.0.0.1", router_port=node.port),
            ROS2Subscriber("/tactiled/finger0/wrench", "geometry_msgs/msg/WrenchStamped",
                           wrenches.append,
                           msg_definition=DEFINITIONS["geometry_msgs/msg/WrenchStamped"],
                           router_ip="127.0.0.1", router_port=node.port)]
    raw = client(node.endpoint)
    ros = raw.declare_subscriber("0/**", zenoh.handlers.FifoChannel(1_000_000))
    js = raw.declare_subscriber(f"{PREFIX}/finger0/estimate", zenoh.handlers.FifoChannel(100_000))
    samples: list[tuple[str, bytes, bytes | None]] = []
    estimates: list[dict[str, Any]] = []

    def drain() -> None:
        while (s := ros.try_recv()) is not None:
            samples.append((str(s.key_expr), s.payload.to_bytes(),
                            s.attachment.to_bytes() if s.attachment is not None else None))
        while (s := js.try_recv()) is not None:
            estimates.append(json.loads(s.payload.to_bytes()))

    def enough() -> bool:
        """What the tests below read is there: every kind of topic (the 1 Hz diagnostics
        too), a contact heard by the SDK, and a span of estimates well past their 100."""
        drain()
        return (len(wrenches) >= 20 and sum(c.contact for c in contacts) >= 20
                and len(estimates) >= 300 and {kind_of(key) for key, _, _ in samples} >= KINDS)

    started = time.monotonic()
    try:
        wait_for(enough, 60, "the SDK's messages, every topic and a contact")
        tokens = [str(r.ok.key_expr) for r in raw.liveliness().get("@ros2_lv/0/**", timeout=3)
                  if r.ok is not None]
    finally:
        for sub in subs:
            sub.close()
        drain()
        seconds = time.monotonic() - started
        raw.close()
        sdk.close()
    return {"seconds": seconds, "contacts": list(contacts), "wrenches": list(wrenches),
            "samples": samples,
            "estimates": estimates, "tokens": tokens}


def kind_of(key: str) -> str:
    """A ROS sample's kind, from its key (``0/<topic>/<type>/<hash>``): strain and taxels
    share sensor_msgs/Image, so not from the type."""
    topic = "/" + "/".join(key.split("/")[1:-2])
    return "diagnostics" if topic == messages.DIAGNOSTICS_TOPIC else topic.rsplit("/", 1)[1]


#: Every kind the simulated finger publishes (a 1-axis array: no 3-axis taxels image).
KINDS = set(messages.TYPES) - {"taxels"}


def test_the_sdk_subscriber_receives_every_estimate(heard: dict[str, Any]) -> None:
    contacts, wrenches, estimates = heard["contacts"], heard["wrenches"], heard["estimates"]
    assert len(estimates) > 100, len(estimates)
    lo = max(contacts[0].seq, estimates[0]["seq"])
    hi = min(contacts[-1].seq, estimates[-1]["seq"])
    span = [e for e in estimates if lo <= e["seq"] <= hi]
    assert len(span) > 100
    by_seq = {c.seq: c for c in contacts}
    missing = [e["seq"] for e in span if e["seq"] not in by_seq]
    assert not missing, f"{len(missing)} of {len(span)} estimates missed: {missing[:10]}"
    for e in span:
        c = by_seq[e["seq"]]
        assert (c.gate, c.contact, c.fitted_seq) == (
            e["gate"], e["contact"], -1 if e["fitted_seq"] is None else e["fitted_seq"])
        for key in ("force_n", "r1_mm", "angle_deg", "x_mm", "y_mm"):
            v = getattr(c, key)
            assert (v != v) if e[key] is None else v == e[key], (e["seq"], key)
    assert sum(c.contact for c in contacts) > 0
    # The wrench of every contact estimate: -force_n along z.
    forces = sorted(-w.wrench.force.z for w in wrenches)
    expected = sorted((e["force_n"] if e["contact"] and e["force_n"] is not None else 0.0)
                      for e in estimates if e["seq"] in by_seq)
    assert len(wrenches) >= len(span) and set(expected) <= set(forces)


def test_every_payload_decodes_with_another_implementation(heard: dict[str, Any]) -> None:
    decoders = {}
    for typename in set(messages.TYPES.values()):
        name = typename.replace("/msg/", "/")
        decoders[rmw.dds_type(typename)] = generate_dynamic(name, messages.definition(typename))[name]
    seen: dict[str, list[tuple[int, bytes]]] = defaultdict(list)
    kinds: dict[str, int] = defaultdict(int)
    for key, payload, attachment in heard["samples"]:
        parts = key.split("/")
        kind = kind_of(key)
        assert rmw.dds_type(messages.TYPES[kind]) == parts[-2], key
        decode = decoders[parts[-2]]
        assert parts[-1] == messages.type_hash(messages.TYPES[kind])
        decode(payload)  # raises on a payload that is not that type's CDR
        assert attachment is not None, key
        seq, stamp, gid = z_deserialize(tuple[Int64, Int64, bytes], zenoh.ZBytes(attachment))
        assert abs(stamp / 1e9 - time.time()) < 600 and len(gid) == 16
        seen[key].append((seq, gid))
        kinds[kind] += 1
    assert set(kinds) == KINDS, dict(kinds)
    for key, got in seen.items():
        seqs = [s for s, _ in got]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), f"{key}: a gap"
        assert len({g for _, g in got}) == 1, key
    seconds = heard["seconds"] + 3  # the window, generously
    assert kinds["strain"] <= FRAME_RATE_HZ * seconds * 2
    # GIDs are those rmw_zenoh derives from the publishers' tokens.
    by_topic = {parse_token(t).get("topic"): t for t in heard["tokens"]
                if parse_token(t)["entity"] == "MP" and parse_token(t)["node"] == "tactiled"}
    for key, got in seen.items():
        topic = "/" + "/".join(key.split("/")[1:-2])
        assert got[0][1] == rmw.gid(by_topic[topic]), topic


def test_the_contacts_topic_lists_every_contact_of_each_estimate(heard: dict[str, Any]) -> None:
    """ContactArray payloads off the wire, decoded by mcap_ros2, against the JSON estimates."""
    def decoded(kind: str) -> dict[int, Any]:
        typename = messages.TYPES[kind]
        name = typename.replace("/msg/", "/")
        decode = generate_dynamic(name, messages.definition(typename))[name]
        prefix = f"0/tactiled/finger0/{kind}/{rmw.dds_type(typename)}/"
        return {(msg := decode(payload)).seq: msg for key, payload, _ in heard["samples"]
                if key.startswith(prefix)}

    arrays, contacts = decoded("contacts"), decoded("contact")
    span = [e for e in heard["estimates"] if e["seq"] in arrays]
    assert len(span) > 100, len(span)
    for e in span:
        a = arrays[e["seq"]]
        assert (a.sensor, a.header.frame_id) == ("finger0", "finger0")
        assert [(c.contact_id, c.seq, c.gate) for c in a.contacts] == [
            (k["contact_id"], e["seq"], e["gate"]) for k in e["contacts"]], e["seq"]
        for c, k in zip(a.contacts, e["contacts"]):
            for key in ("x_mm", "y_mm", "force_n", "r1_mm"):
                v = getattr(c, key)
                assert (v != v) if k[key] is None else v == k[key], (e["seq"], key)
        top = contacts.get(e["seq"])
        if top is not None:
            assert top.contact_id == (a.contacts[0].contact_id if a.contacts else -1)
    assert sum(bool(arrays[e["seq"]].contacts) for e in span) > 0


def test_liveliness_tokens_follow_rmw_zenohs_layout(heard: dict[str, Any]) -> None:
    ours = [parse_token(t) for t in heard["tokens"] if parse_token(t)["node"] == "tactiled"]
    nodes = [p for p in ours if p["entity"] == "NN"]
    pubs = [p for p in ours if p["entity"] == "MP"]
    assert len(nodes) == 1 and nodes[0]["namespace"] == "/tactiled"
    assert {p["topic"]: p["type"] for p in pubs} == {
        "/tactiled/finger0/wrench": "geometry_msgs::msg::dds_::WrenchStamped_",
        "/tactiled/finger0/contact": "tactiled_msgs::msg::dds_::Contact_",
        "/tactiled/finger0/contacts": "tactiled_msgs::msg::dds_::ContactArray_",
        "/tactiled/finger0/markers": "visualization_msgs::msg::dds_::MarkerArray_",
        "/tactiled/finger0/strain": "sensor_msgs::msg::dds_::Image_",
        "/diagnostics": "diagnostic_msgs::msg::dds_::DiagnosticArray_"}
    assert len({p["id"] for p in pubs}) == len(pubs) and all(p["nid"] == "0" for p in pubs)
    assert all(p["zid"] == nodes[0]["zid"] for p in pubs)


def test_health_counts_the_ros2_messages(node: Node, heard: dict[str, Any]) -> None:
    import httpx

    ros2 = httpx.get(node.url + "v1/health", timeout=10).json()["zenoh"]["ros2"]
    assert set(ros2["published"]) == {"wrench", "contact", "contacts", "markers", "strain",
                                      "taxels", "diagnostics"}
    assert ros2["published"]["taxels"] == 0  # a 1-axis array: no taxels topic
    assert ros2["published"]["contact"] >= len(heard["contacts"])
    assert ros2["put_errors"] == 0 and ros2["last_error"] == ""


def test_watch_ros2_prints_decoded_messages(node: Node) -> None:
    done = subprocess.run([PYTHON, "-m", "tactiled.cli", "watch", "--ros2", "--connect",
                           node.endpoint, "--count", "6"], capture_output=True, text=True,
                          timeout=60, env={"TACTILED_ZENOH_MULTICAST_SCOUTING": "false",
                                           "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr
    lines = [json.loads(line) for line in done.stdout.splitlines()]
    assert len(lines) == 6
    for line in lines:
        assert line["topic"] in ("/tactiled/finger0/wrench", "/tactiled/finger0/contact",
                                 "/tactiled/finger0/contacts", "/tactiled/finger0/markers",
                                 "/diagnostics")
        assert line["type"] == messages.TYPES[line["topic"].rsplit("/", 1)[-1]]
        assert line["sequence_number"] >= 1 and isinstance(line["message"], dict)


def test_stop_closes_the_mcap_recording(node: Node) -> None:
    node.proc.proc.send_signal(signal.SIGTERM)
    assert node.proc.proc.wait(20) == 0
    tact = Path(str(node.record).replace("{sensor}", "finger0"))
    mcap = tact.with_suffix(".mcap")
    assert tact.stat().st_size > 32
    with open(mcap, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        counts: dict[str, int] = defaultdict(int)
        seqs = []
        for _s, channel, _m, dec in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            if channel.topic.endswith("/contact"):
                seqs.append(dec.seq)
    assert counts["/tactiled/finger0/contact"] == counts["/tactiled/finger0/wrench"] > 100
    assert counts["/tactiled/finger0/strain"] >= counts["/tactiled/finger0/contact"]
    assert counts["/diagnostics"] >= 1
    assert seqs == sorted(seqs)


@pytest.mark.slow
def test_the_ros2_benchmark_runs() -> None:
    done = subprocess.run([PYTHON, "-m", "tactiled_bench.ros2_fanout", "--quick"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    rows = [line for line in done.stdout.splitlines() if line.startswith("| ")]
    assert [r.split("|")[1].strip() for r in rows[1:]] == ["idle", "json", "ros2", "both"]
    assert "ROS messages missing 0 of" in done.stdout

"""An estimate's ROS 2 bytes are built once, whoever publishes them.

The live node (every middleware of each topic) and the MCAP recorder take the CDR of an
estimate's wrench, contact, contacts and markers from the estimate record
(``Estimate.encoded`` through ``messages.estimate_cdr``): serialised once per estimate and
kind, and the same bytes object on the wire as in the recording.  Here a real ``Ros2Node`` and a
real ``McapRecorder`` of one daemon listen to its hub, each on its own sender thread; the
node's topics have one sink each that keeps what it is handed (it stands for a middleware: the
middlewares themselves are tests/service/test_ros2_node.py's and test_ros2_live.py's), the
recorder writes a real MCAP file, read back with the MCAP project's reader.
"""

from __future__ import annotations

import asyncio
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from tactiled.pipeline import Daemon
from tactiled.pipeline.estimate import make_estimate
from tactiled.settings import load_settings
from tactiled_service.ros2 import messages
from tactiled_service.ros2.mcap_file import McapRecorder
from tactiled_service.ros2.node import Ros2Node

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_ros2_dds import estimate as estimate_line  # noqa: E402

ENVELOPE = ("type", "sensor", "sensor_id", "seq", "device_time_us", "host_time", "time",
            "latency_ms", "worker_ms", "gate", "fitted_seq")


class Kept:
    """A topic's sink that keeps every payload it is handed (a middleware's place)."""

    matched = True

    def __init__(self) -> None:
        self.payloads: list[bytes] = []

    def write(self, payload: bytes, timestamp_ns: int) -> None:
        self.payloads.append(payload)


def records(n: int) -> list[Any]:
    """``n`` estimates of finger0 (none, one and two contacts in turn), stamped 10 ms apart."""
    out = []
    for i in range(n):
        line = estimate_line(i % 3)
        fit = {k: v for k, v in line.items() if k not in ENVELOPE}
        out.append(make_estimate(sensor="finger0", sensor_id=0, seq=100 + i,
                                 device_time_us=1000 * i, host_time=time.monotonic(),
                                 gate="fit", fitted_seq=100 + i, worker_ms=0.5, fit=fit,
                                 stamp=1_790_000_000.0 + 0.01 * i))
    return out


def test_the_node_and_the_recorder_share_each_estimates_bytes(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    built: Counter[str] = Counter()
    serialize = messages.serialize

    def counted(message: Any, typename: str) -> bytes:
        built[typename] += 1
        return serialize(message, typename)

    monkeypatch.setattr(messages, "serialize", counted)
    settings = load_settings(None, {}, {
        "sensor[0].url": "sim://?scene=demo&seed=1", "sensor[0].name": "finger0",
        "fit.workers": 1, "ros2.enabled": True,
        "record.path": str(tmp_path / "{sensor}.tact"), "record.format": "mcap"})
    daemon = Daemon(settings)
    node = Ros2Node(settings, daemon, health=None)
    kept = {kind: Kept() for kind in messages.ESTIMATE_KINDS}
    for kind, sink in kept.items():
        node.topics[("finger0", kind)].sinks.append(sink)
    recorder = McapRecorder(settings, daemon)
    ests = records(12)

    async def publish() -> None:
        node._start("a sink per topic")
        recorder.start()
        try:
            for est in ests:
                daemon.hub.publish(est)
            deadline = time.monotonic() + 30
            while not (all(len(s.payloads) == len(ests) for s in kept.values())
                       and not recorder.sender.items):
                assert time.monotonic() < deadline, (
                    {k: len(s.payloads) for k, s in kept.items()}, len(recorder.sender.items))
                await asyncio.sleep(0.02)
        finally:
            node.stop()
            recorder.stop()

    asyncio.run(publish())
    # once per estimate and kind, for the node's sinks and the recording together
    assert built == Counter({messages.TYPES[k]: len(ests) for k in messages.ESTIMATE_KINDS})
    assert node.sender.dropped == 0 and recorder.sender.dropped == 0
    with open(tmp_path / "finger0.mcap", "rb") as fh:
        recorded = {(channel.topic, message.sequence): message.data
                    for _schema, channel, message in make_reader(fh).iter_messages()}
    for kind, sink in kept.items():
        topic = messages.topic(settings.ros2.namespace, "finger0", kind)
        for i, (est, payload) in enumerate(zip(ests, sink.payloads)):
            assert recorded[(topic, i)] == payload, (kind, i)
            # the record holds that very bytes object: asked again, nothing is built
            again = messages.estimate_cdr(kind, est, est.stamp, "finger0")
            assert again is payload, (kind, i)
    assert sum(built.values()) == 4 * len(ests)

"""Reading ROS 2 samples off DDS: ``tactiled watch --ros2`` on the DDS middleware.

Discovers the domain's DDS writers (Cyclone's built-in ``DCPSPublication`` topic), reads each
ROS topic (``rt/...``) of one of tactiled's types (:data:`.messages.TYPES`), and prints one JSON
object per sample as on Zenoh (:mod:`.reader`), decoded by :func:`.messages.deserialize`;
``sequence_number`` is null (DDS keeps it in the protocol, not the sample).
"""
# Each line: {"topic", "type", "sequence_number", "source_timestamp_ns", "message"};
# source_timestamp_ns is the writer's.

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterable
from typing import Any, TextIO

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from tactiled_service.ros2 import dds, messages
from tactiled_service.ros2.reader import plain

POLL_S = 0.01
#: DDS type name -> ROS type name, for tactiled's types.
_BY_DDS = {dds.idl_type(t).__idl_typename__: t for t in messages.TYPES.values()}


def _wanted(topic: str, typename: str, sensors: set[str] | None, frames: bool) -> bool:
    if typename == messages.TYPES["strain"] and not frames:
        return False
    if sensors is None or topic == messages.DIAGNOSTICS_TOPIC:
        return True
    parts = topic.rsplit("/", 2)
    return len(parts) == 3 and parts[-2] in sensors


def watch(domain_id: int, out: TextIO, *, sensors: Iterable[str] | None = None,
          frames: bool = False, count: int | None = None,
          stop: threading.Event | None = None) -> int:
    """Print the samples of tactiled's topics in DDS domain ``domain_id`` until ``count``
    lines or ``stop`` (as :func:`.reader.watch` does on Zenoh).  Returns the exit code."""
    wanted = None if sensors is None else {messages.ros_segment(s) for s in sensors}
    stop = stop or threading.Event()
    participant = dds.participant(domain_id)
    publications = BuiltinDataReader(participant, BuiltinTopicDcpsPublication)
    readers: dict[str, tuple[str, str, DataReader]] = {}  # DDS topic -> (topic, type, reader)
    printed = 0
    while not stop.is_set():
        for pub in publications.take(N=100):
            name, dds_type = getattr(pub, "topic_name", None), getattr(pub, "type_name", None)
            typename = _BY_DDS.get(dds_type or "")
            if (typename is None or not name or not name.startswith(f"{dds.TOPIC_PREFIX}/")
                    or name in readers):
                continue
            topic = name[len(dds.TOPIC_PREFIX):]
            if not _wanted(topic, typename, wanted, frames):
                continue
            best_effort = typename == messages.TYPES["strain"]
            qos = Qos(Policy.Reliability.BestEffort if best_effort
                      else Policy.Reliability.Reliable(duration(seconds=1)),
                      Policy.History.KeepLast(100))
            readers[name] = (topic, typename, DataReader(
                participant, Topic(participant, name, dds.idl_type(typename)), qos=qos))
        for topic, typename, reader in list(readers.values()):
            for sample in reader.take(N=100):
                line = {"topic": topic, "type": typename, "sequence_number": None,
                        "source_timestamp_ns": sample.sample_info.source_timestamp,
                        "message": plain(messages.deserialize(sample.serialize(), typename))}
                out.write(json.dumps(line, allow_nan=False) + "\n")
                printed += 1
                if count is not None and printed >= count:
                    out.flush()
                    return 0
        out.flush()
        time.sleep(POLL_S)
    return 0

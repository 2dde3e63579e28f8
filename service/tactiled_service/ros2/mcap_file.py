"""tactiled's ROS 2 messages in an MCAP file, the ``ros2`` profile rosbag2 writes (docs/howto/ros2.md).

The same topics and types as the live ROS 2 node (:mod:`.node`), so ``ros2 bag play`` replays
a file onto a ROS graph and Foxglove opens it: one schema per type (encoding ``ros2msg``, the
message definition with its dependencies), one channel per topic (``cdr`` messages, the
type's RIHS01 hash in the channel's ``topic_type_hash`` metadata), log and publish times =
the message's ``header.stamp``.  :class:`McapWriter` writes; ``tactiled export`` and the live
recorder (:class:`McapRecorder`, ``[record] format = "mcap"``) both use it.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from mcap.writer import CompressionType, Writer

from tactiled import __version__
from tactiled.pipeline import Daemon, Estimate, ZeroedFrame
from tactiled.settings import Settings
from tactiled_service.ros2 import messages
from tactiled_service.sender import QUEUE_SIZE, Sender

log = logging.getLogger(__name__)


class McapWriter:
    """Write tactiled's ROS 2 messages to ``output`` (a new file: never overwritten; or an
    open binary stream).  Not thread-safe: one writer per thread."""

    def __init__(self, output: str | Path | BinaryIO, *, namespace: str = "/tactiled",
                 frame_id: str = "{sensor}") -> None:
        if isinstance(output, (str, Path)):
            self._stream: BinaryIO = open(output, "xb")  # noqa: SIM115 - closed in close()
            self._owned = True
        else:
            self._stream, self._owned = output, False
        self.namespace = namespace
        self.frame_id = frame_id
        self.writer = Writer(self._stream, compression=CompressionType.ZSTD)
        self.writer.start(profile="ros2", library=f"tactiled {__version__}")
        self.writer.add_metadata("tactiled", {"ros_distro": messages.DISTRO,
                                              "namespace": namespace})
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}  # topic -> (channel id, type)
        self._sequence: dict[int, int] = {}
        self.messages = 0
        self.closed = False

    def _channel(self, topic: str, typename: str) -> int:
        known = self._channels.get(topic)
        if known is not None:
            return known[0]
        schema = self._schemas.get(typename)
        if schema is None:
            schema = self.writer.register_schema(
                name=typename, encoding="ros2msg",
                data=messages.definition(typename).encode())
            self._schemas[typename] = schema
        channel = self.writer.register_channel(
            topic=topic, message_encoding="cdr", schema_id=schema,
            metadata={"topic_type_hash": messages.type_hash(typename)})
        self._channels[topic] = (channel, typename)
        return channel

    def write(self, topic: str, typename: str, message: Any, stamp_s: float) -> None:
        """One message on ``topic``, logged at ``stamp_s`` (Unix seconds)."""
        self.write_cdr(topic, typename, messages.serialize(message, typename), stamp_s)

    def write_cdr(self, topic: str, typename: str, data: bytes, stamp_s: float) -> None:
        """One message's CDR bytes (:func:`.messages.serialize`) on ``topic``, logged at
        ``stamp_s`` (Unix seconds)."""
        channel = self._channel(topic, typename)
        seq = self._sequence.get(channel, 0)
        self._sequence[channel] = seq + 1
        t_ns = messages.nanoseconds(stamp_s)
        self.writer.add_message(channel, log_time=t_ns, publish_time=t_ns, sequence=seq,
                                data=data)
        self.messages += 1

    def write_estimate(self, est: Estimate | dict[str, Any], stamp_s: float) -> None:
        """The wrench, contact, contacts and markers of an estimate: an ``Estimate`` (its
        bytes built once, shared with the live ROS 2 node: :func:`.messages.estimate_cdr`)
        or its JSON dict (``Estimate.json_dict``: read, never changed)."""
        sensor = str(est["sensor"] if isinstance(est, dict) else est.sensor)
        frame_id = messages.frame_name(self.frame_id, sensor)
        for kind in messages.ESTIMATE_KINDS:
            self.write_cdr(messages.topic(self.namespace, sensor, kind), messages.TYPES[kind],
                           messages.estimate_cdr(kind, est, stamp_s, frame_id), stamp_s)

    def write_frame(self, sensor: str, strain: np.ndarray, stamp_s: float) -> None:
        """The strain image of a zeroed frame."""
        self.write(messages.topic(self.namespace, sensor, "strain"), messages.TYPES["strain"],
                   messages.strain_image(strain, stamp_s,
                                         messages.frame_name(self.frame_id, sensor)), stamp_s)

    def write_taxels(self, sensor: str, taxels: np.ndarray, stamp_s: float) -> None:
        """The 3-channel image of a 3-axis array's zeroed readings (``<sensor>/taxels``)."""
        self.write(messages.topic(self.namespace, sensor, "taxels"), messages.TYPES["taxels"],
                   messages.taxel_image(taxels, stamp_s,
                                        messages.frame_name(self.frame_id, sensor)), stamp_s)

    def write_zeroed(self, frame: ZeroedFrame, stamp_s: float) -> None:
        """A zeroed frame: its strain image and, for a 3-axis array, its readings' 3-channel
        image."""
        self.write_frame(frame.sensor, frame.strain, stamp_s)
        if frame.taxels is not None:
            self.write_taxels(frame.sensor, frame.taxels, stamp_s)

    def write_diagnostics(self, report: dict[str, Any], stamp_s: float,
                          hardware_ids: dict[str, str]) -> None:
        """A health document as ``/diagnostics``."""
        self.write(messages.DIAGNOSTICS_TOPIC, messages.TYPES["diagnostics"],
                   messages.diagnostics(report, stamp_s, hardware_ids), stamp_s)

    def close(self) -> None:
        """Write the summary and close the file (idempotent)."""
        if self.closed:
            return
        self.closed = True
        try:
            self.writer.finish()
        finally:
            if self._owned:
                self._stream.close()


def fresh_path(path: Path, now: float | None = None) -> Path:
    """``path``, or when it exists ``<stem>-<UTC date and time>.mcap`` beside it (an MCAP file
    cannot be continued, and a recording is never overwritten)."""
    if not path.exists():
        return path
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(time.time() if now is None else now))
    return path.with_name(f"{path.stem}-{stamp}{path.suffix}")


class McapRecorder:
    """Record the daemon's estimates, every zeroed frame and, once a second, the health, to
    one MCAP file per sensor (``Settings.mcap_record_path``): a hub listener that queues the
    items for a writer thread (bounded, oldest dropped and counted, as the Zenoh fronts do)."""

    def __init__(self, settings: Settings, daemon: Daemon, health: Any = None,
                 queue_size: int = QUEUE_SIZE) -> None:
        self.daemon = daemon
        self.health = health
        self.hardware_ids = {s.name: s.url for s in settings.sensors}
        self.clock_offset = time.time() - time.monotonic()
        self.sender = Sender(queue_size, kinds=("estimate", "frame", "diagnostics"),
                             name="tactiled-mcap-write")
        self.writers: dict[str, McapWriter] = {}
        for s in settings.sensors:
            path = settings.mcap_record_path(s.name)
            if path is None:
                continue
            path = fresh_path(path)
            path.parent.mkdir(parents=True, exist_ok=True)
            self.writers[s.name] = McapWriter(path, namespace=settings.ros2.namespace,
                                              frame_id=settings.ros2.frame_id)
            log.info("recording %s to %s", s.name, path)
        self._remove: Callable[[], None] | None = None
        self._last_diag = 0.0

    def start(self) -> None:
        self.sender.start()
        self._remove = self.daemon.hub.add_listener(self._on_item)

    def _on_item(self, item: Estimate | ZeroedFrame) -> None:
        writer = self.writers.get(item.sensor)
        if writer is None:
            return
        self.sender.offer(_Sink(writer, self), item.kind, item)
        now = time.monotonic()
        if self.health is not None and now - self._last_diag >= 1.0:
            self._last_diag = now
            report = self.health.report()
            for name, w in self.writers.items():
                one = {**report, "sensors": {name: report["sensors"][name]}}
                self.sender.offer(_Sink(w, self), "diagnostics", (one, time.time()))

    def stop(self) -> None:
        """Stop listening, write what is queued, close the files."""
        if self._remove is not None:
            self._remove()
            self._remove = None
        deadline = time.monotonic() + 2.0
        while self.sender.items and time.monotonic() < deadline:
            time.sleep(0.01)
        self.sender.stop()
        for writer in self.writers.values():
            with contextlib.suppress(Exception):
                writer.close()


class _Sink:
    """What the sender thread calls ``put`` on: one item into one writer."""

    __slots__ = ("writer", "recorder")

    def __init__(self, writer: McapWriter, recorder: McapRecorder) -> None:
        self.writer, self.recorder = writer, recorder

    def put(self, item: Any) -> None:
        offset = self.recorder.clock_offset
        if isinstance(item, tuple):
            self.writer.write_diagnostics(item[0], item[1], self.recorder.hardware_ids)
        elif item.kind == "estimate":
            self.writer.write_estimate(item, messages.item_stamp(item, offset))
        else:
            self.writer.write_zeroed(item, messages.item_stamp(item, offset))

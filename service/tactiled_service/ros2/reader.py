"""Reading ROS 2 samples off Zenoh: ``tactiled watch --ros2`` (docs/howto/ros2.md).

It subscribes to ``<domain_id>/**``, keeps the samples whose key is a topic of one of
tactiled's types (:data:`.messages.TYPES`), decodes the CDR payload and the rmw_zenoh
attachment, and prints one JSON object per sample: what a ROS 2 subscriber of that topic
receives, ``{"topic", "type", "sequence_number", "source_timestamp_ns", "message"}``, the
message's fields by name (NaN as null, byte arrays as lists of numbers).
"""

from __future__ import annotations

import dataclasses
import json
import math
import threading
from collections.abc import Iterable
from typing import Any, TextIO

import numpy as np
import zenoh
from zenoh.ext import Int64, z_deserialize

from tactiled.settings import ZenohSettings
from tactiled_service.bus import listen_until
from tactiled_service.ros2 import messages, rmw

#: DDS-style type name -> ROS type name, for tactiled's types.
_BY_DDS = {rmw.dds_type(t): t for t in messages.TYPES.values()}


def parse_key(key: str) -> tuple[str, str, str] | None:
    """``(topic, type, type hash)`` of a data key ``<domain>/<topic...>/<dds type>/<hash>``
    (Humble's ``TypeHashNotSupported`` in place of the hash too) when its type is one of
    tactiled's, else None."""
    parts = key.split("/")
    if len(parts) < 4 or parts[-2] not in _BY_DDS or not (
            parts[-1].startswith("RIHS01_") or parts[-1] == rmw.NO_TYPE_HASH):
        return None
    return "/" + "/".join(parts[1:-2]), _BY_DDS[parts[-2]], parts[-1]


def parse_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(sequence number, source timestamp in ns, GID) of an rmw_zenoh attachment."""
    seq, stamp, gid = z_deserialize(tuple[Int64, Int64, bytes], zenoh.ZBytes(data))
    return int(seq), int(stamp), bytes(gid)


def plain(value: Any) -> Any:
    """A rosbags message as JSON data: fields by name, arrays as lists, NaN as None.

    rosbags lists a definition's constants (``uint8 STICK=0``) among the dataclass fields; ROS 2
    names fields in lower case and constants in upper case, so a name with a capital is left out.
    """
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)
                if not f.name.startswith("__") and f.name.islower()}
    if isinstance(value, np.ndarray):
        return [plain(v) for v in value.tolist()]
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, np.generic):
        return plain(value.item())
    return value


def decode(key: str, payload: bytes, attachment: bytes | None) -> dict[str, Any] | None:
    """The printed object of one sample (None when the key is not one of tactiled's)."""
    parsed = parse_key(key)
    if parsed is None:
        return None
    topic, typename, _ = parsed
    seq = stamp = None
    if attachment:
        seq, stamp, _gid = parse_attachment(attachment)
    return {"topic": topic, "type": typename, "sequence_number": seq,
            "source_timestamp_ns": stamp,
            "message": plain(messages.deserialize(payload, typename))}


def watch(settings: ZenohSettings, domain_id: int, out: TextIO, *,
          sensors: Iterable[str] | None = None, frames: bool = False,
          count: int | None = None, stop: threading.Event | None = None) -> int:
    """Print the samples of tactiled's topics in ROS domain ``domain_id`` until ``count``
    lines or ``stop``; ``frames`` adds the strain images, ``sensors`` keeps those sensors'
    topics (and /diagnostics).  Returns the exit code."""
    wanted = None if sensors is None else {messages.ros_segment(s) for s in sensors}
    stop = stop or threading.Event()
    printed = 0
    lock = threading.Lock()

    def on_sample(sample: Any) -> None:
        nonlocal printed
        key = str(sample.key_expr)
        parsed = parse_key(key)
        if parsed is None:
            return
        topic, typename, _ = parsed
        if typename == messages.TYPES["strain"] and not frames:
            return
        if wanted is not None and topic != messages.DIAGNOSTICS_TOPIC and \
                topic.rsplit("/", 2)[-2] not in wanted:
            return
        att = sample.attachment
        try:
            line = decode(key, sample.payload.to_bytes(),
                          att.to_bytes() if att is not None else None)
        except Exception:  # not CDR of that type: another publisher's bytes
            return
        with lock:
            if stop.is_set() or line is None:
                return
            out.write(json.dumps(line, allow_nan=False) + "\n")
            out.flush()
            printed += 1
            if count is not None and printed >= count:
                stop.set()

    return listen_until(settings, f"{domain_id}/**", on_sample, stop)

"""ROS 2 over DDS: the same topics, types and bytes as on Zenoh, through Eclipse Cyclone DDS
(``cyclonedds`` on PyPI, in the ``ros2`` extra), as ROS 2's DDS middlewares lay them out.

One builder, two transports: :func:`prebuilt` hands Cyclone the CDR bytes already built for
Zenoh, so the types registered here (:func:`idl_type`) serve for discovery and type matching
only.  ``tests/ros2/test_ros2_dds.py`` checks Cyclone's own serialisation gives the same bytes.
"""
# How ROS 2 maps onto DDS (rmw_dds_common and rmw_cyclonedds_cpp,
# https://github.com/ros2/rmw_cyclonedds, rmw_cyclonedds_cpp/src/rmw_node.cpp:
# ROS_TOPIC_PREFIX "rt" and make_fqtopic; the type names from rosidl_typesupport_introspection's
# create_type_name with dds_ and a trailing _, as
# https://design.ros2.org/articles/topic_and_service_names.html describes):
# * a topic /tactiled/finger0/wrench is the DDS topic rt/tactiled/finger0/wrench;
# * its type geometry_msgs/msg/WrenchStamped is the DDS type
#   geometry_msgs::msg::dds_::WrenchStamped_ (tactiled_msgs::msg::dds_::Contact_ ...);
# * a sample is the message in plain CDR (XCDR1, little-endian, 00 01 00 00), exactly the bytes
#   tactiled_service.ros2.messages.serialize builds for Zenoh;
# * QoS as rclcpp's defaults: estimates and diagnostics reliable, volatile, keep-last 10; strain
#   images as rmw_qos_profile_sensor_data: best effort, volatile, keep-last 5;
# * the domain is ROS_DOMAIN_ID (here [ros2] domain_id); CYCLONEDDS_URI is read by Cyclone DDS
#   itself; ROS_LOCALHOST_ONLY=1 (Humble) or ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST / OFF
#   (Jazzy and later) keep discovery on this machine, as rmw_cyclonedds does by configuring the
#   loopback interface.
# Cyclone DDS's Python binding writes a sample by calling its serialize(); prebuilt returns the
# bytes built once per message, and idl_type is generated from the message definitions the
# builders use.

from __future__ import annotations

import functools
import os
from typing import Any

from cyclonedds.core import Listener
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct, make_idl_struct
from cyclonedds.idl import types as t
from cyclonedds.pub import DataWriter, Publisher
from cyclonedds.qos import Policy, Qos
from cyclonedds.topic import Topic
from rosbags.interfaces import Nodetype

from tactiled_service.ros2 import messages

TOPIC_PREFIX = "rt"
DEPTH = 10  # rclcpp's default history depth
SENSOR_DATA_DEPTH = 5  # rmw_qos_profile_sensor_data

_BASE: dict[str, Any] = {
    "bool": bool, "byte": t.byte, "char": t.uint8, "int8": t.int8, "uint8": t.uint8,
    "int16": t.int16, "uint16": t.uint16, "int32": t.int32, "uint32": t.uint32,
    "int64": t.int64, "uint64": t.uint64, "float32": t.float32, "float64": t.float64,
    "string": str,
}


def dds_topic(topic: str) -> str:
    """A fully qualified ROS topic as its DDS topic name: ``rt/tactiled/finger0/wrench``."""
    return f"{TOPIC_PREFIX}/{topic.lstrip('/')}"


def _field_type(desc: tuple[Any, Any]) -> Any:
    kind, detail = desc
    if kind == Nodetype.BASE:
        name, bound = detail
        if name == "string" and bound:
            return t.bounded_str[bound]
        return _BASE[name]
    if kind == Nodetype.NAME:
        return idl_type(detail)
    sub, size = detail
    if kind == Nodetype.ARRAY:
        return t.array[_field_type(sub), size]
    return t.sequence[_field_type(sub), size] if size else t.sequence[_field_type(sub)]


@functools.cache
def idl_type(typename: str) -> type[IdlStruct]:
    """The Cyclone DDS type of a ROS message type (``pkg/msg/Name``), from the definitions
    the builders use (:func:`messages.typestore`), named as ROS 2 names it on DDS."""
    _consts, fields = messages.typestore().fielddefs[typename]
    pkg, kind, name = typename.split("/")
    return make_idl_struct(f"{name}_", f"{pkg}::{kind}::dds_::{name}_",
                           {fname: _field_type(desc) for fname, desc in fields})


def prebuilt(typename: str, payload: bytes) -> Any:
    """A sample of ``typename`` whose serialisation is ``payload`` (CDR with its header), for
    :meth:`DataWriter.write`: the bytes are the builders', not rebuilt from fields."""
    sample = object.__new__(idl_type(typename))
    sample.serialize = lambda use_version_2=False, endianness=None: payload
    return sample


def qos(kind: str, type_hash: str | None = None) -> Qos:
    """The writer QoS of a topic kind: the sensor-data profile for images (strain, taxels), rclcpp's
    default for the rest; with ``type_hash`` (``RIHS01_...``, Iron and later) the USER_DATA
    ``typehash=<hash>;`` that rmw_cyclonedds_cpp writes and reads (``rmw_dds_common``'s
    ``encode_type_hash_for_user_data_qos``; without it a Jazzy reader logs that it cannot
    parse the type hash, and still receives)."""
    policies = [Policy.Durability.Volatile]
    if kind in ("strain", "taxels"):
        policies += [Policy.Reliability.BestEffort, Policy.History.KeepLast(SENSOR_DATA_DEPTH)]
    else:
        policies += [Policy.Reliability.Reliable(max_blocking_time=0),
                     Policy.History.KeepLast(DEPTH)]
    if type_hash:
        policies.append(Policy.Userdata(f"typehash={type_hash};".encode()))
    return Qos(*policies)


def localhost_only(env: dict[str, str] | None = None) -> bool:
    """Whether ROS 2's environment asks for discovery on this machine only."""
    env = os.environ if env is None else env
    return (env.get("ROS_LOCALHOST_ONLY", "") == "1"
            or env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").upper() in ("LOCALHOST", "OFF"))


#: The Cyclone DDS configuration for :func:`localhost_only` (as rmw_cyclonedds_cpp sets it:
#: the loopback interface, multicast on it allowed for discovery).
LOCALHOST_CONFIG = ('<CycloneDDS><Domain id="any"><General><Interfaces>'
                    '<NetworkInterface address="127.0.0.1" multicast="true"/></Interfaces>'
                    '<AllowMulticast>spdp</AllowMulticast></General></Domain></CycloneDDS>')


class DdsSink:
    """One DDS writer of a topic: ``matched`` while a reader listens, ``write(payload)``."""

    def __init__(self, participant: DomainParticipant, publisher: Publisher, topic: str,
                 typename: str, kind: str, distro: str = "jazzy") -> None:
        self.typename = typename
        self.matched = False
        type_hash = None if distro == "humble" else messages.type_hash(typename)
        self.topic = Topic(participant, dds_topic(topic), idl_type(typename))
        self.writer = DataWriter(publisher, self.topic, qos=qos(kind, type_hash),
                                 listener=Listener(on_publication_matched=self._on_matched))

    def _on_matched(self, _writer: Any, status: Any) -> None:  # a Cyclone DDS thread
        self.matched = status.current_count > 0

    def write(self, payload: bytes, timestamp_ns: int) -> None:
        self.writer.write(prebuilt(self.typename, payload), timestamp=timestamp_ns)


def participant(domain_id: int) -> DomainParticipant:
    """The domain participant: ``CYCLONEDDS_URI`` as Cyclone reads it, or the loopback-only
    configuration when ROS 2's environment asks for it and ``CYCLONEDDS_URI`` is not set."""
    if localhost_only() and not os.environ.get("CYCLONEDDS_URI") and domain_id not in _DOMAINS:
        from cyclonedds.domain import Domain

        # configures the domain before its first participant; kept for the process's life
        _DOMAINS[domain_id] = Domain(domain_id, LOCALHOST_CONFIG)
    return DomainParticipant(domain_id)


_DOMAINS: dict[int, Any] = {}

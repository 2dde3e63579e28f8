"""A plain Cyclone DDS reader of ``geometry_msgs/msg/WrenchStamped``, with its own IDL types
written here from the ROS 2 message definitions (not tactiled's), run as a separate process:

    python dds_wrench_reader.py DOMAIN_ID DDS_TOPIC SECONDS WAIT_S

It waits up to WAIT_S for the first sample, then reads for SECONDS and prints one JSON object:
``{"samples": [[frame_id, sec, nanosec, fx, fy, fz, tx, ty, tz], ...]}`` (``CYCLONEDDS_URI``
from the environment chooses the network).
"""

# (no "from __future__ import annotations": Cyclone DDS resolves the field types at runtime)
import json
import sys
import time
from dataclasses import dataclass

from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32
    nanosec: t.uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: t.float64
    y: t.float64
    z: t.float64


@dataclass
class Wrench(IdlStruct, typename="geometry_msgs::msg::dds_::Wrench_"):
    force: Vector3
    torque: Vector3


@dataclass
class WrenchStamped(IdlStruct, typename="geometry_msgs::msg::dds_::WrenchStamped_"):
    header: Header
    wrench: Wrench


def main() -> None:
    domain, topic, seconds, wait_s = int(sys.argv[1]), sys.argv[2], float(sys.argv[3]), \
        float(sys.argv[4])
    participant = DomainParticipant(domain)
    reader = DataReader(participant, Topic(participant, topic, WrenchStamped),
                        qos=Qos(Policy.Reliability.Reliable(duration(seconds=1)),
                                Policy.History.KeepLast(1000)))
    samples: list[list[object]] = []
    deadline = time.monotonic() + wait_s
    end = None
    while True:
        now = time.monotonic()
        if end is None and now > deadline or end is not None and now > end:
            break
        for s in reader.take(N=1000):
            if end is None:
                end = time.monotonic() + seconds
            w = s.wrench
            samples.append([s.header.frame_id, s.header.stamp.sec, s.header.stamp.nanosec,
                            w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y,
                            w.torque.z])
        time.sleep(0.005)
    print(json.dumps({"samples": samples}), flush=True)


if __name__ == "__main__":
    main()

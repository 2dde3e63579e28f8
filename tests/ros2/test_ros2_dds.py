"""ROS 2 on DDS without a network: names, types and bytes.

The bytes a DDS writer sends are the builders' CDR (one builder, two transports); here they are
compared with what Cyclone DDS itself serialises from the same message, converted field by
field into the DDS types, for every kind of message tactiled publishes.  The names follow ROS
2's DDS mapping (``rt/`` prefix, ``pkg::msg::dds_::Type_``; ros2/rmw_cyclonedds,
``rmw_cyclonedds_cpp/src/rmw_node.cpp``), the QoS rclcpp's default and sensor-data profiles.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from cyclonedds.qos import Policy
from rosbags.interfaces import Nodetype

from tactiled_service.ros2 import dds, messages

STAMP = 1_790_000_000.123456


def to_idl(msg: Any, typename: str) -> Any:
    """``msg`` (a rosbags message) as an instance of Cyclone DDS's type, field by field."""
    _consts, fields = messages.typestore().fielddefs[typename]
    return dds.idl_type(typename)(**{name: convert(getattr(msg, name), desc)
                                     for name, desc in fields})


def convert(value: Any, desc: tuple[Any, Any]) -> Any:
    kind, detail = desc
    if kind == Nodetype.BASE:
        return value.item() if hasattr(value, "item") else value
    if kind == Nodetype.NAME:
        return to_idl(value, detail)
    return [convert(v, detail[0]) for v in value]


def estimate(n_contacts: int) -> dict[str, Any]:
    contacts = [{"contact": True, "contact_id": 3 + k, "model": "sphere", "x_mm": 1.5 + k,
                 "y_mm": -2.0, "force_n": 0.75 * (k + 1), "r1_mm": 4.0, "r2_mm": 4.0,
                 "angle_deg": 12.0, "rms": 1e-4, "label": "ok", "converged": True,
                 "iterations": 7} for k in range(n_contacts)]
    top = contacts[0] if contacts else {"contact": False}
    return {**top, "sensor": "finger0", "sensor_id": 0, "seq": 41, "device_time_us": 41000,
            "gate": "fit", "fitted_seq": 41, "contacts": contacts, "latency_ms": 1.25,
            "worker_ms": 0.5}


@pytest.mark.parametrize("n_contacts", [0, 1, 2])
@pytest.mark.parametrize("kind", messages.ESTIMATE_KINDS)
def test_dds_bytes_are_the_builders_bytes(kind: str, n_contacts: int) -> None:
    msg = messages.estimate_message(kind, estimate(n_contacts), STAMP, "finger0")
    typename = messages.TYPES[kind]
    ours = messages.serialize(msg, typename)
    assert to_idl(msg, typename).serialize() == ours
    assert dds.prebuilt(typename, ours).serialize() == ours


def test_strain_image_and_diagnostics_bytes_too() -> None:
    img = messages.strain_image(np.arange(12.0).reshape(3, 4) * 1e-4, STAMP, "finger0")
    ours = messages.serialize(img, messages.TYPES["strain"])
    assert to_idl(img, messages.TYPES["strain"]).serialize() == ours
    report = {"status": "OK", "reasons": [], "sensors": {"finger0": {
        "status": "DEGRADED", "reasons": ["rate below nominal"], "frame_rate_hz": 180.0}}}
    diag = messages.diagnostics(report, STAMP, {"finger0": "sim://"})
    ours = messages.serialize(diag, messages.TYPES["diagnostics"])
    assert to_idl(diag, messages.TYPES["diagnostics"]).serialize() == ours


def test_names_are_ros2s_dds_names() -> None:
    assert dds.dds_topic("/tactiled/finger0/wrench") == "rt/tactiled/finger0/wrench"
    assert dds.dds_topic("/diagnostics") == "rt/diagnostics"
    names = {t: dds.idl_type(t).__idl_typename__ for t in messages.TYPES.values()}
    assert names == {
        "geometry_msgs/msg/WrenchStamped": "geometry_msgs::msg::dds_::WrenchStamped_",
        "tactiled_msgs/msg/Contact": "tactiled_msgs::msg::dds_::Contact_",
        "tactiled_msgs/msg/ContactArray": "tactiled_msgs::msg::dds_::ContactArray_",
        "sensor_msgs/msg/Image": "sensor_msgs::msg::dds_::Image_",
        "visualization_msgs/msg/MarkerArray": "visualization_msgs::msg::dds_::MarkerArray_",
        "diagnostic_msgs/msg/DiagnosticArray": "diagnostic_msgs::msg::dds_::DiagnosticArray_"}


def test_qos_is_rclcpps_default_and_the_sensor_data_profile() -> None:
    wrench = dds.qos("wrench", messages.type_hash(messages.TYPES["wrench"]))
    assert wrench[Policy.Reliability].__scope__ == "Reliability"
    assert isinstance(wrench[Policy.Reliability], Policy.Reliability.Reliable)
    assert wrench[Policy.History] == Policy.History.KeepLast(10)
    assert wrench[Policy.Durability] == Policy.Durability.Volatile
    assert wrench[Policy.Userdata].data == (
        f"typehash={messages.type_hash(messages.TYPES['wrench'])};".encode())
    strain = dds.qos("strain")
    assert strain[Policy.Reliability] == Policy.Reliability.BestEffort
    assert strain[Policy.History] == Policy.History.KeepLast(5)
    assert Policy.Userdata not in strain


@pytest.mark.parametrize(("env", "expected"), [
    ({}, False), ({"ROS_LOCALHOST_ONLY": "1"}, True), ({"ROS_LOCALHOST_ONLY": "0"}, False),
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}, True),
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF"}, True),
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}, False)])
def test_ros2s_localhost_variables_are_honoured(env: dict[str, str], expected: bool) -> None:
    assert dds.localhost_only(env) is expected

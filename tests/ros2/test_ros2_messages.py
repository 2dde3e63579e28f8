"""ROS 2 messages of estimates, frames and health, checked with code that is not ours.

The messages are built and serialised by ``tactiled_service.ros2.messages`` with rosbags; here
every one is decoded by the MCAP project's ROS 2 decoder (``mcap_ros2``, a second CDR
implementation, fed only the message definition text), and its values are compared with an
independent computation from the estimate's JSON.  Type hashes are compared with the values
ROS 2 itself publishes, and the hashes of ``tactiled_msgs/msg/Contact`` and ``ContactArray``
with those ``zenoh-ros2-sdk`` computes on its own from the ``.msg`` texts.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap_ros2._dynamic import generate_dynamic
from zenoh_ros2_sdk.utils import get_type_hash

from tactiled.pipeline.association import ContactIds, identified
from tactiled_service.ros2 import messages as m

ROOT = Path(__file__).resolve().parents[2]
CONTACT_MSG = ROOT / "ros2" / "tactiled_msgs" / "msg" / "Contact.msg"
CONTACT_ARRAY_MSG = CONTACT_MSG.with_name("ContactArray.msg")
#: What the ament package declares: its messages' RIHS01 hashes, which a ROS 2 build of
#: ros2/tactiled_msgs reports (``ros2 interface show`` / ``ros2 topic info -v``).
TACTILED_HASHES = {
    "tactiled_msgs/msg/Contact":
        "RIHS01_546e8129eb3b97c6489596dc81cb49dfcaa162f3a1323df4db7088a71095d2ca",
    "tactiled_msgs/msg/ContactArray":
        "RIHS01_d4a8bf810955d7afc5fd911539894650411c624b5f817acdc42ad3c4f3932475",
}

#: RIHS01 hashes as ROS 2 (Jazzy, Kilted) reports them, hard-coded from outside this project:
#: sensor_msgs/Image is the "Topic type hash" line of ``ros2 topic info -v`` in the
#: image_pipeline documentation (docs.ros.org/en/rolling/p/image_pipeline/tutorials, "Using QoS
#: Overrides"); the four also appear, identically, in the generated type tables of independent
#: ROS 2 client libraries that copy them from ROS 2's type_description build output.
ROS2_HASHES = {
    "geometry_msgs/msg/WrenchStamped":
        "RIHS01_8dc3deaf06b2ab281f9f9a742a8961c328ca7cec16e3fd6586d3a5c83fa78f77",
    "sensor_msgs/msg/Image":
        "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47",
    "visualization_msgs/msg/MarkerArray":
        "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf",
    "diagnostic_msgs/msg/DiagnosticArray":
        "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e",
}

#: docs/reference/api.md's example estimate (a held cylinder contact).
ESTIMATE: dict[str, Any] = {
    "type": "estimate", "sensor": "finger0", "sensor_id": 0, "seq": 9561,
    "device_time_us": 9561000, "host_time": 2522.376680267, "time": 1795309645.9224312,
    "latency_ms": 0.0855, "worker_ms": 0.0, "gate": "unchanged", "fitted_seq": 8442,
    "contact": True, "model": "cylinder", "x_mm": 11.6135, "y_mm": 13.6789, "force_n": 1.0312,
    "r1_mm": 12.9935, "r2_mm": None, "angle_deg": 92.967, "rms": 0.0132,
    "std": {"x_mm": 0.0278, "y_mm": 0.0324, "force_n": 0.0103, "r1_mm": 1.0938, "r2_mm": None,
            "angle_deg": 2.136, "vx_mm_s": 0.0148, "vy_mm_s": 0.0162,
            "angle_rate_deg_s": 1.05, "force_rate_n_s": 0.0051},
    "fit_ms": 5.0119, "label": "cylinder", "converged": True, "iterations": 16,
    "condition": 1.71, "peak": 0.0312, "reasons": {"r2_mm": "infinite: cylinder model"},
    "message": "predicted decrease below ftol",
    "ellipse": {"a_mm": 3.213, "b_mm": 2.9936, "theta_deg": 142.698},
    "frames_used": 1119, "vx_mm_s": 0.0123, "vy_mm_s": -0.0071, "angle_rate_deg_s": 0.0412,
    "force_rate_n_s": -0.0009}
NO_CONTACT: dict[str, Any] = {
    "type": "estimate", "sensor": "finger0", "sensor_id": 0, "seq": 3, "device_time_us": 3000,
    "gate": "no_contact", "fitted_seq": None, "contact": False, "model": None, "x_mm": None,
    "y_mm": None, "force_n": None, "r1_mm": None, "r2_mm": None, "angle_deg": None,
    "std": {}, "reasons": {"x_mm": "no contact"}, "ellipse": None, "frames_used": 0}
STAMP = 1795309645.25


def decode(kind: str, data: bytes) -> Any:
    """``data`` decoded by mcap_ros2 from the definition text alone (not rosbags)."""
    typename = m.TYPES[kind]
    assert data[:4] == b"\x00\x01\x00\x00", "CDR little-endian encapsulation header"
    decoders = generate_dynamic(typename.replace("/msg/", "/"), m.definition(typename))
    return decoders[typename.replace("/msg/", "/")](data)


def same(a: float, b: Any) -> bool:
    """``a`` equals the JSON value ``b`` (null: NaN)."""
    return math.isnan(a) if b is None else math.isclose(a, b, rel_tol=1e-15, abs_tol=0.0)


def test_standard_type_hashes_are_those_ros2_publishes() -> None:
    for typename, expected in ROS2_HASHES.items():
        assert m.type_hash(typename) == expected, typename


def test_contact_hashes_agree_with_an_independent_implementation() -> None:
    deps = {"std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
            "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
            m.CONTACT_TYPE: CONTACT_MSG.read_text()}
    for typename, path in ((m.CONTACT_TYPE, CONTACT_MSG),
                           (m.CONTACT_ARRAY_TYPE, CONTACT_ARRAY_MSG)):
        ours = m.type_hash(typename)
        assert ours == get_type_hash(typename, msg_definition=path.read_text(),
                                     dependencies=deps), typename
        assert ours == TACTILED_HASHES[typename], "a message changed: update docs/howto/ros2.md"


def test_wrench_hash_agrees_with_an_independent_implementation() -> None:
    deps = {"std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
            "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
            "geometry_msgs/msg/Wrench": "Vector3 force\nVector3 torque\n",
            "geometry_msgs/msg/Vector3": "float64 x\nfloat64 y\nfloat64 z\n"}
    typename = "geometry_msgs/msg/WrenchStamped"
    sdk = get_type_hash(typename, msg_definition="std_msgs/Header header\nWrench wrench\n",
                        dependencies=deps)
    assert sdk == m.type_hash(typename) == ROS2_HASHES[typename]


def test_the_daemon_publishes_the_messages_the_ament_package_builds() -> None:
    assert m.contact_definition() == CONTACT_MSG.read_text()
    assert m.contact_definition(m.CONTACT_ARRAY_TYPE) == CONTACT_ARRAY_MSG.read_text()
    package = ROOT / "ros2" / "tactiled_msgs"
    assert '"msg/ContactArray.msg"' in (package / "CMakeLists.txt").read_text()


def test_wrench_is_the_force_on_the_sensor_in_si_units() -> None:
    msg = decode("wrench", m.serialize(m.wrench(ESTIMATE, STAMP, "finger0"), m.TYPES["wrench"]))
    assert msg.header.frame_id == "finger0"
    assert msg.header.stamp.sec == 1795309645 and msg.header.stamp.nanosec == 250_000_000
    f = np.array([msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z])
    t = np.array([msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z])
    np.testing.assert_allclose(f, [0.0, 0.0, -1.0312], rtol=1e-15)
    r = np.array([ESTIMATE["x_mm"], ESTIMATE["y_mm"], 0.0]) / 1000.0  # m
    np.testing.assert_allclose(t, np.cross(r, f), rtol=1e-12)
    none = decode("wrench", m.serialize(m.wrench(NO_CONTACT, STAMP, "f"), m.TYPES["wrench"]))
    assert none.wrench.force.z == 0.0 and none.wrench.torque.x == 0.0


def test_wrench_of_a_3_axis_estimate_carries_the_tangential_force_and_torsion() -> None:
    """The shear table's fx_n, fy_n (N) join the force; the moment is r x F plus the torsion
    about +z, converted from N mm to N m."""
    shear = {"fx_n": 0.21, "fy_n": -0.13, "torque_nmm": 2.5, "q_over_p": 0.24, "mu": None}
    est = {**ESTIMATE, "shear": shear}
    msg = decode("wrench", m.serialize(m.wrench(est, STAMP, "xela"), m.TYPES["wrench"]))
    f = np.array([msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z])
    t = np.array([msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z])
    np.testing.assert_allclose(f, [0.21, -0.13, -1.0312], rtol=1e-15)
    r = np.array([ESTIMATE["x_mm"], ESTIMATE["y_mm"], 0.0]) / 1000.0
    np.testing.assert_allclose(t, np.cross(r, f) + [0.0, 0.0, 2.5e-3], rtol=1e-12, atol=1e-18)
    withheld = {**ESTIMATE, "shear": {**shear, "fx_n": None}}
    msg = decode("wrench", m.serialize(m.wrench(withheld, STAMP, "xela"), m.TYPES["wrench"]))
    assert msg.wrench.force.x == 0.0 and msg.wrench.force.y == -0.13


def test_taxel_image_is_a_3_channel_float_image() -> None:
    """x, y, z of each taxel as 32FC3, rows by columns, read back with numpy."""
    taxels = np.arange(4 * 6 * 3, dtype=float).reshape(4, 6, 3) - 20.5
    msg = decode("taxels", m.serialize(m.taxel_image(taxels, STAMP, "xela"), m.TYPES["taxels"]))
    assert (msg.height, msg.width, msg.encoding, msg.step) == (4, 6, "32FC3", 72)
    back = np.frombuffer(bytes(msg.data), dtype="<f4").reshape(4, 6, 3)
    np.testing.assert_array_equal(back, taxels.astype(np.float32))
    assert back[1, 2, 0] == taxels[1, 2, 0] and back[1, 2, 2] == taxels[1, 2, 2]


def test_contact_carries_every_value_and_sigma_with_the_json_names() -> None:
    msg = decode("contact", m.serialize(m.contact(ESTIMATE, STAMP, "finger0"),
                                        m.TYPES["contact"]))
    for key in ("x_mm", "y_mm", "force_n", "r1_mm", "r2_mm", "angle_deg", "vx_mm_s", "vy_mm_s",
                "angle_rate_deg_s", "force_rate_n_s"):
        assert same(getattr(msg, key), ESTIMATE[key]), key
        assert same(getattr(msg, f"std_{key}"), ESTIMATE["std"][key]), f"std_{key}"
    for key in ("rms", "peak", "condition", "latency_ms", "worker_ms", "fit_ms"):
        assert same(getattr(msg, key), ESTIMATE[key]), key
    for key in ("sensor", "sensor_id", "seq", "device_time_us", "gate", "fitted_seq", "contact",
                "model", "label", "converged", "iterations", "message", "frames_used"):
        assert getattr(msg, key) == ESTIMATE[key], key
    e = ESTIMATE["ellipse"]
    assert (msg.ellipse_a_mm, msg.ellipse_b_mm, msg.ellipse_theta_deg) == (
        e["a_mm"], e["b_mm"], e["theta_deg"])
    assert dict(zip(msg.reason_keys, msg.reason_texts)) == ESTIMATE["reasons"]
    assert msg.contact_id == -1  # an estimate written before contacts had ids
    msg = decode("contact", m.serialize(m.contact({**ESTIMATE, "contact_id": 7}, STAMP, "f"),
                                        m.TYPES["contact"]))
    assert msg.contact_id == 7
    none = decode("contact", m.serialize(m.contact(NO_CONTACT, STAMP, "f"), m.TYPES["contact"]))
    assert none.contact is False and none.fitted_seq == -1 and none.model == ""
    assert none.contact_id == -1
    assert math.isnan(none.force_n) and math.isnan(none.ellipse_a_mm)


def test_markers_draw_the_ellipse_and_the_force_arrow_in_metres() -> None:
    msg = decode("markers", m.serialize(m.markers(ESTIMATE, STAMP, "finger0"),
                                        m.TYPES["markers"]))
    clear, ellipse, arrow = msg.markers
    assert (clear.ns, clear.action) == ("finger0", 3)  # DELETEALL of the sensor's namespace
    assert (ellipse.ns, ellipse.id, ellipse.type, ellipse.action) == ("finger0", 0, 3, 0)
    assert math.isclose(ellipse.scale.x, 2 * 3.213e-3) and math.isclose(ellipse.scale.y,
                                                                          2 * 2.9936e-3)
    assert math.isclose(ellipse.pose.position.x, 11.6135e-3)
    q = ellipse.pose.orientation
    assert math.isclose(math.degrees(2 * math.atan2(q.z, q.w)), 142.698)
    assert (arrow.id, arrow.type, arrow.action) == (1, 0, 0)
    tail, head = arrow.points
    assert math.isclose(tail.z - head.z, 1.0312 * m.ARROW_M_PER_N)  # into the skin
    assert (head.x, head.y, head.z) == (ellipse.pose.position.x, ellipse.pose.position.y, 0.0)
    gone = decode("markers", m.serialize(m.markers(NO_CONTACT, STAMP, "f"), m.TYPES["markers"]))
    assert [(k.ns, k.action) for k in gone.markers] == [("finger0", 3)]  # DELETEALL alone


def test_strain_image_is_32fc1_rows_by_cols() -> None:
    rng = np.random.default_rng(5)
    strain = rng.normal(0, 1e-3, size=(8, 6))
    strain[2, 3] = np.nan  # the zeroer never sends one, but NaN must not reach a viewer
    msg = decode("strain", m.serialize(m.strain_image(strain, STAMP, "finger0"),
                                       m.TYPES["strain"]))
    assert (msg.height, msg.width, msg.encoding, msg.step, msg.is_bigendian) == (
        8, 6, "32FC1", 24, 0)
    pixels = np.frombuffer(bytes(msg.data), dtype="<f4").reshape(8, 6)
    expected = np.where(np.isnan(strain), 0.0, strain).astype(np.float32)
    np.testing.assert_array_equal(pixels, expected)


def test_diagnostics_levels_and_reasons() -> None:
    report = {"status": "ERROR", "sensors": {
        "finger0": {"status": "OK", "reason": "", "frame_rate_hz": 1000.0, "connected": True},
        "thumb": {"status": "DEGRADED", "reason": "frame rate 512 Hz, below the nominal"},
        "index": {"status": "STALE", "reason": "no estimate for 1.2 s"},
        "pinky": {"status": "ERROR", "reason": "disconnected"}}}
    msg = decode("diagnostics", m.serialize(
        m.diagnostics(report, STAMP, {"finger0": "sim://?seed=1"}), m.TYPES["diagnostics"]))
    got = {s.name: (s.level, s.message, s.hardware_id) for s in msg.status}
    assert got == {
        "tactiled: finger0": (0, "OK", "sim://?seed=1"),
        "tactiled: thumb": (1, "frame rate 512 Hz, below the nominal", "thumb"),
        "tactiled: index": (3, "no estimate for 1.2 s", "index"),
        "tactiled: pinky": (2, "disconnected", "pinky")}
    values = {kv.key: kv.value for kv in msg.status[0].values}
    assert values == {"status": "OK", "frame_rate_hz": "1000.0", "connected": "true"}


@pytest.mark.parametrize(("sensor", "expected"), [
    ("finger0", "/tactiled/finger0/wrench"), ("finger-0", "/tactiled/finger_0/wrench"),
    ("0", "/tactiled/s0/wrench"), ("a.b__c", "/tactiled/a_b_c/wrench")])
def test_topic_names_are_valid_ros_names(sensor: str, expected: str) -> None:
    assert m.topic("/tactiled", sensor, "wrench") == expected
    assert m.topic("/", sensor, "diagnostics") == "/diagnostics"


def test_sensors_whose_topics_would_collide_are_refused() -> None:
    m.check_segments(["finger0", "thumb", "finger-1"])
    with pytest.raises(ValueError, match="sensors 'finger-0' and 'finger_0' have the same ROS"):
        m.check_segments(["finger-0", "thumb", "finger_0"])


def test_a_line_contacts_table_rides_in_the_contact_message() -> None:
    line = {"load_n_per_mm": 0.0801, "offset_mm": -2.147, "load_n_per_mm_std": 0.00048,
            "offset_mm_std": 0.019}
    est = {**ESTIMATE, "force_n": None, "label": "line", "line": line, "ellipse": None}
    msg = decode("contact", m.serialize(m.contact(est, STAMP, "pad"), m.TYPES["contact"]))
    for key, value in line.items():
        assert getattr(msg, f"line_{key}") == value, key
    assert math.isnan(msg.force_n) and msg.label == "line"
    plain = decode("contact", m.serialize(m.contact(ESTIMATE, STAMP, "f"), m.TYPES["contact"]))
    assert math.isnan(plain.line_load_n_per_mm) and math.isnan(plain.line_offset_mm_std)


def two_contacts() -> dict[str, Any]:
    """An estimate of two contacts, its ids given by the daemon's own association: the held
    cylinder of ESTIMATE and a lighter sphere beside it, after one frame of the cylinder alone
    (so their ids are 1 and 2, the strongest first)."""
    envelope = ("type", "sensor", "sensor_id", "seq", "device_time_us", "host_time", "time",
                "latency_ms", "worker_ms", "gate", "fitted_seq")
    first = {k: v for k, v in ESTIMATE.items() if k not in envelope and k != "fit_ms"}
    first["reasons"] = {**first["reasons"], "contacts": "one of 2 contacts on this array"}
    second = {**first, "model": "sphere", "label": "sphere", "x_mm": 4.25, "y_mm": 6.5,
              "force_n": 0.4375, "r1_mm": 6.0, "r2_mm": 6.0, "angle_deg": None,
              "std": {**first["std"], "force_n": 0.02, "angle_deg": None, "r2_mm": 0.9},
              "ellipse": {"a_mm": 1.5, "b_mm": 1.5, "theta_deg": 0.0},
              "reasons": {"angle_deg": "undefined: sphere", "contacts": "one of 2 contacts"},
              "frames_used": 1, "vx_mm_s": None, "line": {"load_n_per_mm": 0.125,
                                                          "offset_mm": -1.5}}
    ids = ContactIds(2.0)
    identified(dict(first), ids)
    fit = identified({**first, "fit_ms": 7.5, "contacts": [first, second]}, ids)
    return {**{k: ESTIMATE[k] for k in envelope}, **fit}


def check_contact(msg: Any, est: dict[str, Any], element: dict[str, Any]) -> None:
    """``msg`` (a decoded Contact) is ``element`` of ``est``'s contacts, field by field."""
    for key in ("sensor", "sensor_id", "seq", "device_time_us", "gate", "fitted_seq"):
        assert getattr(msg, key) == est[key], key
    for key in ("latency_ms", "worker_ms", "fit_ms"):
        assert same(getattr(msg, key), est[key]), key
    for key in ("contact_id", "model", "label", "converged", "iterations", "message",
                "frames_used", "contact"):
        assert getattr(msg, key) == element[key], key
    for key in ("x_mm", "y_mm", "force_n", "r1_mm", "r2_mm", "angle_deg", "vx_mm_s", "vy_mm_s",
                "angle_rate_deg_s", "force_rate_n_s"):
        assert same(getattr(msg, key), element.get(key)), key
        assert same(getattr(msg, f"std_{key}"), element["std"].get(key)), f"std_{key}"
    for key in ("rms", "peak", "condition"):
        assert same(getattr(msg, key), element[key]), key
    e = element["ellipse"]
    assert (msg.ellipse_a_mm, msg.ellipse_b_mm, msg.ellipse_theta_deg) == (
        e["a_mm"], e["b_mm"], e["theta_deg"])
    line = element.get("line") or {}
    for key in ("load_n_per_mm", "offset_mm", "load_n_per_mm_std", "offset_mm_std"):
        assert same(getattr(msg, f"line_{key}"), line.get(key)), key
    assert dict(zip(msg.reason_keys, msg.reason_texts)) == element["reasons"]
    assert msg.header.frame_id == "finger0" and msg.header.stamp.nanosec == 250_000_000


def test_contact_array_lists_every_contact_the_strongest_first() -> None:
    est = two_contacts()
    assert [c["contact_id"] for c in est["contacts"]] == [1, 2] and est["contact_id"] == 1
    msg = decode("contacts", m.serialize(m.contact_array(est, STAMP, "finger0"),
                                         m.TYPES["contacts"]))
    assert (msg.sensor, msg.sensor_id, msg.seq) == ("finger0", 0, 9561)
    assert msg.header.frame_id == "finger0" and msg.header.stamp.sec == 1795309645
    assert len(msg.contacts) == 2
    for got, element in zip(msg.contacts, est["contacts"]):
        check_contact(got, est, element)
    # the contact topic carries the strongest, the same message as the array's first
    top = decode("contact", m.serialize(m.contact(est, STAMP, "finger0"), m.TYPES["contact"]))
    check_contact(top, est, est["contacts"][0])
    none = decode("contacts", m.serialize(m.contact_array(
        {**NO_CONTACT, "contact_id": None, "contacts": []}, STAMP, "f"), m.TYPES["contacts"]))
    assert none.contacts == [] and none.seq == 3
    # an estimate written before the contacts list existed is its own one contact
    old = decode("contacts", m.serialize(m.contact_array(ESTIMATE, STAMP, "f"),
                                         m.TYPES["contacts"]))
    assert [(c.contact_id, c.force_n) for c in old.contacts] == [(-1, 1.0312)]


def test_markers_draw_every_contact_with_ids_from_its_contact_id() -> None:
    est = two_contacts()
    msg = decode("markers", m.serialize(m.markers(est, STAMP, "finger0"), m.TYPES["markers"]))
    assert (msg.markers[0].action, msg.markers[0].ns) == (3, "finger0")  # DELETEALL first
    drawn = {(k.id, k.type): k for k in msg.markers[1:]}
    assert all(k.action == 0 and k.ns == "finger0" for k in drawn.values())
    assert sorted(drawn) == [(2, 3), (3, 0), (4, 3), (5, 0)]  # ids 2c (ellipse), 2c+1 (arrow)
    for element in est["contacts"]:
        cid = element["contact_id"]
        ellipse, arrow = drawn[(2 * cid, 3)], drawn[(2 * cid + 1, 0)]
        assert math.isclose(ellipse.pose.position.x, element["x_mm"] * 1e-3)
        assert math.isclose(ellipse.pose.position.y, element["y_mm"] * 1e-3)
        assert math.isclose(ellipse.scale.x, 2e-3 * element["ellipse"]["a_mm"])
        tail, head = arrow.points
        assert math.isclose(tail.z - head.z, element["force_n"] * m.ARROW_M_PER_N)
        assert (head.x, head.y) == (ellipse.pose.position.x, ellipse.pose.position.y)
    assert m.marker_ids(2**30) == (0, 1)  # int32 ids, wrapped


def test_watch_ros2_prints_every_contact_of_the_array() -> None:
    from tactiled_service.ros2 import reader, rmw

    est = two_contacts()
    typename = m.TYPES["contacts"]
    key = f"0/tactiled/finger0/contacts/{rmw.dds_type(typename)}/{m.type_hash(typename)}"
    line = reader.decode(key, m.serialize(m.contact_array(est, STAMP, "finger0"), typename),
                         None)
    assert line is not None and (line["topic"], line["type"]) == ("/tactiled/finger0/contacts",
                                                                  typename)
    listed = line["message"]["contacts"]
    assert [(c["contact_id"], c["force_n"], c["angle_deg"]) for c in listed] == [
        (k["contact_id"], k["force_n"], k["angle_deg"]) for k in est["contacts"]]


def test_watch_prints_fields_not_a_definitions_constants() -> None:
    """rosbags lists a definition's constants as dataclass fields; `watch --ros2` prints only
    the fields (checked on a definition with constants and on the messages the daemon sends)."""
    import dataclasses

    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from tactiled_service.ros2.reader import plain

    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg("uint8 STICK=0\nuint8 SLIP=2\nfloat64 x_mm\nuint8 state",
                                      "probe_msgs/msg/State"))
    cls = store.types["probe_msgs/msg/State"]
    assert {"STICK", "SLIP"} <= {f.name for f in dataclasses.fields(cls)}  # what rosbags does
    assert plain(cls(x_mm=1.5, state=2)) == {"x_mm": 1.5, "state": 2}
    field = store.types["sensor_msgs/msg/PointField"](name="z", offset=8, datatype=7, count=1)
    assert plain(field) == {"name": "z", "offset": 8, "datatype": 7, "count": 1}


def test_a_3axis_contacts_shear_and_slip_ride_in_the_contact_message() -> None:
    """The JSON's shear and slip tables (docs/concepts/shear.md) as the Contact's fields, the
    same names; null (mu withheld) as NaN; a 1-axis estimate has NaN and an empty state."""
    shear = {"fx_n": 0.213, "fy_n": -0.087, "torque_nmm": 0.041, "q_over_p": 0.1796,
             "mu": None, "slip_margin": None, "seq": 17,
             "std": {"fx_n": 0.0031, "fy_n": 0.0029, "torque_nmm": 0.0052, "q_over_p": 0.0024,
                     "mu": None, "slip_margin": None}}
    est = {**ESTIMATE, "shear": shear, "slip": {"state": "partial", "lam": 0.41, "lam_std": 0.12}}
    msg = decode("contact", m.serialize(m.contact(est, STAMP, "xela"), m.TYPES["contact"]))
    for key in ("fx_n", "fy_n", "torque_nmm", "q_over_p", "mu", "slip_margin"):
        assert same(getattr(msg, key), shear[key]), key
        assert same(getattr(msg, f"std_{key}"), shear["std"][key]), key
    assert msg.slip_state == "partial"
    plain = decode("contact", m.serialize(m.contact(ESTIMATE, STAMP, "f"), m.TYPES["contact"]))
    assert math.isnan(plain.fx_n) and math.isnan(plain.std_torque_nmm) and plain.slip_state == ""

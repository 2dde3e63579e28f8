"""Estimates, frames and health as ROS 2 messages: pure conversion, no I/O (docs/howto/ros2.md).

Every function takes the daemon's own JSON objects and returns a ``rosbags`` message;
:func:`serialize` turns it into CDR bytes with their 4-byte encapsulation header (little-endian,
as rmw_zenoh and rosbag2 write them).  REP 103, SI units, except the Contact message, which
keeps the JSON's names and units (mm, N, degrees; NaN for null).
"""
# Conventions:
# * the sensor frame (header.frame_id): x along the finger (tactel row m at x = m * dx), y around
#   it (column n at y = n * dy, arc length), z out of the skin; the cylinder's curvature is not
#   unrolled (a flat-patch approximation, good to ~1 % over a tactel window on a 12.7 mm finger);
# * header.stamp: wall-clock time (Unix epoch) of the frame's arrival on the host;
# * the wrench is the force the object exerts on the sensor, -force_n along z applied at the
#   contact centre, with its moment about the frame's origin, in N and N*m;
# * markers are in metres; the Contact message keeps the JSON's names and units so that one name
#   means one thing on every interface.
# Inputs: an estimate's to_json_dict(), a zeroed frame, the health document.

from __future__ import annotations

import functools
import json
import math
import re
from importlib import resources
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore, get_types_from_msg

#: Topic kind -> ROS 2 type name (the topic is ``<namespace>/<sensor>/<kind>``, diagnostics
#: ``/diagnostics``).
TYPES: dict[str, str] = {
    "wrench": "geometry_msgs/msg/WrenchStamped",
    "contact": "tactiled_msgs/msg/Contact",
    "contacts": "tactiled_msgs/msg/ContactArray",
    "strain": "sensor_msgs/msg/Image",
    "taxels": "sensor_msgs/msg/Image",
    "markers": "visualization_msgs/msg/MarkerArray",
    "diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}
CONTACT_TYPE = TYPES["contact"]
CONTACT_ARRAY_TYPE = TYPES["contacts"]
#: The kinds published for every estimate (the strain image goes with frames).
ESTIMATE_KINDS = ("wrench", "contact", "contacts", "markers")
DIAGNOSTICS_TOPIC = "/diagnostics"
#: The ROS 2 distribution whose message definitions the standard types follow (Jazzy and
#: Kilted define these four identically: same RIHS01 hashes).
DISTRO = "jazzy"

#: Contact fields filled from the estimate's JSON key of the same name (NaN for null).
_VALUE_KEYS = ("x_mm", "y_mm", "force_n", "r1_mm", "r2_mm", "angle_deg",
               "vx_mm_s", "vy_mm_s", "angle_rate_deg_s", "force_rate_n_s")
_FIT_KEYS = ("rms", "peak", "condition", "latency_ms", "worker_ms", "fit_ms")
#: Contact fields filled from the estimate's ``shear`` table (with their ``std_``).
_SHEAR_KEYS = ("fx_n", "fy_n", "torque_nmm", "q_over_p", "mu", "slip_margin")
#: tactiled health status -> diagnostic_msgs/DiagnosticStatus level (OK 0, WARN 1, ERROR 2,
#: STALE 3): DEGRADED (a rate below nominal) is a warning, STALE (no estimates) is STALE.
LEVELS = {"OK": 0, "WARN": 1, "DEGRADED": 1, "ERROR": 2, "STALE": 3}
ARROW_M_PER_N = 0.01  # length of the force arrow, m per N (1 cm per newton)
ELLIPSE_THICKNESS_M = 0.0005  # height of the flat cylinder drawn as the contact ellipse


def contact_definition(typename: str = CONTACT_TYPE) -> str:
    """The text of a ``tactiled_msgs`` message (``ros2/tactiled_msgs/msg/<Name>.msg``)."""
    name = typename.rsplit("/", 1)[-1] + ".msg"
    return resources.files("tactiled_service.ros2").joinpath(name).read_text("utf-8")


@functools.cache
def typestore() -> Any:
    """The type store: the standard types of ROS 2 Jazzy plus ``tactiled_msgs/msg/Contact``
    and ``tactiled_msgs/msg/ContactArray``."""
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(contact_definition(), CONTACT_TYPE))
    store.register(get_types_from_msg(contact_definition(CONTACT_ARRAY_TYPE), CONTACT_ARRAY_TYPE))
    return store


@functools.cache
def type_hash(typename: str) -> str:
    """The RIHS01 type hash ROS 2 computes for ``typename`` (``RIHS01_<64 hex digits>``)."""
    return str(typestore().hash_rihs01(typename))


@functools.cache
def definition(typename: str) -> str:
    """The ``ros2msg`` definition with its dependencies (the MCAP schema rosbag2 writes)."""
    return str(typestore().generate_msgdef(typename, ros_version=2)[0])


def serialize(message: Any, typename: str) -> bytes:
    """CDR bytes, little-endian, with the encapsulation header ``00 01 00 00``."""
    return bytes(typestore().serialize_cdr(message, typename, little_endian=True))


def deserialize(data: bytes, typename: str) -> Any:
    """The message object of CDR ``data`` (the reading side: ``tactiled watch --ros2``)."""
    return typestore().deserialize_cdr(data, typename)


def ros_segment(sensor: str) -> str:
    """A sensor name as a ROS name segment: characters other than letters, digits and '_'
    become '_', runs of '_' one, and a leading digit gets an 's' (``finger-0`` ->
    ``finger_0``, ``0`` -> ``s0``)."""
    text = re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9_]", "_", sensor))
    return f"s{text}" if not text or text[0].isdigit() else text


def check_segments(sensors: list[str]) -> None:
    """ValueError when two sensor names map to one ROS name segment (their topics would be
    the same: ``finger-0`` and ``finger_0``)."""
    seen: dict[str, str] = {}
    for name in sensors:
        other = seen.setdefault(ros_segment(name), name)
        if other != name:
            raise ValueError(f"sensors {other!r} and {name!r} have the same ROS topics "
                             f"(.../{ros_segment(name)}/...): rename one")


def topic(namespace: str, sensor: str, kind: str) -> str:
    """The fully qualified topic of ``kind`` for ``sensor``: ``<namespace>/<sensor>/<kind>``
    (``/tactiled/finger0/wrench``); diagnostics are ``/diagnostics`` (the ROS convention)."""
    if kind == "diagnostics":
        return DIAGNOSTICS_TOPIC
    return f"{namespace.rstrip('/')}/{ros_segment(sensor)}/{kind}"


def frame_name(template: str, sensor: str) -> str:
    """``header.frame_id`` of ``sensor``'s messages: ``template`` with "{sensor}" filled in."""
    return template.replace("{sensor}", sensor)


# --------------------------------------------------------------------------------------------
# Building blocks


def _cls(name: str) -> Any:
    return typestore().types[name]


def nanoseconds(seconds: float) -> int:
    """Unix ``seconds`` as integer nanoseconds, never negative (whole seconds and the fraction
    apart: ``seconds * 1e9`` itself is beyond a double's 53 bits and would lose ~100 ns)."""
    if not seconds > 0:
        return 0
    whole = math.floor(seconds)
    return whole * 1_000_000_000 + round((seconds - whole) * 1e9)


def _time(seconds: float) -> Any:
    """builtin_interfaces/Time of Unix ``seconds``."""
    sec, nanosec = divmod(nanoseconds(seconds), 1_000_000_000)
    return _cls("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)


def header(stamp_s: float, frame_id: str) -> Any:
    return _cls("std_msgs/msg/Header")(stamp=_time(stamp_s), frame_id=frame_id)


def _vector(x: float, y: float, z: float) -> Any:
    return _cls("geometry_msgs/msg/Vector3")(x=x, y=y, z=z)


def _num(value: Any) -> float:
    """A JSON number as float; null (and anything non-finite) as NaN."""
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) \
        else math.nan


def _present(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and \
        math.isfinite(value)


# --------------------------------------------------------------------------------------------
# Estimates


def wrench(est: dict[str, Any], stamp_s: float, frame_id: str) -> Any:
    """geometry_msgs/WrenchStamped: the contact force on the sensor, N, with its moment about
    the frame's origin, N*m (zero without contact or without a force estimate).  On a 3-axis
    array whose estimate has a ``shear`` table, the force gains the tangential force
    (``fx_n``, ``fy_n``) and the moment the torsion about +z (``torque_nmm``, in N*m): REP 103,
    SI units."""
    fx = fy = fz = x = y = tz = 0.0
    if est.get("contact") and _present(est.get("force_n")):
        fz = -float(est["force_n"])
        x = _num(est.get("x_mm")) * 1e-3 if _present(est.get("x_mm")) else 0.0
        y = _num(est.get("y_mm")) * 1e-3 if _present(est.get("y_mm")) else 0.0
        shear = est.get("shear")
        if isinstance(shear, dict):
            fx = float(shear["fx_n"]) if _present(shear.get("fx_n")) else 0.0
            fy = float(shear["fy_n"]) if _present(shear.get("fy_n")) else 0.0
            tz = float(shear["torque_nmm"]) * 1e-3 if _present(shear.get("torque_nmm")) else 0.0
    # r x F with r = (x, y, 0) and F = (fx, fy, fz), plus the torsion about +z
    torque = _vector(y * fz + 0.0, -x * fz + 0.0, x * fy - y * fx + tz + 0.0)  # + 0.0: no -0
    body = _cls("geometry_msgs/msg/Wrench")(force=_vector(fx + 0.0, fy + 0.0, fz), torque=torque)
    return _cls("geometry_msgs/msg/WrenchStamped")(header=header(stamp_s, frame_id),
                                                   wrench=body)


def item_stamp(item: Any, clock_offset: float) -> float:
    """A hub item's ``header.stamp``, Unix s: the frame's time (``item.stamp``, from
    :mod:`tactiled.clock`), or, for an item no clock stamped, its arrival moved onto the
    wall clock by ``clock_offset`` (Unix - monotonic s)."""
    stamp = getattr(item, "stamp", math.nan)
    return stamp if math.isfinite(stamp) else item.host_time + clock_offset


def estimate_message(kind: str, est: dict[str, Any], stamp_s: float, frame_id: str) -> Any:
    """The message of ``kind`` (one of :data:`ESTIMATE_KINDS`) for an estimate."""
    return _ESTIMATE_BUILDERS[kind](est, stamp_s, frame_id)


def estimate_cdr(kind: str, est: Any, stamp_s: float, frame_id: str) -> bytes:
    """The CDR bytes of ``kind``'s message (:func:`serialize` of :func:`estimate_message`) for
    ``est``: an ``Estimate`` record (its bytes built once per estimate, kind, frame id and stamp,
    kept on the record and shared by every consumer: the live node's middlewares and the MCAP
    recorder), or an estimate's JSON dict (built each call: ``tactiled export``)."""
    if isinstance(est, dict):
        return serialize(estimate_message(kind, est, stamp_s, frame_id), TYPES[kind])
    return est.encoded(("ros2", kind, frame_id, stamp_s), lambda record: serialize(
        estimate_message(kind, record.json_dict, stamp_s, frame_id), TYPES[kind]))


def contact(est: dict[str, Any], stamp_s: float, frame_id: str) -> Any:
    """tactiled_msgs/Contact: every value of the estimate with its 1-sigma (NaN for null)."""
    std = est.get("std") or {}
    ellipse = est.get("ellipse") or {}
    line = est.get("line") or {}
    reasons = est.get("reasons") or {}
    fields: dict[str, Any] = {
        "header": header(stamp_s, frame_id),
        "sensor": str(est.get("sensor", "")),
        "sensor_id": int(est.get("sensor_id") or 0),
        "seq": int(est.get("seq") or 0),
        "device_time_us": int(est.get("device_time_us") or 0),
        "gate": str(est.get("gate", "")),
        "fitted_seq": -1 if est.get("fitted_seq") is None else int(est["fitted_seq"]),
        "contact": bool(est.get("contact")),
        "contact_id": -1 if est.get("contact_id") is None else int(est["contact_id"]),
        "model": str(est.get("model") or ""),
        "label": str(est.get("label") or ""),
        "frames_used": int(est.get("frames_used") or 0),
        "ellipse_a_mm": _num(ellipse.get("a_mm")),
        "ellipse_b_mm": _num(ellipse.get("b_mm")),
        "ellipse_theta_deg": _num(ellipse.get("theta_deg")),
        **{f"line_{k}": _num(line.get(k)) for k in ("load_n_per_mm", "offset_mm",
                                                    "load_n_per_mm_std", "offset_mm_std")},
        "converged": bool(est.get("converged")),
        "iterations": int(est.get("iterations") or 0),
        "message": str(est.get("message") or ""),
        "reason_keys": [str(k) for k in reasons],
        "reason_texts": [str(v) for v in reasons.values()],
    }
    for key in _VALUE_KEYS:
        fields[key] = _num(est.get(key))
        fields[f"std_{key}"] = _num(std.get(key))
    for key in _FIT_KEYS:
        fields[key] = _num(est.get(key))
    shear = est.get("shear") or {}
    shear_std = shear.get("std") or {}
    for key in _SHEAR_KEYS:
        fields[key] = _num(shear.get(key))
        fields[f"std_{key}"] = _num(shear_std.get(key))
    slip = est.get("slip") or {}
    fields["slip_state"] = str(slip.get("state") or "")
    return _cls(CONTACT_TYPE)(**fields)


#: An estimate's per-frame keys (the envelope of ``Estimate.to_json_dict()`` and the fitter's
#: time for the frame), which every contact of the frame shares unless it has its own.
_FRAME_KEYS = ("sensor", "sensor_id", "seq", "device_time_us", "latency_ms", "worker_ms", "gate",
               "fitted_seq", "fit_ms")


def contact_list(est: dict[str, Any]) -> list[dict[str, Any]]:
    """Every contact of an estimate, the strongest first, each as a one-contact estimate: the
    frame's keys and that element of ``contacts`` (``[]`` without contact).  An estimate
    without ``contacts`` (written before the key existed) is its own one contact."""
    listed = est.get("contacts")
    if listed is None:
        return [est] if est.get("contact") else []
    frame = {k: est[k] for k in _FRAME_KEYS if k in est}
    return [{**frame, "contact": True, **c} for c in listed]


def contact_array(est: dict[str, Any], stamp_s: float, frame_id: str) -> Any:
    """tactiled_msgs/ContactArray: every contact of the frame (:func:`contact` each, the
    strongest first; ``contacts[0]`` is the ``contact`` topic's message), empty without
    contact."""
    return _cls(CONTACT_ARRAY_TYPE)(
        header=header(stamp_s, frame_id), sensor=str(est.get("sensor", "")),
        sensor_id=int(est.get("sensor_id") or 0), seq=int(est.get("seq") or 0),
        contacts=[contact(c, stamp_s, frame_id) for c in contact_list(est)])


def _quaternion_z(angle_rad: float) -> Any:
    return _cls("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=math.sin(angle_rad / 2),
                                                w=math.cos(angle_rad / 2))


def _marker(hdr: Any, ns: str, mid: int, mtype: int, action: int, *, position=(0.0, 0.0, 0.0),
            yaw_rad: float = 0.0, scale=(0.0, 0.0, 0.0), rgba=(0.0, 0.0, 0.0, 0.0),
            points: tuple[tuple[float, float, float], ...] = ()) -> Any:
    point = _cls("geometry_msgs/msg/Point")
    pose = _cls("geometry_msgs/msg/Pose")(position=point(x=position[0], y=position[1],
                                                         z=position[2]),
                                          orientation=_quaternion_z(yaw_rad))
    unused = _unused_marker_fields()
    return _cls("visualization_msgs/msg/Marker")(
        header=hdr, ns=ns, id=mid, type=mtype, action=action, pose=pose,
        scale=_vector(*scale),
        color=_cls("std_msgs/msg/ColorRGBA")(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
        frame_locked=False, points=[point(x=p[0], y=p[1], z=p[2]) for p in points], colors=[],
        texture_resource="", uv_coordinates=[], text="", mesh_resource="",
        mesh_use_embedded_materials=False, **unused)


@functools.cache
def _unused_marker_fields() -> dict[str, Any]:
    """The Marker fields tactiled leaves empty, built once and shared (messages are only
    read after they are built): an infinite lifetime, no texture, no mesh."""
    return {"lifetime": _cls("builtin_interfaces/msg/Duration")(sec=0, nanosec=0),
            "texture": _cls("sensor_msgs/msg/CompressedImage")(
                header=header(0.0, ""), format="", data=np.zeros(0, dtype=np.uint8)),
            "mesh_file": _cls("visualization_msgs/msg/MeshFile")(
                filename="", data=np.zeros(0, dtype=np.uint8))}


def marker_ids(contact_id: int) -> tuple[int, int]:
    """The Marker ids of a contact: ``2 * contact_id`` its ellipse, ``2 * contact_id + 1`` its
    force arrow (modulo 2**31: ``Marker.id`` is an int32), the same for as long as it is held."""
    base = (2 * contact_id) % 2**31
    return base, base + 1


def markers(est: dict[str, Any], stamp_s: float, frame_id: str) -> Any:
    """visualization_msgs/MarkerArray, namespace = the sensor: first a DELETEALL of that
    namespace, then for every contact (the strongest first) its ellipse (a flat green cylinder,
    2a x 2b, major axis at theta) and its force arrow (red, 1 cm per N, pointing into the skin
    at the contact centre), with the ids of :func:`marker_ids`.  Each message thus holds the
    whole picture: no contact leaves a stale marker, even when a message before was dropped
    or the viewer joined late; without contact it is the DELETEALL alone."""
    hdr = header(stamp_s, frame_id)
    ns = str(est.get("sensor", ""))
    marker_t = _cls("visualization_msgs/msg/Marker")
    out = [_marker(hdr, ns, 0, marker_t.CYLINDER, marker_t.DELETEALL)]
    for index, c in enumerate(contact_list(est)):
        if not (_present(c.get("x_mm")) and _present(c.get("y_mm"))):
            continue
        cid = c.get("contact_id")
        ellipse_id, arrow_id = marker_ids(index if cid is None else int(cid))
        cx, cy = float(c["x_mm"]) * 1e-3, float(c["y_mm"]) * 1e-3
        ellipse = c.get("ellipse") or {}
        if _present(ellipse.get("a_mm")) and _present(ellipse.get("b_mm")):
            theta = float(ellipse["theta_deg"]) if _present(ellipse.get("theta_deg")) else 0.0
            out.append(_marker(hdr, ns, ellipse_id, marker_t.CYLINDER, marker_t.ADD,
                               position=(cx, cy, 0.0), yaw_rad=math.radians(theta),
                               scale=(2e-3 * float(ellipse["a_mm"]),
                                      2e-3 * float(ellipse["b_mm"]), ELLIPSE_THICKNESS_M),
                               rgba=(0.1, 0.8, 0.2, 0.6)))
        if _present(c.get("force_n")):
            length = ARROW_M_PER_N * float(c["force_n"])
            out.append(_marker(hdr, ns, arrow_id, marker_t.ARROW, marker_t.ADD,
                               scale=(0.0008, 0.0016, 0.002), rgba=(0.9, 0.1, 0.1, 1.0),
                               points=((cx, cy, length), (cx, cy, 0.0))))
    return _cls("visualization_msgs/msg/MarkerArray")(markers=out)


_ESTIMATE_BUILDERS = {"wrench": wrench, "contact": contact, "contacts": contact_array,
                      "markers": markers}


# --------------------------------------------------------------------------------------------
# Frames and health


def strain_image(strain: np.ndarray, stamp_s: float, frame_id: str) -> Any:
    """sensor_msgs/Image ``32FC1``: the zeroed strain (dimensionless, + under compression),
    ``height`` = rows (x), ``width`` = cols (y), little-endian float32."""
    data = np.ascontiguousarray(np.nan_to_num(strain, nan=0.0, posinf=0.0, neginf=0.0),
                                dtype="<f4")
    rows, cols = data.shape
    return _cls("sensor_msgs/msg/Image")(
        header=header(stamp_s, frame_id), height=rows, width=cols, encoding="32FC1",
        is_bigendian=0, step=4 * cols, data=data.reshape(-1).view(np.uint8))


def taxel_image(taxels: np.ndarray, stamp_s: float, frame_id: str) -> Any:
    """sensor_msgs/Image ``32FC3``: a 3-axis array's zeroed readings, channels x, y, z (z +
    under compression; the description's readings), ``height`` = rows, ``width`` = cols,
    little-endian float32."""
    data = np.ascontiguousarray(np.nan_to_num(taxels, nan=0.0, posinf=0.0, neginf=0.0),
                                dtype="<f4")
    rows, cols, axes = data.shape
    return _cls("sensor_msgs/msg/Image")(
        header=header(stamp_s, frame_id), height=rows, width=cols, encoding=f"32FC{axes}",
        is_bigendian=0, step=4 * axes * cols, data=data.reshape(-1).view(np.uint8))


#: Per-sensor health keys copied into a DiagnosticStatus's values (those present).
_DIAG_KEYS = ("frame_rate_hz", "fit_rate_hz", "frames", "published", "lost_frames",
              "crc_errors", "fit_errors", "connected", "in_contact", "model")


def diagnostics(report: dict[str, Any], stamp_s: float, hardware_ids: dict[str, str]) -> Any:
    """diagnostic_msgs/DiagnosticArray of a health document (``GET /v1/health``): one status per
    sensor, named ``tactiled: <sensor>``, the reason as its message when not OK."""
    status_t = _cls("diagnostic_msgs/msg/DiagnosticStatus")
    kv = _cls("diagnostic_msgs/msg/KeyValue")
    statuses = []
    for name, s in report.get("sensors", {}).items():
        status = str(s.get("status", "ERROR"))
        values = [kv(key="status", value=status)]
        values += [kv(key=k, value=json.dumps(s[k]) if not isinstance(s[k], str) else s[k])
                   for k in _DIAG_KEYS if k in s]
        statuses.append(status_t(level=LEVELS.get(status, 2), name=f"tactiled: {name}",
                                 message=str(s.get("reason") or status),
                                 hardware_id=hardware_ids.get(name, name), values=values))
    return _cls("diagnostic_msgs/msg/DiagnosticArray")(header=header(stamp_s, ""),
                                                       status=statuses)

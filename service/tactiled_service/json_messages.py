"""What the service sends: estimates and frames as wire messages, and control messages.

Every message is a JSON object with ``type``, ``v`` (:data:`SCHEMA_VERSION`) and ``seq`` (the
sensor's frame sequence number; null for messages about no frame).  An estimate message is
``Estimate.to_json_dict()`` with ``type`` in place of ``class``, plus ``ellipse``; the REST
endpoints return the same objects.  :class:`Encoder` encodes each item once, whatever the
number of subscribers.
"""
# ellipse: the contact ellipse to draw, {a_mm, b_mm, theta_deg} (semi-axes in mm, major axis
# from +x toward +y in degrees), or null; when the estimate lists several contacts (contacts),
# each element gets its own ellipse too.  A slip message is a 3-axis array's slip event
# (tactiled.pipeline.shear_track.SlipItem).

from __future__ import annotations

import json
import logging
import math
import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

from tactiled.pipeline import Estimate, ZeroedFrame

log = logging.getLogger(__name__)

#: Version of the message schemas, bumped when what a message holds changes (docs/reference/api.md):
#: 2 added ``contact_id`` and ``contacts`` to the estimate; every key of 1 is unchanged.
SCHEMA_VERSION = 2

#: ``streams`` a client may ask for -> the hub's item kinds.
STREAM_KINDS = {"estimates": "estimate", "frames": "frame", "slip": "slip"}

EllipseFunc = Callable[..., Any]
_ellipse_func: EllipseFunc | None = None
_ellipse_error: str | None = None
_ellipse_lock = threading.Lock()


def load_ellipse() -> EllipseFunc | None:
    """Import the Hertz ellipse (it imports scipy, so call this once at startup, off the
    event loop) and return ``contact_ellipse_radii``; None (logged once) if it cannot
    be loaded: estimates then carry ``ellipse: null`` rather than failing."""
    global _ellipse_func, _ellipse_error
    with _ellipse_lock:
        if _ellipse_func is None and _ellipse_error is None:
            try:
                from tactiled.physics.hertz import contact_ellipse_radii

                contact_ellipse_radii(10.0, math.inf, 90.0, 1.0)  # a first call, off the loop
                _ellipse_func = contact_ellipse_radii
            except Exception as err:  # a display aid: never worth stopping the daemon
                _ellipse_error = f"{type(err).__name__}: {err}"
                log.warning("contact ellipses unavailable: %s", _ellipse_error)
    return _ellipse_func


def display_ellipse(fit: dict[str, Any], finger_radius: float,
                    compliance: float) -> dict[str, float] | None:
    """The contact ellipse of a fit line, for drawing: ``{a_mm, b_mm, theta_deg}`` or None.

    Uses the pipeline's own ``ellipse`` when the fit carries one; otherwise Hertz from the
    fitted r1, r2 (None: infinite), angle (None: a sphere, any angle) and force, on a finger
    of ``finger_radius`` mm with rubber compliance ``compliance`` mm^2/N.  None without
    contact, or for a contact Hertz cannot describe (an infinite line).
    """
    own = fit.get("ellipse")
    if isinstance(own, dict):
        return own
    if not fit.get("contact"):
        return None
    r1, r2, angle, force = (fit.get(k) for k in ("r1_mm", "r2_mm", "angle_deg", "force_n"))
    if r1 is None or force is None or not (r1 > 0 and force > 0):
        return None
    func = _ellipse_func or load_ellipse()
    if func is None:
        return None
    try:
        ell = func(float(r1), math.inf if r2 is None else float(r2),
                   0.0 if angle is None else float(angle), float(force),
                   finger_radius, compliance)
    except (ValueError, ZeroDivisionError, OverflowError):
        return None
    if not (math.isfinite(ell.a) and math.isfinite(ell.b) and math.isfinite(ell.theta)):
        return None
    return {"a_mm": round(ell.a, 4), "b_mm": round(ell.b, 4),
            "theta_deg": round(math.degrees(ell.theta) % 180.0, 3)}


def control(type_: str, **fields: Any) -> dict[str, Any]:
    """A message about no frame (version, subscribed, error, pong): ``seq`` is null."""
    return {"type": type_, "v": SCHEMA_VERSION, "seq": None, **fields}


def error(code: str, message: str, request: str | None = None) -> dict[str, Any]:
    """An error message: ``code`` is a short word, ``message`` says precisely what was wrong."""
    return control("error", code=code, message=message, request=request)


class Encoder:
    """Items -> message dicts and JSON text, each computed once per item.

    ``sensor_physics`` maps a sensor name to ``(finger_radius_mm, compliance_mm2_per_n)``
    for its ellipse.  The caches hold the items they key (by ``id``), so an id is never
    reused while cached.
    """

    def __init__(self, sensor_physics: dict[str, tuple[float, float]],
                 size: int = 1024) -> None:
        self.sensor_physics = sensor_physics
        self.size = size
        self._text: OrderedDict[int, tuple[object, str]] = OrderedDict()
        self._ellipse: OrderedDict[int, tuple[object, dict[str, float] | None]] = OrderedDict()

    def ellipse(self, est: Estimate, fit: dict[str, Any] | None = None) -> dict[str, float] | None:
        """The ellipse of ``fit``: the estimate's own fit line, or one of its ``contacts``."""
        fit = est.fit if fit is None else fit
        # "unchanged" estimates share their fit dict with the fitted one: one Hertz solve each.
        key = id(fit)
        hit = self._ellipse.get(key)
        if hit is not None and hit[0] is fit:
            return hit[1]
        radius, compliance = self.sensor_physics.get(est.sensor, (12.7, 3.0))
        try:
            ell = display_ellipse(fit, radius, compliance)
        except Exception:  # a display aid must never cost the estimate
            log.exception("ellipse of %s seq %d failed", est.sensor, est.seq)
            ell = None
        self._ellipse[key] = (fit, ell)
        if len(self._ellipse) > self.size:
            self._ellipse.popitem(last=False)
        return ell

    def message(self, item: Estimate | ZeroedFrame) -> dict[str, Any]:
        """The message dict of a hub item (a fresh dict; callers may change it)."""
        # (an estimate's JSON form is built once and shared: read, never changed; its "type"
        # is the item's kind, and keeps its place first)
        body = item.json_dict if isinstance(item, Estimate) else item.to_json_dict()
        msg: dict[str, Any] = {"type": item.kind, "v": SCHEMA_VERSION, **body}
        if isinstance(item, Estimate):
            msg["ellipse"] = self.ellipse(item)
            contacts = item.fit.get("contacts")
            if isinstance(contacts, list):  # each contact of several gets its own ellipse
                msg["contacts"] = [{**c, "ellipse": self.ellipse(item, c)}
                                   if isinstance(c, dict) else c for c in contacts]
        elif isinstance(item, ZeroedFrame):
            msg["rows"], msg["cols"] = (int(n) for n in item.strain.shape)
        return msg

    def text(self, item: Estimate | ZeroedFrame) -> str:
        """The message as compact strict JSON, cached."""
        key = id(item)
        hit = self._text.get(key)
        if hit is not None and hit[0] is item:
            return hit[1]
        text = dumps(self.message(item))
        self._text[key] = (item, text)
        if len(self._text) > self.size:
            self._text.popitem(last=False)
        return text


def dumps(msg: dict[str, Any]) -> str:
    """Compact strict JSON (the pipeline guarantees no NaN; this would raise on one)."""
    return json.dumps(msg, separators=(",", ":"), allow_nan=False)

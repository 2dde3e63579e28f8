"""The one rule every estimate passes before it is published: never a guess."""

# ``tactiled fit``, the daemon's fits, its trackers' estimates, the estimates it reuses for an
# unchanged frame and each contact of a frame of several go through :func:`judge` (the fitter
# through :func:`judge_values` on its own dicts, the daemon through :func:`judge` on the JSON
# form it publishes).  A value is ``null`` with its reason when
#
# * **its own uncertainty says it is unknown**: a radius or force whose 1-sigma bound exceeds
#   ``UNOBSERVABLE_RELATIVE_SIGMA`` of it (or the caller's ``withhold_relative_sigma``, for a
#   radius), a radius outside ``RADIUS_LIMITS``, an orientation uncertain by more than
#   ``MAX_ANGLE_SIGMA``, a position uncertain by more than the array's span along it (it could
#   lie anywhere on the array);
# * **the frame rejects its model**: the Hertz ellipse of the reported radii, orientation and
#   force is longer than ``OFF_ARRAY_LENGTH`` times the array along its major axis (a contact
#   mostly beyond the array, which the planar model describes
#   only inside the array: the part beyond it is not seen, so the force and radii that say how
#   large it is are not measured; the position and orientation of what is seen stay);
# * **it is physically implausible for the array**: a value that is not a finite number, a
#   force or radius that is not positive.
#
# The same rule applies however the value was made (a fit of this frame, a filter over many,
# a fit reused for an unchanged frame), so the daemon publishes nothing ``tactiled fit`` would
# not.  Everything here is derived from the array (its span, its pitch) and the model (Hertz:
# :mod:`tactiled.physics.hertz`); no threshold is tuned to a scene.

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from tactiled.fit.params import (
    MAX_ANGLE_SIGMA,
    RADIUS_LIMITS,
    TOO_LIGHT,
    UNOBSERVABLE_RELATIVE_SIGMA,
    VALUE_KEYS,
)
from tactiled.fit.profile import FLAT_ACROSS
from tactiled.physics import hertz


#: What the ellipse rule withholds: the values that say how large a contact is.
SIZE_KEYS = ("force_n", "r1_mm", "r2_mm")
#: A contact whose Hertz ellipse is longer than this many times the array along it is mostly
#: off the array (its middle two thirds span the array at most): the fitter's own bound for a
#: line along the curved finger (``fitter.LINE_CONTACT_LENGTH``).  Up to it the strains the
#: array sees still fix the contact's size (the paper's finger recovers a 50 mm cylinder at
#: 2 N, 1.13 times the array long, to 1 %: tests/fit/test_recovery.py).
OFF_ARRAY_LENGTH = 1.5


@dataclass(frozen=True)
class ArrayLimits:
    """What an array can see: its span (mm, tactel centre to centre) and pitch along x and y,
    its surface radius (``math.inf``: flat) and its cover's compliance ``(1 - nu^2) / E``
    (mm^2/N), for the Hertz ellipse of a reported contact."""

    span_x: float
    span_y: float
    dx: float
    dy: float
    finger_radius: float
    compliance: float

    @classmethod
    def of(cls, sensor: Any) -> ArrayLimits:
        """The limits of a ``config.SensorModel``."""
        g = sensor.geometry
        return cls(float(g.span_x), float(g.span_y), float(g.dx), float(g.dy),
                   float(g.finger_radius), float(sensor.material.compliance))

    def extent(self, theta: float) -> float:
        """The array's length (mm, edge to edge: its span plus one pitch) along direction
        ``theta`` (rad from +x)."""
        c, s = abs(math.cos(theta)), abs(math.sin(theta))
        return c * (self.span_x + self.dx) + s * (self.span_y + self.dy)


def sigma_reason(key: str, v: float, sd: float | None, limits: ArrayLimits | None = None,
                 withhold_relative_sigma: float | None = None, over: str = "") -> str | None:
    """Why ``key`` (value ``v``, 1-sigma ``sd``) is not known, by its own uncertainty; None to
    report it.  ``over``: what the sigma rests on, for the reason (" over 12 frame(s)")."""
    if key == "angle_deg":
        if sd is None or not sd <= MAX_ANGLE_SIGMA:
            return f"orientation not observable: sigma above {MAX_ANGLE_SIGMA:g} deg"
        return None
    if key in ("x_mm", "y_mm"):
        if limits is None:
            return None
        span = (limits.span_x + limits.dx) if key == "x_mm" else (limits.span_y + limits.dy)
        if sd is None or not sd <= span:
            return (f"position not observable: sigma{over} above the array's span "
                    f"({span:.1f} mm) along it")
        return None
    if key not in ("r1_mm", "r2_mm", "force_n"):
        return None
    radius = key != "force_n"
    what = "radius" if radius else "force"
    if not v > 0.0:
        return f"not a measurement: a {what} of {v:.3g}"
    rel = math.inf if sd is None else sd / v
    limit = withhold_relative_sigma if radius and withhold_relative_sigma is not None else math.inf
    if (rel > UNOBSERVABLE_RELATIVE_SIGMA or rel > limit
            or (radius and not RADIUS_LIMITS[0] <= v <= RADIUS_LIMITS[1])):
        pct = ("unbounded" if math.isinf(rel) else "over 10000 %" if rel > 100.0
               else f"{100 * rel:.0f} %")
        return (f"{TOO_LIGHT if radius else 'not observable'}: the sigma of the {what}{over} "
                f"is {pct} of it")
    return None


def ellipse_of(values: dict[str, Any], limits: ArrayLimits) -> dict[str, float] | None:
    """The Hertz contact ellipse of the reported values (semi-axes ``a_mm >= b_mm``, major
    axis ``theta_deg`` from +x in [0, 180)), or None where they do not give one (a value
    withheld, a line contact on a flat array, an infinite line)."""
    r1, r2, f = values.get("r1_mm"), values.get("r2_mm"), values.get("force_n")
    angle = values.get("angle_deg")
    if r1 is None or f is None or not (r1 > 0.0 and f > 0.0):
        return None
    r2 = math.inf if r2 is None else r2
    if angle is None:
        if r2 != r1:
            return None  # a contact with two radii and no orientation: no ellipse
        angle = 0.0
    if math.isinf(r2) and math.isinf(limits.finger_radius):
        return None  # a cylinder on a flat array is a line, not an ellipse
    if not r2 > 0.0:
        return None
    try:
        a, b, theta, _ = hertz.ellipse_axes(1.0 / r1, 0.0 if math.isinf(r2) else 1.0 / r2,
                                            math.radians(angle), f, limits.finger_radius,
                                            limits.compliance)
    except (ValueError, ZeroDivisionError, OverflowError):
        return None  # (an infinite line among them)
    if not (math.isfinite(a) and math.isfinite(b) and a >= 0.0):
        return None
    return {"a_mm": a, "b_mm": b, "theta_deg": math.degrees(theta) % 180.0}


def _withhold(values: dict, std: dict, reasons: dict, key: str, why: str) -> None:
    values[key] = None
    if key in std:
        std[key] = None
    reasons[key] = why


def _all_kept(values: dict[str, Any], std: dict[str, Any], limits: ArrayLimits | None,
              withhold_relative_sigma: float | None) -> bool:
    """True when :func:`sigma_reason` and the finiteness rule keep every value (the common
    case: a well measured contact), so :func:`judge_values` need not ask value by value.  The
    same tests as theirs, inline; any doubt (an int, a missing sigma where one is needed) is
    False and leaves the decision to them."""
    inf = math.inf
    for key in VALUE_KEYS:
        v = values.get(key)
        if v is None:
            continue
        if v.__class__ is not float or not -inf < v < inf:
            return False
        sd = std.get(key)
        if sd is None:
            if key == "x_mm" or key == "y_mm":
                continue  # (no sigma for a place: judge_values keeps it)
            return False
        if sd.__class__ is not float or not 0.0 <= sd < inf:
            return False
        if key == "x_mm":
            if limits is not None and not sd <= limits.span_x + limits.dx:
                return False
        elif key == "y_mm":
            if limits is not None and not sd <= limits.span_y + limits.dy:
                return False
        elif key == "angle_deg":
            if not sd <= MAX_ANGLE_SIGMA:
                return False
        else:  # force_n, r1_mm, r2_mm
            if not v > 0.0:
                return False
            rel = sd / v
            if rel > UNOBSERVABLE_RELATIVE_SIGMA:
                return False
            if key != "force_n" and ((withhold_relative_sigma is not None
                                      and rel > withhold_relative_sigma)
                                     or not RADIUS_LIMITS[0] <= v <= RADIUS_LIMITS[1]):
                return False
    return True


def judge_values(values: dict[str, Any], std: dict[str, Any], reasons: dict[str, str],
                 limits: ArrayLimits, *, label: str | None = None,
                 withhold_relative_sigma: float | None = None,
                 over: str = "") -> dict[str, float] | None:
    """Apply the rule (see the module's doc) to one contact's ``values``, ``std`` and
    ``reasons`` (``VALUE_KEYS``), in place.  Returns its Hertz contact ellipse from the values
    kept (:func:`ellipse_of`), None where they give none; an ellipse longer than the array
    sets ``reasons["ellipse"]``."""
    for key in () if _all_kept(values, std, limits, withhold_relative_sigma) else VALUE_KEYS:
        v = values.get(key)
        if v is None:
            continue
        if not (isinstance(v, (int, float)) and math.isfinite(v)):
            _withhold(values, std, reasons, key, "not a measurement: not a finite number")
            continue
        sd = std.get(key)
        if sd is not None and not (math.isfinite(sd) and sd >= 0.0):
            sd = None
        why = sigma_reason(key, float(v), sd, limits, withhold_relative_sigma, over)
        if why is not None and (sd is not None or key in ("r1_mm", "r2_mm", "force_n",
                                                           "angle_deg")):
            _withhold(values, std, reasons, key, why)
    if label == "line":
        if FLAT_ACROSS in str(reasons.get("angle_deg", "")):
            # the line's orientation is not known, its likelihood flat across it: the joint
            # likelihood is not quadratic, so the linearised sigma of its place (which trades
            # with the orientation) does not hold either
            why = ("position not observable: the line's orientation is not (its likelihood is "
                   "flat across it), and its place rests on it")
            for key in ("x_mm", "y_mm"):
                if values.get(key) is not None:
                    _withhold(values, std, reasons, key, why)
        return None  # a line's radius and load are judged above; it has no ellipse to bound
    return _bounded(ellipse_of(values, limits), values, std, reasons, limits)


def _bounded(ell: dict[str, float] | None, values: dict[str, Any], std: dict[str, Any],
             reasons: dict[str, str], limits: ArrayLimits) -> dict[str, float] | None:
    """``ell`` (the values' ellipse) where it is not longer than the array allows; else None,
    the size keys of ``values`` (and ``std``) withheld with the reason."""
    if ell is None:
        return None
    extent = limits.extent(math.radians(ell["theta_deg"]))
    if 2.0 * ell["a_mm"] > OFF_ARRAY_LENGTH * extent:
        why = (f"outside the planar model: the Hertz ellipse of these values is "
               f"{2 * ell['a_mm']:.1f} mm long, the array {extent:.1f} mm along it, so the part "
               "beyond the array that sets the contact's size is not seen")
        for key in SIZE_KEYS:
            if values.get(key) is not None:
                _withhold(values, std, reasons, key, why)
        reasons["model"] = why
        reasons["ellipse"] = why
        return None
    return ell


def judge(fit: dict[str, Any], limits: ArrayLimits, *,
          withhold_relative_sigma: float | None = None) -> dict[str, Any]:
    """The rule on a published fit dict (``FitResult.to_json_dict()`` and what the daemon
    adds: ``contacts``), in place: the top-level contact and each of ``contacts``.  Its
    ``ellipse`` becomes the one its kept values give (a tracked estimate's follows its
    tracked radii, orientation and force; null with a reason when they give none).  Returns
    ``fit``."""
    if not fit.get("contact"):
        return fit
    before = _contact_of(fit)
    _judge_one(fit, limits, withhold_relative_sigma)
    for c in fit.get("contacts") or ():
        if c is fit or not isinstance(c, dict):
            continue
        if _reads_as(c, before):
            # the top level's own contact (one contact: the same dict's copy): judged already
            _take_verdict(c, fit)
            continue
        _judge_one(c, limits, withhold_relative_sigma)
    return fit


def _contact_of(fit: dict[str, Any]) -> tuple:
    """What the rule reads of a contact: its sigmas, reasons, label and values."""
    return (fit.get("std"), fit.get("reasons"), fit.get("label"),
            {k: fit.get(k) for k in VALUE_KEYS})


def _reads_as(c: dict[str, Any], before: tuple) -> bool:
    """Whether contact ``c`` reads as ``before`` (:func:`_contact_of`) to the rule."""
    std, reasons, label, values = before
    return (c.get("std") == std and c.get("reasons") == reasons and c.get("label") == label
            and all(c.get(k) == v for k, v in values.items()))


def _take_verdict(c: dict[str, Any], fit: dict[str, Any]) -> None:
    """Contact ``c`` given ``fit``'s verdict (the same contact's, judged)."""
    c.update({k: fit.get(k) for k in VALUE_KEYS})
    c["std"], c["reasons"] = dict(fit["std"]), dict(fit["reasons"])
    if "ellipse" in fit:
        c["ellipse"] = fit["ellipse"]


def judge_fresh(fit: dict[str, Any], limits: ArrayLimits, *,
                withhold_relative_sigma: float | None = None) -> dict[str, Any]:
    """:func:`judge` on an estimate made for this publication alone (a tracker's, completed
    by ``association.identified(..., fresh=True)``): each contact's ``std`` and ``reasons``
    dicts its own, the top level a copy of its first contact's.  Each contact is judged in
    place, once, and the top level takes its first contact's verdict, where :func:`judge`
    judges the top level, compares it with each contact and judges the others: the same
    dicts, key for key (tests/fit/test_verdict_fresh.py).  Anything else (a top level that
    is not its first contact's copy, a dict it cannot vouch for) goes to :func:`judge`."""
    if not fit.get("contact"):
        return fit
    contacts = fit.get("contacts")
    first = contacts[0] if contacts else None
    if (first is None or first is fit or first.__class__ is not dict
            or fit.get("std") is not first.get("std")
            or fit.get("reasons") is not first.get("reasons")
            or fit.get("label") is not first.get("label") or not _copied(fit, first)):
        return judge(fit, limits, withhold_relative_sigma=withhold_relative_sigma)
    same = []
    if len(contacts) == 1:
        _judge_in_place(first, limits, withhold_relative_sigma)
    else:  # (another contact that reads as the first, as judge takes it: its verdict too)
        before = _contact_of(first)
        same = [c for c in contacts[1:] if c is not fit and isinstance(c, dict)
                and _reads_as(c, before)]
        for c in contacts:
            if c is not fit and isinstance(c, dict) and not any(c is d for d in same):
                _judge_in_place(c, limits, withhold_relative_sigma)
    for k in VALUE_KEYS:
        if k in first:
            fit[k] = first[k]
    fit["std"], fit["reasons"] = dict(first["std"]), dict(first["reasons"])
    if "ellipse" in first:
        fit["ellipse"] = first["ellipse"]
    for c in same:
        _take_verdict(c, fit)
    return fit


def _copied(fit: dict[str, Any], first: dict[str, Any]) -> bool:
    """Whether ``fit``'s values are ``first``'s own objects (a copy of its keys)."""
    get, got = fit.get, first.get
    for k in VALUE_KEYS:
        if get(k) is not got(k):
            return False
    return True


def _judge_in_place(fit: dict[str, Any], limits: ArrayLimits,
                    withhold_relative_sigma: float | None) -> None:
    """:func:`_judge_one` on a contact whose ``std`` and ``reasons`` are its own: where every
    value stands by its sigma (:func:`_all_kept`), only its ellipse is judged, in place."""
    std, reasons = fit.get("std"), fit.get("reasons")
    if (std.__class__ is not dict or reasons.__class__ is not dict
            or fit.get("label") == "line" or fit.get("line") is not None
            or not _all_kept(fit, std, limits, withhold_relative_sigma)):
        _judge_one(fit, limits, withhold_relative_sigma)
        return
    ell = _bounded(ellipse_of(fit, limits), fit, std, reasons, limits)
    if ell is not None:
        fit["ellipse"] = ell
    elif fit.get("ellipse") is not None or "ellipse" in reasons:
        fit["ellipse"] = None
        reasons.setdefault("ellipse", "not estimated: a value it follows from is withheld")


def _judge_one(fit: dict[str, Any], limits: ArrayLimits,
               withhold_relative_sigma: float | None) -> None:
    values = {k: fit.get(k) for k in VALUE_KEYS}
    std = fit.get("std")
    std = dict(std) if isinstance(std, dict) else {}
    reasons = dict(fit.get("reasons") or {})
    had = {k: v for k, v in values.items() if v is not None}
    ell = judge_values(values, std, reasons, limits, label=fit.get("label"),
                       withhold_relative_sigma=withhold_relative_sigma)
    for k in had:
        if values[k] is None:
            fit[k] = None
    fit["std"] = std
    fit["reasons"] = reasons
    if fit.get("label") == "line" or fit.get("line") is not None:
        return  # a line contact's ellipse (none on a flat array) stays as its fit gave it
    if ell is not None:
        fit["ellipse"] = ell
    elif fit.get("ellipse") is not None or "ellipse" in reasons:
        fit["ellipse"] = None
        reasons.setdefault("ellipse", "not estimated: a value it follows from is withheld")


def carried(fit: dict[str, Any], change: float, frames: int) -> dict[str, Any]:
    """``fit`` (a published fit dict) carried to a later frame that its gate found unchanged,
    ``frames`` frames after the one fitted: a copy whose 1-sigma bounds cover what the frames
    changed since.  ``change`` is that change's size in the fit's metric, ``|delta s|^2 /
    sigma^2`` (the gate's estimate: twice its chi^2 above its degrees of freedom, never below
    zero).  A change of the strains by ``delta s`` moves a least-squares value by at most
    ``sqrt(change)`` of its single-frame sigma (Cauchy-Schwarz in the metric ``J^T J /
    sigma^2``); spread over the contact's parameters and the residual it is typically about its
    root mean square, so each sigma becomes ``sqrt(1 + change)`` times itself, and the reason
    says from how far the value is carried."""
    out = dict(fit)
    widen = math.sqrt(1.0 + max(float(change), 0.0)) if math.isfinite(change) else math.inf
    std = dict(fit.get("std") or {})
    reasons = dict(fit.get("reasons") or {})
    for key in VALUE_KEYS:
        if std.get(key) is not None:
            std[key] = std[key] * widen if math.isfinite(widen) else None
            if std[key] is None:
                out[key] = None
                reasons[key] = "carried from an earlier fit across a change of unknown size"
    out["std"] = std
    note = (f"carried from the fit {frames} frame(s) earlier (the frame unchanged within its "
            f"noise): sigmas widened {widen:.3g}x for the change since")
    reasons["carried"] = note
    out["reasons"] = reasons
    contacts = fit.get("contacts")
    if contacts:
        out["contacts"] = [c if c is fit else carried(c, change, frames) for c in contacts]
    return out


def withheld_since(before: dict[str, Any], after: dict[str, Any]) -> list[str]:
    """The values (``VALUE_KEYS``, of the top-level contact and of each of ``contacts`` in
    order) that ``before`` published and ``after`` (the same estimate carried and judged)
    withholds: where carrying costs a value, a fit of the frame can still say it."""
    pairs = [(before, after), *zip(before.get("contacts") or (), after.get("contacts") or ())]
    return [k for b, a in pairs for k in VALUE_KEYS
            if b.get(k) is not None and a.get(k) is None]


def carry(fit: dict[str, Any], change: float, frames: int, limits: ArrayLimits, *,
          withhold_relative_sigma: float | None = None) -> dict[str, Any] | None:
    """``fit`` (a published fit dict) :func:`carried` to a later frame and judged by the rule;
    None where that withholds a value ``fit`` published (:func:`withheld_since`): carrying
    never costs a value a fit of the frame would give, so that frame is fitted instead."""
    out = judge(carried(fit, change, frames), limits,
                withhold_relative_sigma=withhold_relative_sigma)
    return None if withheld_since(fit, out) else out

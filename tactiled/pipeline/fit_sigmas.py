"""What a tracked estimate's sigmas carry from the fit it rests on, and what pooling frames
cannot average away (:class:`tactiled.pipeline.contact_filter.Tracker`).

The tracker pools frames measured through a fit's linearisation; their pooled sigma is the
linearised one, shrinking as frames are added.  Two things it does not know: where the fit's
profile test (:mod:`tactiled.fit.profile`) found the likelihood wider than its curvature, and
a force whose frames all lean on the same unresolved radius.  No I/O and no state here.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tactiled.fit.params import RADIUS_LIMITS, VALUE_KEYS, report_terms
from tactiled.fit.profile import TEST_RELATIVE_SIGMA

#: The parameters of a model that are its radii (a force trades with them).
_RADIUS_PARAMS = ("ln_r", "ln_ra", "beta")


def radius_force_variance(cov: np.ndarray, names: tuple[str, ...]) -> float:
    """The variance of ln F (``cov``: one frame's covariance of the model's parameters
    ``names``) that its radius parameters explain: ``c_fR C_RR^-1 c_Rf``.  A tracked force
    resting on a radius the frames do not resolve carries it whole, however many frames it
    pools: such a radius lies anywhere along a curved valley of (radius, force), and the
    filter measures each frame through the point it holds (on the XELA pads a light 8 mm
    ball held at 30-300 mm had its force measured 20-30 % low with the sigma of a point)."""
    f = names.index("ln_f")
    r = [i for i, n in enumerate(names) if n in _RADIUS_PARAMS]
    if not r:
        return 0.0
    c_rr = cov[np.ix_(r, r)]
    c_rf = cov[r, f]
    try:
        x = np.linalg.solve(c_rr, c_rf)
    except np.linalg.LinAlgError:
        return float(cov[f, f])
    return float(min(max(c_rf @ x, 0.0), cov[f, f]))


#: A fit's sigma over its linearised one beyond this counts as widened (below it the two
#: differ by the order of their sums only).
WIDENED = 1.01


def fit_widening(fit: dict[str, Any], lin: Any) -> list[float]:
    """Per value key (``VALUE_KEYS`` order): ``fit``'s published sigma over the linearised
    single-frame sigma its linearisation ``lin`` gives at its point, where over ``WIDENED``,
    else 1.
    A fit's profile test (:mod:`tactiled.fit.profile`) widens a sigma where the likelihood
    rises more slowly than its curvature says (an ellipse's r2, its orientation near a
    circle, a line's angle and place); the tracker pools linearised frames, whose sigma
    knows nothing of it: it multiplies its sigma by this, so nothing it publishes is more
    confident than the fit it rests on beyond what the frames it pools add (their sigma
    shrinks with the frames as the linearised one does)."""
    out = [1.0] * len(VALUE_KEYS)
    std = fit.get("std") or {}
    try:
        _, terms = report_terms(lin.model, lin.p)
    except ValueError:
        return out
    cov = np.asarray(lin.cov, dtype=np.float64)
    for i, key in enumerate(VALUE_KEYS):
        sd_fit, t = std.get(key), terms[i]
        if sd_fit is None or not t or fit.get(key) is None:
            continue
        g = np.zeros(cov.shape[0])
        for j, d in t:
            g[j] = d
        v1 = float(g @ cov @ g)
        if v1 > 0.0 and math.isfinite(sd_fit) and sd_fit > WIDENED * math.sqrt(v1):
            out[i] = sd_fit / math.sqrt(v1)
    return out


def runaway_radius(r1: float | None) -> str | None:
    """Why a tracked force resting on the tracked radius ``r1`` (mm; the smaller one) is
    withheld: that radius lies beyond any a fit gives (``RADIUS_LIMITS``, where the fitter
    calls a radius "not a measurement"), so the filter has run along the valley of a radius
    the frames do not resolve to where its model no longer explains the frame (on the XELA
    4x4 pad a light ball's filter reached 180 m on its third frame, its force 0.008 +- 0.057 N
    against 0.25 N: at such a radius the model puts no strain on the window whatever the
    force).  None below it: a radius at the small end is a point contact, whose force the
    strain fixes."""
    if r1 is None or r1 <= RADIUS_LIMITS[1]:
        return None
    return (f"not observable: the force rests on a tracked radius of {r1:.3g} mm, beyond any a "
            f"fit gives ({RADIUS_LIMITS[1]:g} mm): the filter has run off along the valley of "
            "a radius the frames do not resolve")


def beyond_tested(v: float | None, sd: float | None) -> bool:
    """A fit's radius ``v`` (1-sigma ``sd``) outside the range where its linearised sigma is
    tested (:data:`TEST_RELATIVE_SIGMA`), or not given at all."""
    return v is None or sd is None or not (v > 0.0 and sd <= TEST_RELATIVE_SIGMA * v)


_I_FORCE, _I_ANGLE = VALUE_KEYS.index("force_n"), VALUE_KEYS.index("angle_deg")


def kept_by_limits(i: int, v: float, sd: float, limit: float) -> bool:
    """True where the tracker's rules surely keep its value ``v`` (``VALUE_KEYS[i]``, 1-sigma
    ``sd``; ``Tracker._withheld`` answers None): a place's or an angle's sigma within
    ``limit``, a force's or radius's relative sigma within ``limit`` (a radius within
    ``RADIUS_LIMITS``), or a force or radius not positive (which the fit's rule judges).
    False: the rules decide.  Asked first, so the rules' reasons are built only where due."""
    if i < 2 or i == _I_ANGLE:  # x_mm, y_mm, angle_deg
        return sd <= limit
    return v <= 0.0 or (v > 0.0 and not sd / v > limit
                        and (i == _I_FORCE or RADIUS_LIMITS[0] <= v <= RADIUS_LIMITS[1]))

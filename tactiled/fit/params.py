"""The contact models' parameter vectors in user units, without the physics.

Each model fits an unconstrained internal vector (see :mod:`tactiled.fit.models`):
``cylinder [ln R, psi, ln F, x0, y0]``, ``sphere [ln R, ln F, x0, y0]``, ``general [ln R_a,
beta, psi, ln F, x0, y0]`` (mm, radians, N).  :func:`report` turns one into the values a user
reads (mm, N, degrees) with the gradient for the delta method.  It lives here, apart from the
physics, so the daemon's main process (the temporal tracker) can report a contact without
importing the fitter.
"""

from __future__ import annotations

import math

import numpy as np

#: Keys of a fit's values, in the order of ``tactiled fit``'s JSON.
VALUE_KEYS = ("x_mm", "y_mm", "force_n", "r1_mm", "r2_mm", "angle_deg")

#: Each model's internal parameter names, in order.
PARAMS: dict[str, tuple[str, ...]] = {
    "cylinder": ("ln_r", "psi", "ln_f", "x0", "y0"),
    "sphere": ("ln_r", "ln_f", "x0", "y0"),
    "general": ("ln_ra", "beta", "psi", "ln_f", "x0", "y0"),
}

#: A radius or force whose 1-sigma bound exceeds this fraction of its value is flagged.
POOR_RELATIVE_SIGMA = 0.5
#: ... and withheld beyond this (the solver has run off to a degenerate limit), as is a radius
#: outside ``RADIUS_LIMITS``: a value there is an artefact, not a measurement.
UNOBSERVABLE_RELATIVE_SIGMA = 10.0
RADIUS_LIMITS = (0.01, 1e5)  # mm
#: An orientation whose 1-sigma bound exceeds this (degrees) is withheld.
MAX_ANGLE_SIGMA = 45.0
#: The reason a radius is withheld when the data do not pin it down (the fitter's words; the
#: tracker lifts it once the frames it has gathered do).
TOO_LIGHT = "force too low for curvature"
#: A force is tied to its radius when more than this share of its variance is the radius's
#: (the squared correlation of the two estimates): the radius's uncertainty at least doubles
#: the force's sigma.  See :func:`radius_tied_force`.
TIED_FORCE_SHARE = 0.75


def radius_tied_force(r: float | None, sd_r: float | None, sd_f: float | None,
                      cov_rf: float, unresolved: bool = False) -> str | None:
    """Why a force must be withheld with its radius, or None to keep it.

    ``r``, ``sd_r`` the radius (mm) and its 1-sigma bound, ``sd_f`` the force's (N),
    ``cov_rf`` their covariance (mm N).  Where the contact is not small beside the cover's
    depth, the strain pattern fixes the force only through the contact's size: a smaller
    radius concentrates the same pressure, and the force that explains the window grows as
    the radius shrinks.  When the radius's own 1-sigma interval reaches zero (``sd_r >= r``:
    the window does not tell the contact from a point) and more than ``TIED_FORCE_SHARE`` of
    the force's variance is the radius's (its sigma is over twice what it would be were the
    radius known), the force rests on a radius the array does not resolve: least squares then
    settles anywhere along that valley, and the force it reports there can lie several of its
    bounds from the truth.  Where the force hardly depends on the radius (a light touch under
    a cover deep beside the contact: the paper's finger, where the share stays near 50-56 %),
    the force is kept.  ``unresolved``: the radius is withheld for another reason its
    sigma gives (the daemon's tracker: not yet within the range where its linearised sigma
    holds), so the interval test is not needed."""
    if r is None or sd_r is None or sd_f is None or not (r > 0.0 and sd_f > 0.0) \
            or (sd_r < r and not unresolved):
        return None
    share = cov_rf * cov_rf / (sd_r * sd_r * sd_f * sd_f)
    if not share > TIED_FORCE_SHARE:
        return None
    return (f"{TOO_LIGHT}: the force trades with a radius the window does not resolve (the "
            f"radius's sigma is {100 * sd_r / r:.0f} % of it, {100 * share:.0f} % of the force's "
            "variance is the radius's)")

#: Parameters that move with the contact (the tracker gives them a rate); the others (the
#: curvatures) are a property of the object and held constant between changes.
MOVING = frozenset(("psi", "ln_f", "x0", "y0"))


def wrap_deg(psi: float) -> float:
    """An orientation in radians as degrees in [0, 180)."""
    d = math.degrees(psi) % 180.0
    return 0.0 if d >= 180.0 else d


#: A value's gradient as ``(parameter index, d value / d parameter)`` pairs (at most two are
#: non-zero); None where the value does not exist in the model.
Terms = tuple[tuple[int, float], ...] | None


def report_terms(model: str, p) -> tuple[dict[str, float | None], tuple[Terms, ...]]:
    """:func:`report` with the gradient as its non-zero terms per value key (in
    ``VALUE_KEYS`` order): the tracker takes the delta method term by term on every frame,
    where a dense 6 x k matrix costs a dozen numpy calls."""
    if model == "cylinder":
        r, f = math.exp(p[0]), math.exp(p[2])
        vals = {"x_mm": float(p[3]), "y_mm": float(p[4]), "force_n": f, "r1_mm": r,
                "r2_mm": None, "angle_deg": wrap_deg(p[1])}
        return vals, (((3, 1.0),), ((4, 1.0),), ((2, f),), ((0, r),), None,
                      ((1, 180.0 / math.pi),))
    if model == "sphere":
        r, f = math.exp(p[0]), math.exp(p[1])
        vals = {"x_mm": float(p[2]), "y_mm": float(p[3]), "force_n": f, "r1_mm": r,
                "r2_mm": r, "angle_deg": None}
        return vals, (((2, 1.0),), ((3, 1.0),), ((1, f),), ((0, r),), ((0, r),), None)
    if model != "general":
        raise ValueError(f"unknown model {model!r}; choose one of {sorted(PARAMS)}")
    ra, beta, f = math.exp(p[0]), float(p[1]), math.exp(p[3])
    b2 = beta * beta
    psi = float(p[2])
    t_r1: Terms
    t_r2: Terms
    if b2 <= 1.0:
        # r1 = R_a, r2 = R_a / beta^2 (inf for beta = 0)
        r1 = ra
        r2 = ra / b2 if b2 > 0.0 else None
        t_r1 = ((0, ra),)
        t_r2 = None if r2 is None else ((0, r2), (1, -2.0 * r2 / beta))
    else:
        # axes swapped: the R2 axis is perpendicular to the fitted psi
        r1 = ra / b2
        r2 = ra
        t_r1 = ((0, r1), (1, -2.0 * r1 / beta))
        t_r2 = ((0, ra),)
        psi += 0.5 * math.pi
    vals = {"x_mm": float(p[4]), "y_mm": float(p[5]), "force_n": f, "r1_mm": r1,
            "r2_mm": r2, "angle_deg": wrap_deg(psi)}
    return vals, (((4, 1.0),), ((5, 1.0),), ((3, f),), t_r1, t_r2, ((2, 180.0 / math.pi),))


def report(model: str, p: np.ndarray) -> tuple[dict[str, float | None], np.ndarray]:
    """User-unit values (``VALUE_KEYS``) of ``model``'s internal vector ``p`` and the gradient
    matrix (6 keys x parameters) for the delta method; a row of NaN marks a value that does
    not exist in this model (a cylinder's r2, a sphere's angle)."""
    vals, terms = report_terms(model, p)
    g = np.zeros((len(VALUE_KEYS), len(PARAMS[model])))
    for row, t in zip(g, terms):
        if t is None:
            row[:] = np.nan
        else:
            for j, d in t:
                row[j] = d
    return vals, g

"""The contact models' parameter vectors in user units, without the physics (no numba).

Each model fits an unconstrained internal vector (see :mod:`tactiled.fit.models`):
``cylinder [ln R, psi, ln F, x0, y0]``, ``sphere [ln R, ln F, x0, y0]``, ``general [ln R_a,
beta, psi, ln F, x0, y0]`` (mm, radians, N).  :func:`report` turns one into the values a user
reads (mm, N, degrees) with the gradient for the delta method.  It lives here, apart from the
compiled physics, so the daemon's main process (the temporal tracker) can report a contact
without importing numba.
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

#: Parameters that move with the contact (the tracker gives them a rate); the others (the
#: curvatures) are a property of the object and held constant between changes.
MOVING = frozenset(("psi", "ln_f", "x0", "y0"))


def wrap_deg(psi: float) -> float:
    """An orientation in radians as degrees in [0, 180)."""
    d = math.degrees(psi) % 180.0
    return 0.0 if d >= 180.0 else d


def report(model: str, p: np.ndarray) -> tuple[dict[str, float | None], np.ndarray]:
    """User-unit values (``VALUE_KEYS``) of ``model``'s internal vector ``p`` and the gradient
    matrix (6 keys x parameters) for the delta method; a row of NaN marks a value that does
    not exist in this model (a cylinder's r2, a sphere's angle)."""
    if model == "cylinder":
        r, f = math.exp(p[0]), math.exp(p[2])
        vals = {"x_mm": float(p[3]), "y_mm": float(p[4]), "force_n": f, "r1_mm": r,
                "r2_mm": None, "angle_deg": wrap_deg(p[1])}
        g = np.zeros((6, 5))
        g[0, 3] = 1.0
        g[1, 4] = 1.0
        g[2, 2] = f
        g[3, 0] = r
        g[4, :] = np.nan
        g[5, 1] = 180.0 / math.pi
        return vals, g
    if model == "sphere":
        r, f = math.exp(p[0]), math.exp(p[1])
        vals = {"x_mm": float(p[2]), "y_mm": float(p[3]), "force_n": f, "r1_mm": r,
                "r2_mm": r, "angle_deg": None}
        g = np.zeros((6, 4))
        g[0, 2] = 1.0
        g[1, 3] = 1.0
        g[2, 1] = f
        g[3, 0] = r
        g[4, 0] = r
        g[5, :] = np.nan
        return vals, g
    if model != "general":
        raise ValueError(f"unknown model {model!r}; choose one of {sorted(PARAMS)}")
    ra, beta, f = math.exp(p[0]), float(p[1]), math.exp(p[3])
    b2 = beta * beta
    g = np.zeros((6, 6))
    g[0, 4] = 1.0
    g[1, 5] = 1.0
    g[2, 3] = f
    psi = float(p[2])
    if b2 <= 1.0:
        # r1 = R_a, r2 = R_a / beta^2 (inf for beta = 0)
        r1 = ra
        r2 = ra / b2 if b2 > 0.0 else None
        g[3, 0] = ra
        if r2 is not None:
            g[4, 0] = r2
            g[4, 1] = -2.0 * r2 / beta
        else:
            g[4, :] = np.nan
    else:
        # axes swapped: the R2 axis is perpendicular to the fitted psi
        r1 = ra / b2
        r2 = ra
        g[3, 0] = r1
        g[3, 1] = -2.0 * r1 / beta
        g[4, 0] = ra
        psi += 0.5 * math.pi
    g[5, 2] = 180.0 / math.pi
    vals = {"x_mm": float(p[4]), "y_mm": float(p[5]), "force_n": f, "r1_mm": r1,
            "r2_mm": r2, "angle_deg": wrap_deg(psi)}
    return vals, g

"""Hertz contact ellipse of a rigid paraboloid on the cylindrical finger (paper eqs. 5-12)."""

# Curvatures rather than radii are the natural inputs: ``kappa_a = 1/R1`` is the indentor's
# curvature across its R2 axis, ``kappa_b = 1/R2`` along it (0 for a cylinder), and ``psi`` is the
# direction of the R2 axis from +x toward +y.  Then
#
#     M = 1/2 ( Rot(psi) diag(kappa_b, kappa_a) Rot(psi)^T + diag(0, 1/R_f) )
#
# has eigenvalues ``A' >= C'``; the major semi-axis ``a`` lies along the eigenvector of ``C'``
# (direction ``theta``), ``b = a sqrt(1 - m)`` along that of ``A'``, and
#
#     a^3 = 3 F k (K(m) - E(m)) / (2 pi m C'),    k = (1 - nu_f^2)/E.
#
# The core is scalar code, compiled (core/hertz.cpp; this Python body is its reference): the
# fitter calls it once per iteration, and numpy's per-call overhead on scalars would cost more
# than the algebra.  With ``jac=True`` the analytic
# derivatives of ``(a, b, theta)`` with respect to ``(kappa_a, kappa_b, psi, F)`` come too.

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from tactiled import native

from tactiled.physics.eccentricity import solve_log_scalar


class Ellipse(NamedTuple):
    """A contact ellipse: semi-axes ``a >= b`` in mm, major-axis direction ``theta`` in radians
    in ``[0, pi)``, and ``m = 1 - (b/a)^2``."""

    a: float
    b: float
    theta: float
    m: float


def ellipse_core(
    kappa_a: float,
    kappa_b: float,
    psi: float,
    force: float,
    finger_radius: float,
    compliance: float,
    jac: np.ndarray,
) -> tuple[float, float, float, float]:
    """Compiled core of :func:`contact_ellipse`: returns ``(a, b, theta, m)`` and, when ``jac``
    has shape (3, 4), fills it with ``d(a, b, theta)/d(kappa_a, kappa_b, psi, F)``.  Returns
    ``a = -1`` for an infinite line contact (``C' <= 0``) instead of raising (no exceptions in
    compiled code)."""
    s2, c2 = math.sin(2.0 * psi), math.cos(2.0 * psi)
    kf = 1.0 / finger_radius
    # M = [[p, q], [q, s]]; with cos^2 = (1 + c2)/2, sin^2 = (1 - c2)/2.
    ksum, kdif = kappa_a + kappa_b, kappa_b - kappa_a
    p = 0.25 * (ksum + kdif * c2)
    s = 0.25 * (ksum - kdif * c2 + 2.0 * kf)
    q = 0.25 * kdif * s2
    mu = 0.5 * (p + s)
    half = 0.5 * (p - s)
    delta = math.hypot(half, q)
    # C' = det(M) / A', not mu - delta: near a line contact (a cylinder almost along the
    # finger axis) mu - delta cancels to nothing.  det(2M) = ka kb + kf (kb cos^2 + ka sin^2).
    sp, cp = math.sin(psi), math.cos(psi)
    sin2, cos2 = sp * sp, cp * cp
    det = 0.25 * (kappa_a * kappa_b + kf * (kappa_b * cos2 + kappa_a * sin2))
    c_prime = det / (mu + delta)  # C'
    if not c_prime > 0.0:
        return -1.0, -1.0, 0.0, 1.0
    phi = 0.5 * math.atan2(q, half)  # direction of the A' eigenvector
    theta = (phi + 0.5 * math.pi) % math.pi
    if delta > 0.0:
        x = math.log(2.0 * delta / c_prime)  # log(lambda - 1), no cancellation
        m, m1, log_f, dlogf_dx, dlogm1_dx = solve_log_scalar(x, 1)
    else:  # circular contact: sphere-like limit m = 0, f = pi/4
        m, m1, log_f, dlogf_dx, dlogm1_dx = 0.0, 1.0, math.log(math.pi / 4.0), 0.0, 0.0
    log_a = (math.log(3.0 * compliance / (2.0 * math.pi)) + math.log(force) + log_f
             - math.log(c_prime)) / 3.0
    a = math.exp(log_a)
    b = a * math.sqrt(m1)
    if jac.shape[0] == 3:
        # d(p, s, q) / d(kappa_a, kappa_b, psi)
        for i in range(3):
            if i == 0:
                dp, ds, dq = 0.25 * (1.0 - c2), 0.25 * (1.0 + c2), -0.25 * s2
            elif i == 1:
                dp, ds, dq = 0.25 * (1.0 + c2), 0.25 * (1.0 - c2), 0.25 * s2
            else:
                dp, ds, dq = -0.5 * kdif * s2, 0.5 * kdif * s2, 0.5 * kdif * c2
            dmu = 0.5 * (dp + ds)
            dhalf = 0.5 * (dp - ds)
            if delta > 0.0:
                ddelta = (half * dhalf + q * dq) / delta
                jac[2, i] = 0.5 * (half * dq - q * dhalf) / (delta * delta)
                dc = dmu - ddelta
                dx = ddelta / delta - dc / c_prime
            else:
                ddelta = 0.0
                jac[2, i] = 0.0
                dc = dmu
                dx = 0.0
            dlog_a = (dlogf_dx * dx - dc / c_prime) / 3.0
            jac[0, i] = a * dlog_a
            jac[1, i] = b * (dlog_a + 0.5 * dlogm1_dx * dx)
        jac[0, 3] = a / (3.0 * force)
        jac[1, 3] = b / (3.0 * force)
        jac[2, 3] = 0.0
    return a, b, theta, m


#: the Python body (the reference); ``ellipse_core`` runs the compiled core's when it is loaded
REFERENCE = native.bind(globals(), ("ellipse_core",))

_NO_JAC = np.zeros((0, 0))


def contact_ellipse(
    kappa_a: float,
    kappa_b: float,
    psi: float,
    force: float,
    finger_radius: float,
    compliance: float,
    jac: bool = False,
) -> tuple[Ellipse, np.ndarray | None]:
    """Contact ellipse for curvatures in 1/mm, ``psi`` in radians, ``force`` in N.

    ``finger_radius`` in mm; ``compliance`` is ``k = (1 - nu_f^2)/E`` in mm^2/N.  Returns the
    ellipse and, if ``jac``, the 3x4 matrix ``d(a, b, theta) / d(kappa_a, kappa_b, psi, F)``
    (``theta`` derivative in rad/rad).  ``kappa_b > kappa_a`` is allowed (the fitter's general
    model may cross over); curvatures must be >= 0, and an indentor whose flat direction lies
    exactly along the finger axis (an infinite line contact) is a ``ValueError``.
    """
    out = np.empty((3, 4)) if jac else _NO_JAC
    a, b, theta, m = ellipse_axes(kappa_a, kappa_b, psi, force, finger_radius, compliance, out)
    return Ellipse(a, b, theta, m), (out if jac else None)


def ellipse_axes(kappa_a: float, kappa_b: float, psi: float, force: float,
                 finger_radius: float, compliance: float,
                 out: np.ndarray = _NO_JAC) -> tuple[float, float, float, float]:
    """:func:`contact_ellipse`'s numbers ``(a, b, theta, m)`` and its checks, without the
    record (the verdict asks for one every published estimate); ``out``: its Jacobian, or
    empty."""
    if not (kappa_a >= 0.0 and kappa_b >= 0.0 and force > 0.0 and math.isfinite(force)
            and math.isfinite(kappa_a) and math.isfinite(kappa_b) and math.isfinite(psi)):
        raise ValueError(
            f"need finite curvatures >= 0 and force > 0, got kappa_a={kappa_a!r}, "
            f"kappa_b={kappa_b!r}, psi={psi!r}, force={force!r}"
        )
    a, b, theta, m = ellipse_core(kappa_a, kappa_b, psi, force, finger_radius, compliance, out)
    if a < 0.0:
        raise ValueError(
            "contact is an infinite line (indentor axis parallel to the finger axis): "
            f"kappa_a={kappa_a!r}, kappa_b={kappa_b!r}, psi={psi!r} rad"
        )
    return a, b, theta, m


def contact_ellipse_radii(
    r1: float,
    r2: float,
    psi_deg: float,
    force: float,
    finger_radius: float = 12.7,
    compliance: float = 3.0,
) -> Ellipse:
    """Convenience form with principal radii in mm (``r2 = inf`` for a cylinder) and psi in
    degrees; defaults are the paper's finger, docs/concepts/model.md (R_f = 12.7 mm, k = (1 - 0.5^2)/0.25 mm^2/N)."""
    if not (r1 > 0 and r2 > 0):
        raise ValueError(f"radii must be positive, got r1={r1!r}, r2={r2!r}")
    ell, _ = contact_ellipse(
        1.0 / r1, 0.0 if math.isinf(r2) else 1.0 / r2, math.radians(psi_deg), force,
        finger_radius, compliance,
    )
    return ell

"""Eccentricity of a Hertz contact ellipse from its curvature ratio (docs/concepts/model.md)."""

# With ``m = e^2`` and K, E the complete elliptic integrals of parameter m, the ratio of the
# relative curvatures fixes m through
#
#     lambda = A'/C' = (E/(1-m) - K) / (K - E).
#
# We solve it for ``lambda - 1`` over 1e-19 .. 1e12 (sphere limit to near-line contact) without a
# root finder on the hot path: a precomputed table of ``x = log(lambda - 1)`` against
# ``y = logit(m)`` (where the relation is smooth and nearly linear over the whole range) gives a
# start good to ~1e-6, and Newton steps on ``x(y)`` polish it to machine precision.  ``m`` and
# ``m1 = 1 - m`` are both carried so that near-line contacts (``m1`` ~ 1e-12) keep full relative
# precision; below ``m = 0.05`` power series replace the scipy integrals, whose differences cancel
# there.

from __future__ import annotations

import math
from fractions import Fraction
from typing import NamedTuple

import numpy as np

from scipy.special import ellipe, ellipkm1

from tactiled import native

_SERIES_BELOW = 0.05  # m below which the power series are used (error ~0.05^14 ~ 6e-19)
_N_TERMS = 16


def _series_coefficients(n_terms: int) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients of ``(K-E)/m`` and ``(N-D)/m`` in powers of m, times 2/pi removed."""
    c = [Fraction(math.comb(2 * n, n), 4**n) ** 2 for n in range(n_terms + 2)]
    k = c  # K = pi/2 sum c_n m^n
    e = [cn / (1 - 2 * n) for n, cn in enumerate(c)]  # E = pi/2 sum c_n m^n / (1 - 2n)
    d = [kn - en for kn, en in zip(k, e)]  # K - E
    n_ = [sum(e[: n + 1], Fraction(0)) - k[n] for n in range(len(c))]  # E/(1-m) - K
    half_pi = math.pi / 2
    dm = np.array([float(d[n + 1]) for n in range(n_terms)]) * half_pi
    pm = np.array([float(n_[n + 1] - d[n + 1]) for n in range(n_terms)]) * half_pi
    return dm, pm


_DM_COEF, _PM_COEF = _series_coefficients(_N_TERMS)
_DM_DCOEF = _DM_COEF[1:] * np.arange(1, _N_TERMS)
_PM_DCOEF = _PM_COEF[1:] * np.arange(1, _N_TERMS)


def _poly(coef: np.ndarray, m: np.ndarray) -> np.ndarray:
    return np.polynomial.polynomial.polyval(m, coef)


class _Kernel(NamedTuple):
    dm: np.ndarray  # (K - E) / m            (-> pi/4 at m = 0)
    pm: np.ndarray  # (lambda - 1) (K - E)/m  = (N - D)/m
    d_dm: np.ndarray  # d/dm of dm
    d_pm: np.ndarray  # d/dm of pm


def _kernel(m: np.ndarray, m1: np.ndarray) -> _Kernel:
    """The two smooth combinations of K and E the solve needs, and their m-derivatives."""
    small = m < _SERIES_BELOW
    dm = np.empty_like(m)
    pm = np.empty_like(m)
    d_dm = np.empty_like(m)
    d_pm = np.empty_like(m)
    if np.any(small):
        ms = m[small]
        dm[small] = _poly(_DM_COEF, ms)
        pm[small] = _poly(_PM_COEF, ms)
        d_dm[small] = _poly(_DM_DCOEF, ms)
        d_pm[small] = _poly(_PM_DCOEF, ms)
    big = ~small
    if np.any(big):
        mb, m1b = m[big], m1[big]
        k = ellipkm1(m1b)
        e = ellipe(mb)
        dk = (e - m1b * k) / (2.0 * mb * m1b)
        de = (e - k) / (2.0 * mb)
        d = k - e
        nd = e * (2.0 - mb) / m1b - 2.0 * k  # N - D = E/m1 - K - (K - E)
        dd = dk - de
        # d/dm [E (2 - m)/(1 - m)] = E' (2 - m)/m1 + E/m1^2
        dnd = de * (2.0 - mb) / m1b + e / m1b**2 - 2.0 * dk
        dm[big] = d / mb
        pm[big] = nd / mb
        d_dm[big] = (dd * mb - d) / mb**2
        d_pm[big] = (dnd * mb - nd) / mb**2
    return _Kernel(dm, pm, d_dm, d_pm)


def _x_of_y(y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, _Kernel]:
    """``x = log(lambda - 1)`` and ``dx/dy`` at ``y = logit(m)``; also m, m1 and the kernel."""
    m = 1.0 / (1.0 + np.exp(-y))
    m1 = 1.0 / (1.0 + np.exp(y))
    ker = _kernel(m, m1)
    x = np.log(ker.pm) - np.log(ker.dm)
    dx_dm = ker.d_pm / ker.pm - ker.d_dm / ker.dm
    return x, dx_dm * m * m1, m, m1, ker


# Table of the inverse relation, built once at import (~2 ms).
_Y_TABLE = np.linspace(-46.0, 40.0, 6001)
_X_TABLE = _x_of_y(_Y_TABLE)[0]
if not np.all(np.diff(_X_TABLE) > 0):  # pragma: no cover - a broken scipy would show here
    raise RuntimeError("eccentricity table is not monotone")
X_MIN = float(_X_TABLE[0])  # lambda - 1 ~ 1e-20
X_MAX = float(_X_TABLE[-1])  # lambda - 1 ~ 1e18


class Eccentricity(NamedTuple):
    """Solution of the eccentricity equation at ``x = log(lambda - 1)``.

    ``m = e^2`` and ``m1 = 1 - m`` (both accurate); ``log_f = log((K - E)/m)``, the size factor
    of the contact; ``dlogf_dx`` and ``dlogm1_dx`` are derivatives with respect to x, for the
    fitter's analytic Jacobian.
    """

    m: np.ndarray
    m1: np.ndarray
    log_f: np.ndarray
    dlogf_dx: np.ndarray
    dlogm1_dx: np.ndarray


def solve_log(x: np.ndarray | float, newton_steps: int = 2) -> Eccentricity:
    """Solve for m given ``x = log(lambda - 1)``; vectorised over x.

    Values outside the table (``lambda - 1`` below 1e-20 or above 1e17) are clamped to its ends:
    below, m is ~1e-20 and the contact is a circle to double precision; above, the contact is
    longer than any finger by orders of magnitude and callers flag it as outside the model.
    """
    x = np.clip(np.asarray(x, dtype=float), X_MIN, X_MAX)
    y = np.interp(x, _X_TABLE, _Y_TABLE)
    for _ in range(newton_steps):
        xi, dxdy, *_ = _x_of_y(np.atleast_1d(y))
        y = y - (xi.reshape(np.shape(y)) - x) / dxdy.reshape(np.shape(y))
    xi, dxdy, m, m1, ker = _x_of_y(np.atleast_1d(y))
    dm_dx = m * m1 / dxdy
    shape = np.shape(x)
    return Eccentricity(
        m=m.reshape(shape),
        m1=m1.reshape(shape),
        log_f=np.log(ker.dm).reshape(shape),
        dlogf_dx=(ker.d_dm / ker.dm * dm_dx).reshape(shape),
        dlogm1_dx=(-dm_dx / m1).reshape(shape),
    )


def curvature_ratio(m: np.ndarray | float) -> np.ndarray:
    """``lambda = A'/C'`` from ``m`` straight from scipy's integrals (reference for tests)."""
    m = np.asarray(m, dtype=float)
    from scipy.special import ellipk

    k = ellipk(m)
    e = ellipe(m)
    return (e / (1.0 - m) - k) / (k - e)


# ---------------------------------------------------------------------------------------------
# Scalar fast path, compiled (core/eccentricity.cpp; these bodies are its reference).  The fitter
# solves one ellipse per iteration; numpy's per-call overhead on 1-element arrays (~200 us for
# the vector code above) would dominate a 1 ms fit.  K and E come from the arithmetic-geometric
# mean (agrees with scipy to 4e-15, tested), plain arithmetic the core repeats.
# ---------------------------------------------------------------------------------------------
_DM_H = np.ascontiguousarray(_DM_COEF[::-1])
_PM_H = np.ascontiguousarray(_PM_COEF[::-1])
_DDM_H = np.ascontiguousarray(_DM_DCOEF[::-1])
_DPM_H = np.ascontiguousarray(_PM_DCOEF[::-1])
_XT = np.ascontiguousarray(_X_TABLE)
_YT0 = float(_Y_TABLE[0])
_DY = float(_Y_TABLE[1] - _Y_TABLE[0])


def ellip_ke(m: float, m1: float) -> tuple[float, float]:
    """Complete elliptic integrals ``K(m), E(m)`` by the AGM; ``m1 = 1 - m`` passed separately
    so that near-line contacts keep full precision."""
    a = 1.0
    b = math.sqrt(m1)
    s = 0.5 * m  # 2^-1 c_0^2 with c_0^2 = m
    p = 0.5
    for _ in range(60):
        c = 0.5 * (a - b)
        a, b = 0.5 * (a + b), math.sqrt(a * b)
        p *= 2.0
        s += p * c * c
        if abs(c) <= 1e-17 * a:
            break
    k = math.pi / (2.0 * a)
    return k, k * (1.0 - s)


def _horner(coef_high_first: np.ndarray, m: float) -> float:
    acc = 0.0
    for c in coef_high_first:
        acc = acc * m + c
    return acc


def kernel_scalar(m: float, m1: float) -> tuple[float, float, float, float]:
    """``(K-E)/m``, ``(lambda-1)(K-E)/m`` and their m-derivatives (scalar :func:`_kernel`)."""
    if m < _SERIES_BELOW:
        return _horner(_DM_H, m), _horner(_PM_H, m), _horner(_DDM_H, m), _horner(_DPM_H, m)
    k, e = ellip_ke(m, m1)
    dk = (e - m1 * k) / (2.0 * m * m1)
    de = (e - k) / (2.0 * m)
    d = k - e
    nd = e * (2.0 - m) / m1 - 2.0 * k
    dnd = de * (2.0 - m) / m1 + e / (m1 * m1) - 2.0 * dk
    return d / m, nd / m, ((dk - de) * m - d) / (m * m), (dnd * m - nd) / (m * m)


def solve_log_scalar(x: float, newton_steps: int = 1) -> tuple[float, float, float, float, float]:
    """Scalar :func:`solve_log`: returns ``(m, m1, log_f, dlogf_dx, dlogm1_dx)``."""
    x = min(max(x, X_MIN), X_MAX)
    i = np.searchsorted(_XT, x, side="right") - 1
    i = min(max(i, 0), _XT.shape[0] - 2)
    x0, x1 = _XT[i], _XT[i + 1]
    y = _YT0 + _DY * (i + (x - x0) / (x1 - x0))
    m = m1 = dm = pm = ddm = dpm = dxdy = 0.0
    for step in range(newton_steps + 1):
        m = 1.0 / (1.0 + math.exp(-y))
        m1 = 1.0 / (1.0 + math.exp(y))
        dm, pm, ddm, dpm = kernel_scalar(m, m1)
        dxdy = (dpm / pm - ddm / dm) * m * m1
        if step == newton_steps:
            break
        y -= (math.log(pm / dm) - x) / dxdy
    dm_dx = m * m1 / dxdy
    return m, m1, math.log(dm), ddm / dm * dm_dx, -dm_dx / m1


#: the Python bodies (the reference); the module's names run the compiled core's when it is loaded
REFERENCE = native.bind(globals(), ("ellip_ke", "kernel_scalar", "solve_log_scalar"))
if native.core is not None:  # the core starts from this module's table and coefficients
    native.core.set_eccentricity_tables(_XT, _YT0, _DY, X_MIN, X_MAX, _SERIES_BELOW, _DM_H, _PM_H,
                                        _DDM_H, _DPM_H)

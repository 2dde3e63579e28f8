"""The profile likelihood of ``lam = Q/(mu P)`` and the friction coefficient's interval from it
(docs/concepts/shear.md).
"""

# The readings depend on ``lam`` through the stick zone's size, ``c/a = (1 - lam)^(1/3)``:
# nonlinearly, and with a likelihood that is often one-sided (flat toward full stick, steep
# toward slip, or the reverse), where a sigma from the curvature at the estimate misleads and
# ``mu = |Q| / (lam P)`` (a reciprocal) skews it further.  So the interval of ``lam`` comes from
# its profile: ``chi2(lam)`` minimised over the other parameters, evaluated exactly in ``lam``
# (the model at each ``lam``) and by two Gauss-Newton steps in the others from the fit (their
# Jacobian at the estimate): the readings are linear in the forces and torsion and nearly so in
# the rest over the interval.  The 2-sigma interval is where ``chi2`` lies within 4 of its least.
#
# The interval used is the union of that and the linearised one (``lam +/- 2 sigma``): at the
# bound ``lam = 1`` the profile's interval is cut short by the bound, the shorter the further
# the data stray past it, and publishing by its width would pick out those frames.
#
# ``mu`` then lies in ``[Q/P / lam_hi, Q/P / lam_lo]``, widened by the conditional bound of
# ``ln(Q/P)`` given ``lam`` (added in quadrature in ``ln mu``).  What is published is ``mu``
# where the profile is least, with half the interval's longer arm as sigma: ``mu +/- 2 sigma``
# holds the whole interval (one JSON sigma cannot say a skewed interval's two arms).
#
# Whether ``mu`` is resolved is decided by its Cramer-Rao bound at the estimate (the bound of
# ``lam`` at each ``lam`` of the grid, the other parameters profiled out; :func:`lam_bounds`),
# not by the width of the observed interval: the bound of ``lam`` shrinks fast toward slip,
# and a frame whose noise pushed ``lam`` up looks better resolved than its truth.  Deciding at
# the estimate means publishing where ``lam`` lies above a threshold ``L`` (the bound resolves
# ``mu`` from ``L`` up), and a value published because it cleared ``L`` is biased upward: so
# the interval's lower end is the *selective* one, the least ``lam`` whose truncated law
# (``lam`` Gaussian with its bound there, given that it cleared ``L``) still puts the
# estimate within its upper 2.5 % (Fithian, Sun and Taylor, "Optimal inference after model
# selection", 2014), at most :data:`SELECT_CAP` sigma below the estimate: the farther of
# SELECT_CAP bounds at the estimate and the profile's own SELECT_CAP-sigma end (``chi2`` within
# SELECT_CAP^2 of its least).  The bound shrinks fast toward slip: at an estimate near the bound
# 1 three bounds there reach a short way down, while the profile, flat toward full stick, says
# how far the likelihood reaches (a truth 2.5 sigma down a correct profile lay beyond the
# three bounds).  Far above ``L`` this is the ordinary interval.

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.stats import norm

#: Grid of ``lam`` on which the profile is first evaluated; its crossings are then bisected.
GRID = np.linspace(0.0, 1.0, 21)
#: Bisection steps per crossing (the interval's ends to 0.05 / 2^5 in ``lam``).
BISECT = 5
#: ``chi2`` above its least at the ends of the 2-sigma interval (one parameter).
TWO_SIGMA_CHI2 = 4.0
#: One-sided tail of the selective interval's lower end (that of a 2-sigma interval).
TAIL = 0.025
#: The selective lower end lies at most this many bounds of ``lam`` below the estimate.
SELECT_CAP = 3.0


@dataclass(frozen=True)
class LamInterval:
    """The 2-sigma profile interval ``[lo, hi]`` of ``lam`` and where the profile is least."""

    lo: float
    hi: float
    best: float
    #: The Cramer-Rao bound (1 sigma) of ``lam`` at each ``lam`` of :data:`GRID` (the other
    #: parameters profiled out), or None: what decides whether ``mu`` is resolved.
    bound: tuple[float, ...] | None = None
    #: The lower end of the profile's :data:`SELECT_CAP`-sigma interval (``chi2`` within
    #: ``SELECT_CAP^2`` of its least), or None: how far down the selective end may reach.
    far_lo: float | None = None

    def widened(self, lam: float, sigma: float) -> LamInterval:
        """The union with the linearised 2-sigma interval ``lam +/- 2 sigma`` (clipped to [0,
        1]): where the estimate sits at the bound 1 with the likelihood still falling beyond
        it, the profile interval shrinks as the data stray further past the bound, and a
        decision on its width alone would favour exactly those frames."""
        if not math.isfinite(sigma):
            return LamInterval(0.0, 1.0, self.best, self.bound, self.far_lo)
        return LamInterval(max(0.0, min(self.lo, lam - 2.0 * sigma)), min(1.0, max(self.hi, lam + 2.0 * sigma)),
                           self.best, self.bound, self.far_lo)

    def shifted(self, delta: float) -> LamInterval:
        """The interval moved by ``delta`` in ``lam`` (clipped to [0, 1]): a step's estimate."""
        def clip(v: float) -> float:
            return min(1.0, max(0.0, v))
        far = None if self.far_lo is None else clip(self.far_lo + delta)
        return LamInterval(clip(self.lo + delta), clip(self.hi + delta), clip(self.best + delta), self.bound,
                           far)

    def sigma_at(self, lam: float) -> float:
        """The bound of ``lam`` at ``lam`` (interpolated on the grid; inf without bounds)."""
        if self.bound is None:
            return math.inf
        return float(np.interp(lam, GRID, np.asarray(self.bound)))

    def relative(self, lam: float, s_ln_qp: float) -> float:
        """The relative 1-sigma of ``mu`` that the bound says were ``lam`` the truth: a quarter
        of the width in ``ln mu`` of its 2-sigma interval (:func:`mu_interval`'s)."""
        s = self.sigma_at(lam)
        if not (lam - 2.0 * s > 0.0 and math.isfinite(s)):
            return math.inf
        up = math.hypot(math.log(lam / (lam - 2.0 * s)), 2.0 * s_ln_qp)
        down = math.hypot(math.log(min(1.0, lam + 2.0 * s) / lam), 2.0 * s_ln_qp)
        return (up + down) / 4.0

    def threshold(self, s_ln_qp: float, limit: float) -> float:
        """The least ``lam`` from which, up to the estimate, the bound resolves ``mu``
        (relative 1-sigma under ``limit``); inf where it does not at the estimate."""
        lams = np.linspace(0.0, self.best, 101)[::-1]
        prev = None
        for lam in lams:
            if not self.relative(float(lam), s_ln_qp) < limit:
                return math.inf if prev is None else prev
            prev = float(lam)
        return 0.0

    def selective_lo(self, s_ln_qp: float, limit: float) -> float:
        """The published lower end of ``lam``: the profile's, widened to the selective end
        (the estimate published because it cleared :meth:`threshold`), capped at
        :data:`SELECT_CAP` sigma below the estimate (the farther of that many bounds at the
        estimate and the profile's own end, :attr:`far_lo`)."""
        x, cut = self.best, self.threshold(s_ln_qp, limit)
        if not math.isfinite(cut):
            return self.lo
        floor = max(0.0, x - SELECT_CAP * self.sigma_at(x))
        if self.far_lo is not None:
            floor = min(floor, self.far_lo)
        end = x
        for theta in np.linspace(x, floor, 61)[1:]:
            s = self.sigma_at(float(theta))
            if norm.logsf((x - theta) / s) - norm.logsf((cut - theta) / s) < math.log(TAIL):
                break
            end = float(theta)
        return min(self.lo, end)


def lam_interval(residual: Callable[[np.ndarray], np.ndarray], params: np.ndarray, jac: np.ndarray,
                 lo_bounds: np.ndarray, hi_bounds: np.ndarray) -> LamInterval | None:
    """The profile interval of ``lam`` (``params[7]``) for the noise-scaled ``residual(p)``,
    from the fit ``params`` and its Jacobian ``jac`` (columns per parameter); None when the
    other parameters' Jacobian is singular."""
    others = jac[:, :7]
    q, r = np.linalg.qr(others)
    if not np.all(np.abs(np.diag(r)) > 1e-12 * np.abs(r).max()):
        return None

    def chi2(lam: float) -> float:
        p = params.copy()
        p[7] = lam
        res = residual(p)
        for last in (False, True):
            step = -np.linalg.solve(r, q.T @ res)
            if last:  # the second step's chi2 from the linear model: no third evaluation
                rest = res + others @ step
                return float(rest @ rest)
            p[:7] = np.clip(p[:7] + step, lo_bounds[:7], hi_bounds[:7])
            res = residual(p)
        raise AssertionError("unreachable")

    values = np.array([chi2(float(x)) for x in GRID])
    fit_res = residual(params)
    least = min(float(values.min()), float(fit_res @ fit_res))
    k = int(np.argmin(values))
    best = float(GRID[k]) if values[k] <= fit_res @ fit_res else float(params[7])
    inside = values <= least + TWO_SIGMA_CHI2
    idx = np.nonzero(inside)[0]
    if idx.size == 0:  # the grid misses a narrow minimum: the fit's lam and one cell each side
        j = int(np.clip(np.searchsorted(GRID, params[7]), 1, GRID.size - 1))
        return LamInterval(float(GRID[j - 1]), float(GRID[j]), float(params[7]))

    def cross(a: float, b: float, level: float = least + TWO_SIGMA_CHI2) -> float:
        """Bisect between ``a`` (inside: ``chi2 <= level``) and ``b`` (outside) for the end."""
        for _ in range(BISECT):
            m = 0.5 * (a + b)
            if chi2(m) <= level:
                a = m
            else:
                b = m
        return 0.5 * (a + b)

    i, j = int(idx[0]), int(idx[-1])
    lo = 0.0 if i == 0 else cross(float(GRID[i]), float(GRID[i - 1]))
    hi = 1.0 if j == GRID.size - 1 else cross(float(GRID[j]), float(GRID[j + 1]))
    # the profile's SELECT_CAP-sigma lower end: the first grid point down from the 2-sigma
    # interval's whose chi2 exceeds least + SELECT_CAP^2, its crossing bisected
    far_chi2 = least + SELECT_CAP * SELECT_CAP
    k = i
    while k > 0 and values[k - 1] <= far_chi2:
        k -= 1
    far_lo = 0.0 if k == 0 else cross(float(GRID[k]), float(GRID[k - 1]), far_chi2)
    return LamInterval(lo, hi, min(max(best, lo), hi), far_lo=min(far_lo, lo))


def lam_bounds(residual: Callable[[np.ndarray], np.ndarray], params: np.ndarray, jac: np.ndarray,
               step: float = 1e-3) -> tuple[float, ...]:
    """The Cramer-Rao bound of ``lam`` at each ``lam`` of :data:`GRID`: ``lam``'s column of the
    Jacobian there (central differences) against the other parameters' at the fit."""
    q, _ = np.linalg.qr(jac[:, :7])
    out = []
    for lam in GRID:
        lo, hi = params.copy(), params.copy()
        lo[7], hi[7] = max(0.0, lam - step), min(1.0, lam + step)
        col = (residual(hi) - residual(lo)) / (hi[7] - lo[7])
        col = col - q @ (q.T @ col)
        norm2 = float(col @ col)
        out.append(1.0 / math.sqrt(norm2) if norm2 > 0 else math.inf)
    return tuple(out)


def mu_interval(lam: LamInterval, qp: float, s_ln_qp: float) -> tuple[float, float, float]:
    """``(lo, best, hi)``: the 2-sigma interval of ``mu = qp / lam`` (``hi`` inf when ``lam.lo``
    is 0) and ``mu`` where the profile is least; ``qp = |Q|/P``, ``s_ln_qp`` the 1-sigma of
    ``ln(Q/P)`` given ``lam``."""
    if not (qp > 0 and lam.hi > 0 and lam.best > 0):
        return 0.0, math.inf, math.inf
    best = qp / lam.best
    up = math.inf if lam.lo <= 0 else math.hypot(math.log(lam.best / lam.lo), 2.0 * s_ln_qp)
    down = math.hypot(math.log(lam.hi / lam.best), 2.0 * s_ln_qp)
    return best * math.exp(-down), best, (math.inf if not math.isfinite(up) else best * math.exp(up))


def symmetric(lo: float, best: float, hi: float) -> tuple[float, float]:
    """``(best, sigma)`` with ``best +/- 2 sigma`` holding the whole 2-sigma interval ``[lo,
    hi]``: sigma is half its longer arm (a skewed interval's short side is then over-bounded,
    never under-bounded)."""
    return best, 0.5 * max(hi - best, best - lo)

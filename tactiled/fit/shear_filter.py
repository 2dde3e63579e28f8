"""A contact's shear state through time: a Kalman filter on the frame-rate estimates and the
likelihood-ratio test of a slide on its innovations (docs/concepts/shear.md, "Slip").
"""

# The filter follows the parameters of :data:`tactiled.fit.shear.NAMES` but ``lam`` (bounded at
# 0 and 1, not Gaussian near slip): the contact's size ``ln r``, its force ``ln P``, the
# tangential force ``fx, fy`` and the torsion follow a constant-velocity model (their rates are
# state too: a pull is a ramp); the centre ``x0, y0`` follows the *stick hypothesis*: it stays
# where it is, up to a small random walk.  The measurement of a frame is its step estimate
# (:class:`tactiled.fit.shear.ShearStep`) with the fit's covariance, one joint update (a frame's
# parameters are correlated: on a coarse patch the centre and the tangential force pull the
# readings alike, and the force's smooth history sharpens the centre).  Process noise is in
# units of each parameter's own single-frame sigma, so the filter's memory is a number of
# frames on every array.
#
# A slide breaks the stick hypothesis in a known way: from a frame ``t0`` the centre moves
# along the tangential force by ``A g(k)`` (``k`` frames later; ``g`` a template: from rest at
# constant acceleration, ``(k + 1)^2``, or at constant speed, ``k + 1``).  Its effect on the
# filter's innovations is linear in ``A`` and computed exactly by running the filter's own
# recursion on the template (Willsky and Jones, "A generalized likelihood ratio approach to the
# detection and estimation of jumps in linear systems", IEEE TAC 21, 1976):
#
#     rho_k = H b_k - H F m_{k-1},   m_k = F m_{k-1} + K_k rho_k
#
# and the generalised likelihood ratio of ``A > 0`` is ``z = sum rho' S^-1 nu / sqrt(sum rho'
# S^-1 rho)`` (``nu`` the innovations, ``S`` their covariance), a unit normal under the
# stick hypothesis for each ``(t0, g)``; the test is the largest over the last :data:`WINDOW`
# starts and the templates.  Its false-alarm rate follows from that null distribution
# (:func:`null_exceedance`), not from the pull scenes.

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: The filtered parameters (indices into the shear fit's parameters) and those with a rate.
TRACKED = (0, 1, 2, 3, 4, 5, 6)
RATED = (0, 1, 4, 5, 6)
_N = len(TRACKED) + len(RATED)
_POS = (2, 3)  # x0, y0 in the measurement
#: A rate's random walk per frame, in units of its parameter's single-frame sigma: a pull's
#: ramp may steepen or level off by this much a frame.
RATE_WALK = 0.1
#: The centre's random walk per frame under stick, in units of its single-frame sigma.
CENTRE_WALK = 0.02
#: A new contact's rates: this many single-frame sigmas a frame (1 sigma).
RATE_START = 1.0
#: Slide starts tested: the last this many frames.
WINDOW = 16
#: The slide templates: position ``k`` frames after the start, up to scale.
TEMPLATES = {"accelerating": lambda k: (k + 1.0) ** 2, "steady": lambda k: k + 1.0}


def _matrices() -> tuple[np.ndarray, np.ndarray]:
    f = np.eye(_N)
    h = np.zeros((len(TRACKED), _N))
    h[:, : len(TRACKED)] = np.eye(len(TRACKED))
    for j, k in enumerate(RATED):
        f[TRACKED.index(k), len(TRACKED) + j] = 1.0
    return f, h


_F, _H = _matrices()


class ShearFilter:
    """The Kalman filter of one contact's shear state (see the module's comment).

    :meth:`update` takes a frame's estimate (``params`` and covariance, the shear fit's order);
    :attr:`x`, :attr:`P` are the filtered state and covariance, :attr:`nu`, :attr:`s_inv` the
    last innovation and its inverse covariance, :attr:`gain` the last Kalman gain."""

    def __init__(self) -> None:
        self.x: np.ndarray | None = None
        self.P = np.zeros((_N, _N))
        self.frames = 0
        self.nu = np.zeros(len(TRACKED))
        self.s_inv = np.zeros((len(TRACKED), len(TRACKED)))
        self.gain = np.zeros((_N, len(TRACKED)))
        #: the last innovation's chi-square (units: its own covariance), ``len(TRACKED)`` dof
        self.chi2 = 0.0
        #: the centre's random walk (single-frame sigmas a frame) in place of
        #: :data:`CENTRE_WALK`: a sliding contact's centre follows its frames
        self.centre_walk: float | None = None

    def _noise(self, sig: np.ndarray) -> np.ndarray:
        """Process noise of one frame, from the single-frame sigmas ``sig`` of the parameters."""
        q = np.zeros((_N, _N))
        for j, k in enumerate(RATED):
            i, r = TRACKED.index(k), len(TRACKED) + j
            v = (RATE_WALK * sig[k]) ** 2  # white acceleration over one frame
            q[i, i] += v / 4
            q[i, r] = q[r, i] = v / 2
            q[r, r] += v
        for k in _POS:
            q[k, k] += ((CENTRE_WALK if self.centre_walk is None else self.centre_walk) * sig[k]) ** 2
        return q

    def update(self, params: np.ndarray, cov: np.ndarray) -> bool:
        """One frame's estimate; False (nothing changed) when its covariance is not finite."""
        z = np.asarray(params, dtype=float)[list(TRACKED)]
        r = np.asarray(cov, dtype=float)[np.ix_(TRACKED, TRACKED)]
        if not (np.all(np.isfinite(z)) and np.all(np.isfinite(r))):
            return False
        sig = np.sqrt(np.clip(np.diag(r), 1e-30, None))
        sig8 = np.zeros(8)
        sig8[list(TRACKED)] = sig
        self.frames += 1
        if self.x is None:
            self.x = np.zeros(_N)
            self.x[: len(TRACKED)] = z
            self.P = np.zeros((_N, _N))
            self.P[: len(TRACKED), : len(TRACKED)] = r
            for j, k in enumerate(RATED):
                self.P[len(TRACKED) + j, len(TRACKED) + j] = (RATE_START * sig8[k]) ** 2
            self.nu = np.zeros(len(TRACKED))
            self.s_inv = np.linalg.inv(r)
            self.gain = np.zeros((_N, len(TRACKED)))
            self.gain[: len(TRACKED)] = np.eye(len(TRACKED))
            self.chi2 = 0.0
            return True
        x = _F @ self.x
        p = _F @ self.P @ _F.T + self._noise(sig8)
        s = _H @ p @ _H.T + r
        s_inv = np.linalg.inv(s)
        k = p @ _H.T @ s_inv
        nu = z - _H @ x
        self.x = x + k @ nu
        ikh = np.eye(_N) - k @ _H
        self.P = ikh @ p @ ikh.T + k @ r @ k.T  # Joseph form: stays symmetric, positive
        self.nu, self.s_inv, self.gain = nu, s_inv, k
        self.chi2 = float(nu @ s_inv @ nu)
        return True

    def value(self, k: int) -> tuple[float, float]:
        """The filtered parameter ``k`` (the shear fit's index) and its 1-sigma."""
        i = TRACKED.index(k)
        assert self.x is not None
        return float(self.x[i]), float(math.sqrt(max(0.0, self.P[i, i])))

    def tangential(self) -> tuple[float, float, float, float]:
        """The filtered ``fx, fy`` (N), ``|Q|`` and its 1-sigma."""
        assert self.x is not None
        fx, fy = self.x[4], self.x[5]
        q = math.hypot(fx, fy)
        if q <= 0:
            return fx, fy, 0.0, math.sqrt(max(0.0, self.P[4, 4]))
        g = np.array((fx / q, fy / q))
        return fx, fy, q, float(math.sqrt(max(0.0, g @ self.P[4:6, 4:6] @ g)))


class SlideTest:
    """The generalised likelihood ratio of a slide along the tangential force on a
    :class:`ShearFilter`'s innovations: :meth:`update` after each filter update gives the
    largest statistic over the last :data:`WINDOW` starts and the :data:`TEMPLATES` (sigma).

    Every (start, template) is a track: the filter's response ``m`` to a unit slide along x and
    along y (columns), and the sums ``a = sum rho' S^-1 nu``, ``b = sum rho' S^-1 rho``; all
    tracks advance together (a few batched products a frame)."""

    def __init__(self) -> None:
        self._names = list(TEMPLATES)
        self._g = [TEMPLATES[n] for n in self._names]
        cap = WINDOW * len(self._names)
        self._kind = np.tile(np.arange(len(self._names)), WINDOW)
        self._age = np.full(cap, -1)  # -1: no track in this slot yet
        self._m = np.zeros((cap, _N, 2))
        self._a = np.zeros((cap, 2))
        self._b = np.zeros((cap, 2, 2))
        self._e = np.zeros((len(TRACKED), 2))
        self._e[_POS[0], 0] = self._e[_POS[1], 1] = 1.0
        self.z = 0.0
        #: the best track's slide scale ``A`` (mm per template unit) and template name
        self.scale = 0.0
        self.template = ""

    def reset(self) -> None:
        self._age[:] = -1
        self.z, self.scale, self.template = 0.0, 0.0, ""

    def update(self, flt: ShearFilter, ux: float, uy: float) -> float:
        """Advance every track by the filter's last frame; the statistic along ``(ux, uy)``."""
        k = len(self._names)
        # the oldest starts leave, this frame's start enters (slots kept in order of start)
        for arr in (self._age, self._m, self._a, self._b):
            arr[:-k] = arr[k:].copy()
        self._age[-k:] = 0
        self._m[-k:] = 0.0
        self._a[-k:] = 0.0
        self._b[-k:] = 0.0
        live = self._age >= 0
        g = np.zeros(len(self._age))
        for j, fn in enumerate(self._g):
            sel = live & (self._kind == j)
            g[sel] = [fn(int(x)) for x in self._age[sel]]
        fm = np.matmul(_F, self._m)
        rho = g[:, None, None] * self._e - np.matmul(_H, fm)
        self._m = fm + np.matmul(flt.gain, rho)
        w = np.matmul(rho.transpose(0, 2, 1), flt.s_inv)
        self._a += np.matmul(w, flt.nu)
        self._b += np.matmul(w, rho)
        self._age[live] += 1
        u = np.array((ux, uy))
        num = self._a @ u
        den = np.einsum("i,tij,j->t", u, self._b, u)
        ok = live & (den > 0) & (num > 0)
        z = np.where(ok, num / np.sqrt(np.where(ok, den, 1.0)), 0.0)
        best = int(np.argmax(z))
        if z[best] > 0:
            self.z, self.scale = float(z[best]), float(num[best] / den[best])
            self.template = self._names[self._kind[best]]
        else:
            self.z, self.scale, self.template = 0.0, 0.0, ""
        return self.z

    def estimate(self, age: int, template: str, ux: float, uy: float) -> tuple[float, float]:
        """The slide's scale ``A`` along ``(ux, uy)`` (mm per template unit) and its 1-sigma,
        for the start ``age`` frames before the last (0: the last) and ``template``."""
        j = self._names.index(template)
        sel = np.nonzero((self._age == age + 1) & (self._kind == j))[0]
        if not sel.size:
            raise KeyError(f"no slide start {age} frames back for {template!r}")
        u = np.array((ux, uy))
        den = float(u @ self._b[sel[0]] @ u)
        return float(self._a[sel[0]] @ u) / den, 1.0 / math.sqrt(den)


def null_exceedance(zs: list[float], levels: tuple[float, ...] = (2.0, 3.0, 4.0)) -> dict[float, float]:
    """The share of frames whose statistic exceeds each level: on stick-only scenes, the
    test's null distribution, to compare with one unit normal's tail."""
    a = np.asarray(zs, dtype=float)
    return {lv: float(np.mean(a > lv)) if a.size else math.nan for lv in levels}

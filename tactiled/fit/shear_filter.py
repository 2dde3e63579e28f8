"""A contact's shear state through time: a Kalman filter on the frame-rate estimates and the
likelihood-ratio test of a slide on its innovations (docs/concepts/shear.md, "Slip").
"""

# The filter follows the parameters of :data:`tactiled.fit.shear.NAMES`: the contact's size
# ``ln r``, its force ``ln P``, the tangential force ``fx, fy``, the torsion and the friction
# mobilised ``lam = Q / (mu P)`` follow a constant-velocity model (their rates are state too: a
# pull is a ramp); the centre ``x0, y0`` follows the *stick hypothesis*: it stays where it is,
# up to a small random walk.  The measurement of a frame is its step estimate
# (:class:`tactiled.fit.shear.ShearStep`, ``lam`` before its clip to [0, 1]) with the fit's
# covariance, one joint update (a frame's parameters are correlated: on a coarse patch the
# centre, the torsion and the size pull the readings alike; their smooth history sharpens the
# centre).  A parameter the frame does not resolve (``lam`` without a tangential force) is left
# out of that frame's update.  Process noise is in units of each parameter's single-frame
# sigma, so the filter's memory is a number of frames on every array.
#
# A slide breaks the stick hypothesis in a known way: from a frame ``t0`` the centre moves
# along the tangential force by ``A g(k)`` (``k`` frames later; ``g`` a template: from rest at
# constant acceleration, ``(k + 1)^2``, or at constant speed, ``k + 1``), and the tangential
# force, at the friction's limit, stops following its ramp: it falls behind the filter's
# extrapolation by ``B (k + 1)``.  Their effect on the filter's innovations is linear in ``A``
# and ``B`` and computed exactly by running the filter's own recursion on the templates
# (Willsky and Jones, "A generalized likelihood ratio approach to the detection and estimation
# of jumps in linear systems", IEEE TAC 21, 1976):
#
#     rho_k = H b_k - H F m_{k-1},   m_k = F m_{k-1} + K_k rho_k
#
# and the generalised likelihood ratio of ``A > 0`` is ``z = sum rho' S^-1 nu / sqrt(sum rho'
# S^-1 rho)`` (``nu`` the innovations, ``S`` their covariance), a unit normal under the stick
# hypothesis for each ``(t0, g)``; likewise for ``B``.  The tests are the largest over the last
# :data:`WINDOW` starts and the templates.

from __future__ import annotations

import math

import numpy as np

#: The filtered parameters (indices into the shear fit's parameters) and those with a rate.
TRACKED = (0, 1, 2, 3, 4, 5, 6, 7)
RATED = (0, 1, 4, 5, 6, 7)
_M = len(TRACKED)
_N = _M + len(RATED)
_POS = (2, 3)  # x0, y0 in the measurement
_FORCE = (4, 5)  # fx, fy
LAM = 7
#: A rate's random walk per frame, in units of its parameter's single-frame sigma: a pull's
#: ramp may steepen or level off by this much a frame (the filter whose values are reported;
#: the slip detector's own filter has a longer memory, tactiled.fit.slip.DETECT_WALK).
RATE_WALK = 0.1
#: The centre's random walk per frame under stick, in units of its single-frame sigma.
CENTRE_WALK = 0.02
#: A new contact's rates: this many single-frame sigmas a frame (1 sigma).
RATE_START = 1.0
#: A parameter with a rate whose innovation exceeds this many of its sigma has jumped: its
#: value and rate start afresh (about 6e-7 of a steady contact's frames, a parameter).
JUMP_Z = 5.0
#: Slide starts tested: the last this many frames.
WINDOW = 16
#: The slide templates: position ``k`` frames after the start, up to scale.
TEMPLATES = {"accelerating": lambda k: (k + 1.0) ** 2, "steady": lambda k: k + 1.0}


def _matrices() -> tuple[np.ndarray, np.ndarray]:
    f = np.eye(_N)
    h = np.zeros((_M, _N))
    h[:, :_M] = np.eye(_M)
    for j, k in enumerate(RATED):
        f[TRACKED.index(k), _M + j] = 1.0
    return f, h


_F, _H = _matrices()


class ShearFilter:
    """The Kalman filter of one contact's shear state (see the module's comment); ``rate_walk``
    replaces :data:`RATE_WALK`.

    :meth:`update` takes a frame's estimate (``params`` and covariance, the shear fit's order);
    :attr:`x`, :attr:`P` are the filtered state and covariance, :attr:`nu`, :attr:`s_inv` the
    last innovation and its inverse covariance (zero rows for what the frame did not measure),
    :attr:`gain` the last Kalman gain."""

    def __init__(self, rate_walk: float = RATE_WALK) -> None:
        self.rate_walk = rate_walk
        self.x: np.ndarray | None = None
        self.P = np.zeros((_N, _N))
        self.frames = 0
        self.nu = np.zeros(_M)
        self.s_inv = np.zeros((_M, _M))
        self.gain = np.zeros((_N, _M))
        #: the last innovation's chi-square (units: its own covariance)
        self.chi2 = 0.0
        #: the centre's random walk (single-frame sigmas a frame) in place of
        #: :data:`CENTRE_WALK`: a sliding contact's centre follows its frames
        self.centre_walk: float | None = None
        self._sig = np.ones(8)
        #: frames on which a parameter jumped (:data:`JUMP_Z`)
        self.jumps = 0

    def _noise(self, sig: np.ndarray) -> np.ndarray:
        """Process noise of one frame, from the single-frame sigmas ``sig`` of the parameters."""
        q = np.zeros((_N, _N))
        for j, k in enumerate(RATED):
            i, r = TRACKED.index(k), _M + j
            v = (self.rate_walk * sig[k]) ** 2  # white acceleration over one frame
            q[i, i] += v / 4
            q[i, r] = q[r, i] = v / 2
            q[r, r] += v
        for k in _POS:
            q[k, k] += ((CENTRE_WALK if self.centre_walk is None else self.centre_walk) * sig[k]) ** 2
        return q

    def update(self, params: np.ndarray, cov: np.ndarray, lam: float | None = None) -> bool:
        """One frame's estimate (``lam`` in place of ``params[7]``: a step's unclipped one);
        False (nothing changed) when it resolves neither the centre nor the forces."""
        z = np.array(params, dtype=float)[list(TRACKED)]
        if lam is not None:
            z[LAM] = lam
        r = np.asarray(cov, dtype=float)[np.ix_(TRACKED, TRACKED)]
        d = np.diag(r)
        seen = np.isfinite(z) & np.isfinite(d) & (d > 0)
        if not seen[:LAM].all():
            return False
        idx = np.nonzero(seen)[0]
        r_s = r[np.ix_(idx, idx)]
        if not np.all(np.isfinite(r_s)):
            return False
        sig = self._sig
        sig[idx] = np.sqrt(d[idx])  # an unmeasured lam keeps its last sigma for the noise
        self.frames += 1
        if self.x is None:
            self.x = np.zeros(_N)
            self.x[:_M] = np.where(seen, z, 0.5)
            self.P = np.zeros((_N, _N))
            self.P[np.ix_(idx, idx)] = r_s
            for k in np.nonzero(~seen)[0]:
                self.P[k, k] = 1.0  # lam unseen: anywhere in [0, 1]
            for j, k in enumerate(RATED):
                self.P[_M + j, _M + j] = (RATE_START * sig[k]) ** 2
            self.nu = np.zeros(_M)
            self.s_inv = np.zeros((_M, _M))
            self.gain = np.zeros((_N, _M))
            self.chi2 = 0.0
            return True
        h = _H[idx]
        x = _F @ self.x
        p = _F @ self.P @ _F.T + self._noise(sig)
        s = h @ p @ h.T + r_s
        # a parameter with a rate that jumps (a force giving way, a grip changing) starts
        # afresh from this frame: its value and rate lose their history
        nu = z[idx] - h @ x
        jumped = [j for j, k in enumerate(idx) if k in RATED and abs(nu[j]) > JUMP_Z * math.sqrt(s[j, j])]
        if jumped:
            for j in jumped:
                k = int(idx[j])
                r = _M + RATED.index(k)
                p[k, :] = p[:, k] = 0.0
                p[r, :] = p[:, r] = 0.0
                p[k, k] = nu[j] ** 2 + (RATE_START * sig[k]) ** 2
                p[r, r] = (RATE_START * sig[k]) ** 2
            self.jumps += 1
            s = h @ p @ h.T + r_s
        s_inv = np.linalg.inv(s)
        k = p @ h.T @ s_inv
        self.x = x + k @ nu
        ikh = np.eye(_N) - k @ h
        self.P = ikh @ p @ ikh.T + k @ r_s @ k.T  # Joseph form: stays symmetric, positive
        self.nu = np.zeros(_M)
        self.nu[idx] = nu
        self.s_inv = np.zeros((_M, _M))
        self.s_inv[np.ix_(idx, idx)] = s_inv
        self.gain = np.zeros((_N, _M))
        self.gain[:, idx] = k
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


    def shear(self) -> dict[str, tuple[float, float]]:
        """The filtered ``fx_n``, ``fy_n`` (N), ``torque_nmm`` (N mm) and ``q_over_p`` (``|Q| /
        P``), each with its 1-sigma: the keys of the ``shear`` table."""
        assert self.x is not None
        fx, fy, q, s_q = self.tangential()
        force = math.exp(self.x[1])
        g = np.zeros(_N)
        if q > 0:
            g[4], g[5] = fx / (q * force), fy / (q * force)
        g[1] = -q / force
        s_qp = float(math.sqrt(max(0.0, g @ self.P @ g)))
        return {"fx_n": self.value(4), "fy_n": self.value(5), "torque_nmm": self.value(6),
                "q_over_p": (q / force, s_qp)}


class SlideTest:
    """The generalised likelihood ratios of a slide along the tangential force, and of that
    force levelling off, on a :class:`ShearFilter`'s innovations.  :meth:`update` after each
    filter update sets :attr:`z` (the slide's statistic, the largest over the last
    :data:`WINDOW` starts and the :data:`TEMPLATES`, sigma) and :attr:`joint` (the largest
    slide statistic among the starts whose levelling-off exceeds ``plateau_z``).

    Every (start, template) is a track: the filter's response ``m`` to a unit slide along x and
    y and to a unit levelling-off of ``fx`` and ``fy`` (four columns), and the sums ``a = sum
    rho' S^-1 nu``, ``b = sum rho' S^-1 rho``; all tracks advance together (a few batched
    products a frame)."""

    def __init__(self, plateau_z: float = math.inf) -> None:
        self.plateau_z = plateau_z
        self._names = list(TEMPLATES)
        self._g = [TEMPLATES[n] for n in self._names]
        cap = WINDOW * len(self._names)
        self._kind = np.tile(np.arange(len(self._names)), WINDOW)
        self._age = np.full(cap, -1)  # -1: no track in this slot yet
        self._m = np.zeros((cap, _N, 4))
        self._a = np.zeros((cap, 4))
        self._b = np.zeros((cap, 4, 4))
        self.z = 0.0
        self.joint = 0.0
        self.slides = np.zeros(len(self._age))
        self.tracks = np.zeros(len(self._age))
        self.levels = np.zeros(len(self._age))
        self.ages = np.zeros(len(self._age), dtype=int)
        #: the best track's slide scale ``A`` (mm per template unit) and template name
        self.scale = 0.0
        self.template = ""

    def reset(self) -> None:
        self._age[:] = -1
        self.z, self.joint, self.scale, self.template = 0.0, 0.0, 0.0, ""
        self.slides[:] = self.tracks[:] = self.levels[:] = 0.0
        self.ages[:] = 0

    def update(self, flt: ShearFilter, ux: float, uy: float) -> float:
        """Advance every track by the filter's last frame; the slide statistic along ``(ux, uy)``."""
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
        e = np.zeros((len(g), _M, 4))
        e[:, _POS[0], 0] = e[:, _POS[1], 1] = g
        e[:, _FORCE[0], 2] = e[:, _FORCE[1], 3] = -(np.maximum(self._age, 0) + 1.0)
        fm = np.matmul(_F, self._m)
        rho = e - np.matmul(_H, fm)
        self._m = fm + np.matmul(flt.gain, rho)
        w = np.matmul(rho.transpose(0, 2, 1), flt.s_inv)
        self._a += np.matmul(w, flt.nu)
        self._b += np.matmul(w, rho)
        self._age[live] += 1
        za, num, den = self._along(self._a[:, :2], self._b[:, :2, :2], ux, uy, live)
        zb, _, _ = self._along(self._a[:, 2:], self._b[:, 2:, 2:], ux, uy, live)
        best = int(np.argmax(za))
        if za[best] > 0:
            self.z, self.scale = float(za[best]), float(num[best] / den[best])
            self.template = self._names[self._kind[best]]
        else:
            self.z, self.scale, self.template = 0.0, 0.0, ""
        both = za[zb > self.plateau_z]
        self.joint = float(both.max()) if both.size else 0.0
        #: per track: the slide's statistic, the slide's and the levelling-off's together
        #: (sigma) and the frames since its start (0: no track)
        self.slides = za
        #: per track: the levelling-off's statistic (sigma)
        self.levels = zb
        self.tracks = self._combined(ux, uy, live, za)
        self.ages = np.maximum(self._age, 0)
        return self.z

    def track(self, age: int, template: str) -> int:
        """The index (into :attr:`slides`, :attr:`tracks`) of the track started ``age - 1``
        frames before the last with ``template``."""
        sel = np.nonzero((self.ages == age) & (self._kind == self._names.index(template)))[0]
        if not sel.size:
            raise KeyError(f"no slide track of age {age} for {template!r}")
        return int(sel[0])

    def _combined(self, ux: float, uy: float, live: np.ndarray, za: np.ndarray) -> np.ndarray:
        """Per track, the likelihood ratio of the slide and the levelling-off together (both
        scales >= 0), in sigma: ``sqrt`` of the chi-bar-square statistic."""
        u = np.array((ux, uy))
        a_s, a_l = self._a[:, :2] @ u, self._a[:, 2:] @ u
        m_ss = np.einsum("i,tij,j->t", u, self._b[:, :2, :2], u)
        m_ll = np.einsum("i,tij,j->t", u, self._b[:, 2:, 2:], u)
        m_sl = np.einsum("i,tij,j->t", u, self._b[:, :2, 2:], u)
        det = m_ss * m_ll - m_sl * m_sl
        ok = live & (m_ss > 0) & (m_ll > 0) & (det > 0)
        det = np.where(ok, det, 1.0)
        xs, xl = (m_ll * a_s - m_sl * a_l) / det, (m_ss * a_l - m_sl * a_s) / det
        both = ok & (xs > 0) & (xl > 0)
        z2 = np.where(both, a_s * xs + a_l * xl, 0.0)
        zl = np.where(ok & (a_l > 0), a_l / np.sqrt(np.where(ok, m_ll, 1.0)), 0.0)
        z2 = np.maximum(z2, np.maximum(za, 0.0) ** 2)
        z2 = np.maximum(z2, np.where(both, 0.0, zl ** 2))
        return np.where(ok, np.sqrt(z2), 0.0)

    @staticmethod
    def _along(a: np.ndarray, b: np.ndarray, ux: float, uy: float, live: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        u = np.array((ux, uy))
        num = a @ u
        den = np.einsum("i,tij,j->t", u, b, u)
        ok = live & (den > 0) & (num > 0)
        return np.where(ok, num / np.sqrt(np.where(ok, den, 1.0)), 0.0), num, den

    def estimate(self, age: int, template: str, ux: float, uy: float) -> tuple[float, float]:
        """The slide's scale ``A`` along ``(ux, uy)`` (mm per template unit) and its 1-sigma,
        for the start ``age`` frames before the last (0: the last) and ``template``."""
        j = self._names.index(template)
        sel = np.nonzero((self._age == age + 1) & (self._kind == j))[0]
        if not sel.size:
            raise KeyError(f"no slide start {age} frames back for {template!r}")
        u = np.array((ux, uy))
        den = float(u @ self._b[sel[0], :2, :2] @ u)
        return float(self._a[sel[0], :2] @ u) / den, 1.0 / math.sqrt(den)

"""Fit a 3-axis frame: the normal contact and its tangential force, torsion and friction state,
with Cramer-Rao bounds (docs/concepts/shear.md).
"""

# The model is :class:`~tactiled.physics.threeaxis.ThreeAxisModel` (a sphere's Hertz pressure, a
# Cattaneo-Mindlin tangential traction, Lubkin's torsion; the half-space's displacement at the
# taxels' depth).  Parameters ``(ln r_mm, ln force, x0, y0, fx, fy, torque, lam)``, ``lam = Q /
# (mu P)`` in [0, 1]; residuals are every live taxel's three readings in a window around the
# contact, each divided by its axis's noise.  A linear solve at full stick starts the search
# (the readings are linear in P, fx, fy and the torsion at a given contact size), then a
# bounded Levenberg-Marquardt (scipy's trust region reflective) finishes it.  The covariance is
# ``(J^T J)^-1`` at the estimate (central differences).
#
# From ``lam`` follow the friction coefficient ``mu = |Q| / (lam P)`` and the margin to slip
# ``1 - lam``, their intervals from the profile likelihood of ``lam`` (tactiled/fit/
# shear_profile.py: the likelihood is often one-sided there, and a linearised sigma misleads),
# reported only where full stick is excluded at 2 sigma and the Cramer-Rao bound at the
# estimate says a relative sigma of ``mu`` under :data:`MU_RESOLVED` (the interval then widened
# for that selection): a stick zone of radius ``c = a (1 - lam)^(1/3)`` changes the readings
# by little when ``Q`` is small or the taxels lie deep under a small contact, and then ``mu`` is
# ``None`` with the reason.

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from tactiled.fit.shear_profile import LamInterval, lam_bounds, lam_interval, mu_interval, symmetric
from tactiled.physics.threeaxis import ShearContact, ThreeAxisModel
from tactiled.physics.traction import Traction
from tactiled.sensors.description import SensorDescription

NAMES = ("ln_r", "ln_force", "x0", "y0", "fx", "fy", "torque", "lam")
#: ``mu`` is reported when its relative 1-sigma bound at the estimate (a quarter of the width
#: in ``ln mu`` of the 2-sigma interval that lam's Cramer-Rao bound there says) is below this.
MU_RESOLVED = 0.2
#: ... and the observed 2-sigma interval's width, in the same units, is below this: where
#: ``lam``'s likelihood is far from its bound's Gaussian (a frame at the bound 1 whose profile
#: runs down to full stick), the bound at the estimate does not say the interval.
MU_SEEN = 0.4
#: Side of the fit window (taxels) at least: the displacement field reaches further than
#: the strain's, so large arrays are fitted on this window around the peak.
MIN_WINDOW = 8
#: Central-difference steps of the covariance's Jacobian, per parameter.
_STEPS = np.array((1e-3, 1e-4, 1e-4, 1e-4, 1e-5, 1e-5, 1e-4, 1e-3))
_LO = np.array((math.log(1.0), math.log(1e-3), -np.inf, -np.inf, -np.inf, -np.inf, -np.inf, 0.0))
_HI = np.array((math.log(500.0), math.log(100.0), np.inf, np.inf, np.inf, np.inf, np.inf, 1.0))


@dataclass
class ShearEstimate:
    """One frame's estimate: ``values`` and 1-sigma ``sigma`` per name of :data:`NAMES`, the
    covariance, the reduced chi-square ``rms`` and the reasons for what is withheld."""

    params: np.ndarray
    cov: np.ndarray
    rms: float
    converged: bool
    reasons: dict[str, str] = field(default_factory=dict)
    #: The fit's window (row-major taxel indices) and the Jacobian of its noise-scaled
    #: residuals at ``params`` (None for an estimate that is not a fit's):
    #: what :class:`ShearStep` follows the frames from.
    window: np.ndarray | None = None
    jac: np.ndarray | None = None
    #: The 2-sigma profile-likelihood interval of ``lam`` (tactiled/fit/shear_profile.py), from
    #: which ``mu`` and ``slip_margin`` follow; None where ``lam`` is unobservable.
    lam_profile: LamInterval | None = None
    #: A step's ``lam`` before its clip to [0, 1] (the linear estimate, Gaussian about the
    #: truth near slip, what a filter of ``lam`` takes); None for a fit's.
    lam_free: float | None = None

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    def contact(self) -> ShearContact:
        p = self.params
        return ShearContact(math.exp(p[0]), math.exp(p[1]), p[2], p[3], p[4], p[5], p[6], p[7])

    def _grad_sigma(self, grad: np.ndarray) -> float:
        nz = np.nonzero(grad)[0]
        g = grad[nz]
        return float(math.sqrt(max(0.0, g @ self.cov[np.ix_(nz, nz)] @ g)))

    def tangential(self) -> tuple[float, float]:
        """``|Q|`` (N) and its 1-sigma."""
        fx, fy = self.params[4], self.params[5]
        q = math.hypot(fx, fy)
        g = np.zeros(8)
        if q > 0:
            g[4], g[5] = fx / q, fy / q
        return q, self._grad_sigma(g) if q > 0 else self.sigma[4]

    def q_over_p(self) -> tuple[float, float]:
        """``|Q| / P`` (the friction mobilised) and its 1-sigma."""
        _, lnp, _, _, fx, fy, _, _ = self.params
        q, force = math.hypot(fx, fy), math.exp(lnp)
        g = np.zeros(8)
        if q > 0:
            g[4], g[5] = fx / (q * force), fy / (q * force)
        g[1] = -q / force
        return q / force, self._grad_sigma(g)

    def mu(self) -> tuple[float | None, float | None, str | None]:
        """``mu = |Q| / (lam P)`` and its sigma, or ``(None, None, reason)``: from the profile
        interval of ``lam`` (:func:`~tactiled.fit.shear_profile.mu_interval`), the value where
        the profile is least and half the 2-sigma interval's longer arm."""
        band = self.mu_band()
        if isinstance(band, str):
            return None, None, band
        best, sigma = symmetric(*band)
        return best, sigma, None

    def mu_band(self) -> tuple[float, float, float] | str:
        """``(lo, best, hi)``, the 2-sigma interval of ``mu`` and its most likely value, or the
        reason it is withheld."""
        prof = self.lam_profile
        if prof is None or not math.isfinite(self.sigma[7]):
            return "the stick zone is not resolved (lam = Q/(mu P) unobservable: no tangential force)"
        qp, _ = self.q_over_p()
        s_ln = self._ln_qp_given_lam()
        if prof.lo <= 0.0:
            return (f"the stick zone is not resolved: Q/(mu P) = {prof.best:.2f}, within 2 sigma of 0 "
                    f"(2-sigma interval {prof.lo:.2f}..{prof.hi:.2f}): mu is unbounded above")
        rel = prof.relative(prof.best, s_ln)  # the bound at the estimate, not the interval's width
        if not rel < MU_RESOLVED:
            return (f"the stick zone is not resolved: Q/(mu P) = {prof.best:.2f} (2-sigma interval "
                    f"{prof.lo:.2f}..{prof.hi:.2f}; mu's bound there {rel:.0%} of it, over {MU_RESOLVED:.0%})")
        seen_lo, _, seen_hi = mu_interval(prof, qp, s_ln)
        seen = math.log(seen_hi / seen_lo) / 4.0 if seen_lo > 0 else math.inf
        if not seen < MU_SEEN:
            return (f"the stick zone is not resolved: Q/(mu P) = {prof.best:.2f} (2-sigma interval "
                    f"{prof.lo:.2f}..{prof.hi:.2f}, far wider than its bound there says: mu's bound "
                    f"from it {seen:.0%}, over {MU_SEEN:.0%})")
        chosen = LamInterval(prof.selective_lo(s_ln, MU_RESOLVED), prof.hi, prof.best)
        lo, best, hi = mu_interval(chosen, qp, s_ln)
        if not math.isfinite(hi):
            return (f"the stick zone is not resolved: Q/(mu P) = {prof.best:.2f}, at the edge of "
                    f"resolution (2-sigma interval {chosen.lo:.2f}..{prof.hi:.2f}): mu is unbounded above")
        return lo, best, hi

    def slip_margin(self) -> tuple[float | None, float | None]:
        """``1 - lam`` where the profile is least and half the longer arm of its 2-sigma
        interval, where ``mu`` is resolved; else ``(None, None)``."""
        if isinstance(self.mu_band(), str):
            return None, None
        prof = self.lam_profile
        lo = prof.selective_lo(self._ln_qp_given_lam(), MU_RESOLVED)
        return symmetric(1.0 - prof.hi, 1.0 - prof.best, 1.0 - lo)

    def _ln_qp_given_lam(self) -> float:
        """1-sigma of ``ln(|Q|/P)`` with ``lam`` held (the conditional Gaussian bound)."""
        _, lnp, _, _, fx, fy, _, _ = self.params
        q = math.hypot(fx, fy)
        if q <= 0:
            return math.inf
        g = np.zeros(8)
        g[4], g[5], g[1] = fx / (q * q), fy / (q * q), -1.0
        c = self.cov
        var = g @ c @ g
        cross = g @ c[:, 7]
        if c[7, 7] > 0 and math.isfinite(c[7, 7]):
            var -= cross * cross / c[7, 7]
        return math.sqrt(max(var, 0.0))

    def state(self) -> str:
        """``stick`` (no slip annulus resolved: ``lam`` within 2 sigma of 0), ``slip`` (the
        stick zone gone: within 2 sigma of 1, and resolved from 0), else ``partial``."""
        lam, s = self.params[7], self.sigma[7]
        if not math.isfinite(s) or lam - 2 * s <= 0.0:
            return "stick"
        return "slip" if lam + 2 * s >= 1.0 else "partial"

    def to_json(self) -> dict[str, Any]:
        return _finite(self._json())

    def _json(self) -> dict[str, Any]:
        """The ``contact``, ``shear`` and ``slip`` tables of ``tactiled fit`` on a 3-axis file."""
        p, s = self.params, self.sigma
        r, force = math.exp(p[0]), math.exp(p[1])
        qp, s_qp = self.q_over_p()
        mu, s_mu, why = self.mu()
        margin, s_margin = self.slip_margin()
        reasons = dict(self.reasons)
        if why:
            reasons["mu"] = reasons["slip_margin"] = why
        return {
            "contact": {"x_mm": p[2], "y_mm": p[3], "force_n": force, "r1_mm": r,
                        "std": {"x_mm": s[2], "y_mm": s[3], "force_n": force * s[1], "r1_mm": r * s[0]}},
            "shear": {"fx_n": p[4], "fy_n": p[5], "torque_nmm": p[6], "q_over_p": qp,
                      "mu": mu, "slip_margin": margin,
                      "std": {"fx_n": s[4], "fy_n": s[5], "torque_nmm": s[6], "q_over_p": s_qp,
                              "mu": s_mu, "slip_margin": s_margin}},
            "slip": {"state": self.state(), "lam": p[7], "lam_std": s[7]},
            "rms_over_noise": self.rms, "converged": self.converged, "reasons": reasons,
        }


def _finite(doc: Any) -> Any:
    """``doc`` with every non-finite number as None (JSON has no inf), floats as Python's."""
    if isinstance(doc, dict):
        return {k: _finite(v) for k, v in doc.items()}
    if isinstance(doc, list):
        return [_finite(v) for v in doc]
    if isinstance(doc, (float, np.floating)):
        return float(doc) if math.isfinite(doc) else None
    return doc


class ShearFitter:
    """Fits frames ``(rows, cols, 3)`` of one 3-axis description."""

    def __init__(self, desc: SensorDescription, tol: float = 1e-6) -> None:
        # 1e-6: the quadrature's error is then some 1e-4 of the noise of a 3-axis taxel
        self.model = ThreeAxisModel(desc, tol)
        self.desc = desc
        self.side = (min(desc.rows, max(desc.window, MIN_WINDOW)), min(desc.cols, max(desc.window, MIN_WINDOW)))

    # -- the window and the residuals ---------------------------------------------------
    def _window(self, frame: np.ndarray) -> np.ndarray:
        """Row-major indices of the live taxels of the window around the normal peak."""
        d = self.desc
        z = np.where(self.model.live.reshape(d.rows, d.cols), frame[..., 2], -np.inf)
        m, n = np.unravel_index(int(np.argmax(z)), z.shape)
        r0 = min(max(0, m - self.side[0] // 2), d.rows - self.side[0])
        c0 = min(max(0, n - self.side[1] // 2), d.cols - self.side[1])
        rr, cc = np.meshgrid(np.arange(r0, r0 + self.side[0]), np.arange(c0, c0 + self.side[1]), indexing="ij")
        idx = (rr * d.cols + cc).ravel()
        return idx[self.model.live[idx]]

    def _predict(self, p: np.ndarray, idx: np.ndarray) -> np.ndarray:
        c = ShearContact(math.exp(p[0]), math.exp(p[1]), p[2], p[3], p[4], p[5], p[6], float(p[7]))
        return self.model.readings(c, self.model.px[idx], self.model.py[idx]) / self.model.noise

    def _jacobian(self, p: np.ndarray, idx: np.ndarray) -> np.ndarray:
        cols = []
        for k in range(8):
            lo, hi = p.copy(), p.copy()
            h = _STEPS[k]
            lo[k] = max(_LO[k], p[k] - h)
            hi[k] = min(_HI[k], p[k] + h)
            cols.append(((self._predict(hi, idx) - self._predict(lo, idx)) / (hi[k] - lo[k])).ravel())
        return np.stack(cols, axis=1)

    # -- the start ----------------------------------------------------------------------
    def start(self, frame: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """A full-stick start: the centre from the normal readings, then ``(P, fx, fy, T)`` by
        linear least squares at a 10 mm sphere (twice, the contact's size following ``P``)."""
        m = self.model
        z = frame.reshape(-1, 3)[idx, 2]
        w = np.clip(z, 0.0, None) ** 2
        if w.sum() <= 0:
            w = np.ones_like(z)
        x0 = float(np.sum(w * m.px[idx]) / w.sum())
        y0 = float(np.sum(w * m.py[idx]) / w.sum())
        data = (frame.reshape(-1, 3)[idx] / m.noise).ravel()
        force, radius = 1.0, 10.0
        coef = np.zeros(4)
        for _ in range(2):
            ell = m.ellipse(radius, force)
            basis = []
            for load in (Traction(1.0), Traction(1.0, fx=1.0), Traction(1.0, fy=1.0), Traction(1.0, torque=1.0)):
                basis.append(m.model.displacement(ell, load, x0, y0, m.px[idx], m.py[idx]) * m.gain / m.noise)
            normal = basis[0]
            cols = [normal.ravel()] + [(b - normal).ravel() for b in basis[1:]]
            coef, *_ = np.linalg.lstsq(np.stack(cols, axis=1), data, rcond=None)
            force = float(min(max(coef[0], 1e-3), 100.0))
        return np.array((math.log(radius), math.log(force), x0, y0, coef[1], coef[2], coef[3], 0.5))

    # -- the fit --------------------------------------------------------------------------
    def fit(self, frame: np.ndarray, start: np.ndarray | None = None) -> ShearEstimate:
        """Fit one frame ``(rows, cols, 3)`` of readings; ``start`` (a previous estimate's
        ``params``) replaces the linear start."""
        frame = np.asarray(frame, dtype=float)
        if frame.shape != self.model.shape:
            raise ValueError(f"a frame of {self.desc.name!r} is {self.model.shape}, got {frame.shape}")
        idx = self._window(frame)
        data = (frame.reshape(-1, 3)[idx] / self.model.noise).ravel()
        p0 = self.start(frame, idx) if start is None else np.clip(start, _LO, _HI)
        p0[7] = min(max(p0[7], 0.02), 0.98)

        def residual(p: np.ndarray) -> np.ndarray:
            return self._predict(p, idx).ravel() - data

        # tolerances: a relative change of 1e-6 in chi-square is far below what the noise decides
        res = least_squares(residual, p0, bounds=(_LO, _HI), method="trf", x_scale="jac",
                            diff_step=1e-6, max_nfev=200, ftol=1e-6, xtol=1e-6)
        p = res.x
        jac = self._jacobian(p, idx)
        reasons: dict[str, str] = {}
        cov = np.full((8, 8), np.inf)
        lam_col = np.linalg.norm(jac[:, 7])
        keep = list(range(8)) if lam_col > 1e-9 * np.linalg.norm(jac) else list(range(7))
        if len(keep) < 8:
            reasons["lam"] = "unobservable: no tangential force"
        fisher = jac[:, keep].T @ jac[:, keep]
        try:
            sub = np.linalg.inv(fisher)
            cov[np.ix_(keep, keep)] = sub
            if len(keep) < 8:
                cov[7, :7] = cov[:7, 7] = 0.0
        except np.linalg.LinAlgError:
            reasons["shear"] = "the information matrix is singular"
        dof = max(1, data.size - 8)
        rms = float(math.sqrt(2.0 * res.cost / dof))
        prof = None
        if len(keep) == 8 and "shear" not in reasons:
            prof = lam_interval(residual, p, jac, _LO, _HI)
            if prof is not None:
                prof = replace(prof.widened(float(p[7]), float(math.sqrt(max(cov[7, 7], 0.0)))),
                               bound=lam_bounds(residual, p, jac))
        return ShearEstimate(p, cov, rms, bool(res.success), reasons, idx, jac, prof)

    def step(self, est: ShearEstimate) -> ShearStep:
        """Frame-rate estimates from the fit ``est``: :class:`ShearStep`."""
        return ShearStep(self, est)


class ShearStep:
    """Estimates at frame rate between fits: one Gauss-Newton step from a fit.

    The fit (:meth:`ShearFitter.fit`, some 10 ms or more) runs on some frames; every frame in
    between is estimated by linearising the model at the last fit: ``p = p_fit + C J^T r``
    with ``r`` the frame's noise-scaled residual from the fit's prediction, ``J`` the fit's
    Jacobian and ``C = (J^T J)^-1`` its covariance (which the step keeps).  A matrix-vector
    product over the fit's window: no model evaluation per frame.  Exact for the parameters
    the readings are linear in (the tangential force and torsion at a given contact size);
    first order in the others (the centre, the size, ``lam``), which move little between two
    fits; ``rms`` is the residual after the step (the linear model's), in units of the noise.
    """

    def __init__(self, fitter: ShearFitter, est: ShearEstimate) -> None:
        if est.window is None or est.jac is None:
            raise ValueError("a shear step starts from a fit's estimate (its window and Jacobian)")
        self.base = est
        self.window = est.window
        self._noise = fitter.model.noise
        self._pred = fitter._predict(est.params, est.window).ravel()
        self._keep = np.nonzero(np.isfinite(np.diag(est.cov)))[0]
        jac = est.jac[:, self._keep]
        self._jac = jac
        self._gain = est.cov[np.ix_(self._keep, self._keep)] @ jac.T
        self._dof = max(1, self._pred.size - len(self._keep))

    def __call__(self, frame: np.ndarray) -> ShearEstimate:
        """The estimate of one frame ``(rows, cols, 3)`` of readings (``lam`` clipped to [0, 1])."""
        data = (np.asarray(frame, dtype=float).reshape(-1, 3)[self.window] / self._noise).ravel()
        r = data - self._pred
        delta = self._gain @ r
        free = self.base.params.copy()
        free[self._keep] += delta
        p = np.clip(free, _LO, _HI)
        rest = r - self._jac @ delta
        rms = float(math.sqrt(float(rest @ rest) / self._dof))
        prof = self.base.lam_profile
        if prof is not None:
            prof = prof.shifted(float(p[7] - self.base.params[7]))
        return ShearEstimate(p, self.base.cov, rms, self.base.converged, dict(self.base.reasons),
                             lam_profile=prof, lam_free=float(free[7]))

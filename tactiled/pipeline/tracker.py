"""The temporal tracker: every contact frame measured, a held contact sharpened, a moving one
followed without lag.

A fit describes one frame.  Between fits the tracker measures each new frame through the last
fit's linearisation (:class:`tactiled.fit.linearize.Linearization`): one least-squares step,
``z = p + G (f - s(p))``, with the single-frame noise covariance ``R``.  Those measurements feed
a Kalman filter per parameter of the model (the fitter's own parameters: ln R, psi, ln F, x0,
y0, ...):

* the **moving** parameters (orientation, force, position) follow a constant-velocity model
  whose white-acceleration noise gives the filter a memory of about ``memory_s`` seconds; their
  rates are the reported velocities;
* the **curvatures** (ln R, beta: a property of the object) are held constant, with a memory
  of ``hold_s``: on a held contact they average every frame, so their uncertainty shrinks like
  1/sqrt(frames) until the model-error floor (:attr:`Linearization.systematic`, added to every
  reported variance, never averaged) dominates.

A change is caught three ways, each the moment it happens:

* the frame leaves the linear range (the part of ``f - s(p)`` that ``J dz`` cannot explain is
  beyond the noise: chi^2 over ``n - k`` degrees of freedom past ``LINEAR_Z`` sigmas): the frame
  needs a fit of its own (:meth:`Tracker.step` says ``"refit"``);
* a parameter jumps (its innovation beyond ``RESET_SIGMA`` of its predicted spread): the filter
  restarts from this frame (``"reset"``: a step in force, a jump in place);
* a parameter drifts away from the model (an exponentially weighted mean of its normalised
  innovations beyond ``DRIFT_LIMIT`` of its spread: an acceleration): its rate's uncertainty is
  widened so the filter catches up within tens of frames.

The filters of different parameters run independently (a frame's measurements are correlated,
``R`` is not diagonal): on a held contact, whose ``R`` is the same every frame, that loses
nothing (the joint estimate of a constant is the plain mean as well); the reported covariance
puts the single-frame correlation back.  No I/O and no physics here: the main process runs
it for every frame, in tens of microseconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from tactiled.fit.params import (
    MAX_ANGLE_SIGMA,
    MOVING,
    PARAMS,
    RADIUS_LIMITS,
    TOO_LIGHT,
    UNOBSERVABLE_RELATIVE_SIGMA,
    VALUE_KEYS,
    report,
)

#: The linearity test's threshold: the chi^2 (dof n - k) quantile a frame of the contact
#: exceeds once in ~3.5 million (a normal deviate of 5, through Wilson-Hilferty).
LINEAR_Z = 5.0


def chi2_limit(dof: int, z: float = LINEAR_Z) -> float:
    """The chi^2 quantile of ``dof`` degrees of freedom at the normal deviate ``z``
    (Wilson-Hilferty: 5 % above the exact one at 5 degrees of freedom, 1 % at 30)."""
    a = 2.0 / (9.0 * dof)
    return dof * (1.0 - a + z * math.sqrt(a)) ** 3
#: A parameter's innovation beyond this many sigmas restarts the filter (a step, a jump).
RESET_SIGMA = 5.0
#: Weight of the newest normalised innovation in the drift detector's running mean.
DRIFT_ALPHA = 1.0 / 32.0
#: The drift detector's alarm, in standard deviations of its running mean.
DRIFT_LIMIT = 5.0
#: The mean residual of this many frames measured through one linearisation is tested for
#: what averaging cannot remove (see :meth:`Tracker.step`).
MEAN_RESIDUAL_FRAMES = 16
#: ... at this normal deviate of its chi^2 (Wilson-Hilferty), over the last ~this many
#: seconds (an exponential memory: what the contact did a while ago says little of now).
MEAN_RESIDUAL_Z = 3.0
MEAN_RESIDUAL_S = 1.0

#: Velocities are reported from this many frames after a (re)start of the filter.
MIN_RATE_FRAMES = 3
#: A gap in the device clock longer than this (s), or time running backwards (the device
#: restarted), restarts the filter: the motion model says nothing over it.
MAX_GAP_S = 0.25
#: The state moved from the linearisation point by this many single-frame sigmas (in any
#: parameter), or its own spread shrank below 1/``SHARPEN`` of the point's: time to
#: linearise again, where the contact now is.
RELINEARIZE_SIGMA = 1.0
SHARPEN = 2.0

#: Reasons of the fitter's for a value it withheld that the tracker judges again on the frames
#: it has gathered (a radius too uncertain in one light frame may be sharp in a hundred).
_SOFT = (TOO_LIGHT, "poorly determined", "orientation not observable")

#: Estimate keys the tracker adds: rates (their 1-sigma in ``std`` under the same key).
RATE_KEYS = ("vx_mm_s", "vy_mm_s", "angle_rate_deg_s", "force_rate_n_s")
_RATE_OF = {"x0": "vx_mm_s", "y0": "vy_mm_s", "psi": "angle_rate_deg_s",
            "ln_f": "force_rate_n_s"}


@dataclass
class _Param:
    """One parameter's filter: value ``x``, rate ``v`` (moving parameters), covariance."""

    moving: bool
    x: float = 0.0
    v: float = 0.0
    pxx: float = 0.0
    pxv: float = 0.0
    pvv: float = 0.0
    drift: float = 0.0


class Tracker:
    """Tracks one sensor's contact through the frames between fits (see the module's doc).

    ``memory_s``: how far back the moving parameters' filter looks (s); ``hold_s``: the same
    for the curvatures.  Times are the device's clock in seconds.
    """

    def __init__(self, memory_s: float = 0.25, hold_s: float = 30.0,
                 withhold_relative_sigma: float | None = None) -> None:
        if not (memory_s > 0 and hold_s > 0):
            raise ValueError(f"memory_s and hold_s must be positive, got {memory_s}, {hold_s}")
        self.memory_s = float(memory_s)
        self.hold_s = float(hold_s)
        #: a radius whose sigma exceeds this fraction of it is withheld, as the fitter does
        self.withhold = withhold_relative_sigma
        #: counters: filter restarts on a change; frames it could not use
        self.resets = 0
        self.skipped = 0
        self.clear()

    # -- state ----------------------------------------------------------------------------------

    def clear(self) -> None:
        """Forget the contact (it ended, a tare, new settings)."""
        self.lin = None  # the Linearization frames are measured through
        self.excess = 1.0
        self._esum = self._ecount = None
        self.model: str | None = None
        self.names: tuple[str, ...] = ()
        self.params: list[_Param] | None = None
        self.t: float | None = None
        self.n = 0  # frames the estimate rests on since the filter (re)started
        #: how far the mean of the frames departs from the model beyond their noise: the
        #: reported variances are multiplied by it (1: not at all)
        self.excess = 1.0
        self._esum: np.ndarray | None = None  # per tactel: the residuals' sum, their count
        self._ecount: np.ndarray | None = None
        self._corr: np.ndarray | None = None
        self._lin_sd: np.ndarray | None = None  # the state's spread when linearised

    @property
    def active(self) -> bool:
        """True when frames can be measured (a linearisation is held)."""
        return self.lin is not None

    @property
    def started(self) -> bool:
        """True when the filter holds an estimate."""
        return self.params is not None

    def adopt(self, lin) -> None:
        """Measure the following frames through ``lin`` (a new fit's, or a relinearisation's).
        A different model than the filter's restarts it at the next frame."""
        if self.model is not None and lin.model != self.model:
            self.params, self.t, self.n = None, None, 0
        names = PARAMS[lin.model]
        if self.params is not None and "psi" in names:
            # psi is periodic by pi: take the linearisation's psi next to the state's
            i = names.index("psi")
            turns = round((self.params[i].x - float(lin.p[i])) / math.pi)
            if turns:
                p = lin.p.copy()
                p[i] += turns * math.pi
                lin = replace(lin, p=p)
        self.lin, self.model, self.names = lin, lin.model, names
        if self._esum is None:
            cells = int(lin.index.max()) + 1 if lin.index.size else 0
            size = max(cells, 64)
            self._esum, self._ecount = np.zeros(size), np.zeros(size)
        self._log = np.array([n.startswith("ln_") for n in names])
        self._limit = chi2_limit(max(lin.dof, 1))
        sd = np.sqrt(np.diag(lin.cov))
        self._corr = lin.cov / np.outer(sd, sd)
        self._lin_sd = (None if self.params is None
                        else np.array([math.sqrt(q.pxx) for q in self.params]))

    def wants_linearization(self) -> tuple[str, np.ndarray] | None:
        """``(model, p)``: where to linearise again, when the state has moved from the
        linearisation point, or has sharpened well past it; None while the point serves."""
        lin, params = self.lin, self.params
        if lin is None or params is None:
            return None
        x = np.array([q.x for q in params])
        sd1 = np.sqrt(np.diag(lin.cov))
        moved = bool(np.any(np.abs(x - lin.p) > RELINEARIZE_SIGMA * sd1))
        sd = np.array([math.sqrt(q.pxx) for q in params])
        sharper = self._lin_sd is None or bool(np.any(sd * SHARPEN < self._lin_sd))
        return (self.model, x) if (moved or sharper) else None

    def predicted(self, t: float) -> tuple[str, tuple[float, ...]] | None:
        """``(model, params)`` of the contact predicted at ``t``: a warm start for a fit."""
        if self.params is None or self.t is None:
            return None
        dt = t - self.t
        dt = dt if 0.0 < dt < MAX_GAP_S else 0.0
        return self.model, tuple(q.x + q.v * dt for q in self.params)

    # -- a frame --------------------------------------------------------------------------------

    def step(self, strain: np.ndarray, t: float, fitted: bool = False) -> str:
        """Measure one zeroed frame (flattened row-major, strain) taken at device time ``t``
        (s) and update the estimate: ``"tracked"``, ``"reset"`` (a change: the filter restarted
        from this frame) or ``"refit"`` (it needs a fit of its own: outside the linear range,
        or a jump the linearisation would measure poorly; the estimate is unchanged).
        ``fitted``: the frame is the one the current linearisation was fitted on (it is
        measured exactly there, and a jump restarts the filter)."""
        lin = self.lin
        if fitted:
            z = lin.p.copy()  # the fit itself: the frame's own measurement
        else:
            d = strain[lin.index] - lin.strain
            dp = lin.gain @ d
            e = d - lin.jacobian @ dp
            if lin.dof > 0 and float((e * e) @ lin.weight) > self._limit:
                return "refit"
            # a log radius or force moved by more than a factor e from the point: no linear
            # range reaches that far (a release: force to zero), whatever the residual says
            if not (np.isfinite(dp).all() and (np.abs(dp[self._log]) < 1.0).all()):
                return "refit"
            z = lin.p + dp
            self._mean_residual(e, t - self.t if self.t is not None else 0.0)
        r = np.diag(lin.cov)
        if self.params is None or self.t is None:
            self._start(z, r, t)
            return "tracked"
        dt = t - self.t
        if not 0.0 < dt < MAX_GAP_S:
            self._start(z, r, t)
            self.resets += 1
            return "reset"
        self._predict(dt)
        innov = z - np.array([q.x for q in self.params])
        spread = np.sqrt(np.array([q.pxx for q in self.params]) + r)
        u = innov / spread
        jumped = np.abs(u) > RESET_SIGMA
        if jumped.any():
            if not fitted:
                return "refit"
            # a change: the moving parameters start again from this frame; a curvature only
            # if it changed itself (a force step does not change the object)
            self._start(z, r, t, keep=[not (q.moving or j) for q, j in zip(self.params, jumped)])
            self.resets += 1
            return "reset"
        self._update(innov, r, u, dt)
        self.t = t
        self.n += 1
        return "tracked"

    def _mean_residual(self, e: np.ndarray, dt: float) -> None:
        """Model error that no single frame shows can dominate an average of thousands (a
        tactel's zero drifting under a held contact, the rubber's hysteresis behind a rolling
        one, a finger that departs from its model): the residual of the frames' mean, whose
        noise is sigma / sqrt(m), reveals it.  Summed per tactel over the contact; when its
        chi^2 is beyond the noise's, the reported variances are scaled by chi^2 / dof (the
        Birge ratio), so the uncertainty stops shrinking where the data stop agreeing."""
        idx = self.lin.index
        if idx.size and int(idx.max()) >= self._esum.size:
            return
        if 0.0 < dt < MAX_GAP_S:
            fade = math.exp(-dt / MEAN_RESIDUAL_S)
            self._esum *= fade
            self._ecount *= fade
        self._esum[idx] += e
        self._ecount[idx] += 1.0
        used = self._ecount >= MEAN_RESIDUAL_FRAMES
        n = int(used.sum())
        dof = n - self.lin.p.size
        if dof < 1:
            return
        c = self._ecount[used]
        chi2 = float(np.sum(self._esum[used] ** 2 / c)) / (self.lin.sigma * self.lin.sigma)
        self.excess = chi2 / dof if chi2 > chi2_limit(dof, MEAN_RESIDUAL_Z) else 1.0

    def skip(self) -> None:
        """A frame the tracker must not use (non-finite tactels): counted, nothing learnt."""
        self.skipped += 1

    def _start(self, z: np.ndarray, r: np.ndarray, t: float,
               keep: list[bool] | None = None) -> None:
        """(Re)start the filter at measurement ``z``; ``keep`` marks parameters whose filter
        goes on (updated with this frame)."""
        old = self.params
        self.params = [_Param(moving=n in MOVING, x=float(z[i]), pxx=float(r[i]))
                       for i, n in enumerate(self.names)]
        if old is not None and keep is not None:
            for i, k in enumerate(keep):
                if k:
                    q = old[i]
                    s = q.pxx + float(r[i])
                    gain = q.pxx / s
                    q.x += gain * (float(z[i]) - q.x)
                    q.pxx *= 1.0 - gain
                    self.params[i] = q
        self.t, self.n = t, 1
        # The rate is unknown: a prior wide enough for any contact the scenes move (it is
        # learnt from the next frames; velocities are reported after MIN_RATE_FRAMES).
        for q, ri in zip(self.params, r):
            if q.moving:
                q.pvv = 1e6 * float(ri)
        self._lin_sd = np.sqrt(np.array([q.pxx for q in self.params]))

    def _predict(self, dt: float) -> None:
        lin_r = np.diag(self.lin.cov)
        tau4 = self.memory_s ** 4
        hold2 = self.hold_s ** 2
        for q, ri in zip(self.params, lin_r):
            if q.moving:
                # white acceleration of density 36 R dt / tau^4: an alpha-beta filter with a
                # window of about tau s (R: one frame's noise variance, dt: the frame period)
                acc = 36.0 * float(ri) * dt / tau4
                q.x += q.v * dt
                q.pxx += 2.0 * dt * q.pxv + dt * dt * q.pvv + acc * dt ** 3 / 3.0
                q.pxv += dt * q.pvv + acc * dt * dt / 2.0
                q.pvv += acc * dt
            else:
                q.pxx += float(ri) * dt * dt / hold2  # a random walk with a memory of hold_s

    def _update(self, innov: np.ndarray, r: np.ndarray, u: np.ndarray, dt: float) -> None:
        drift_sd = math.sqrt(DRIFT_ALPHA / (2.0 - DRIFT_ALPHA))
        for i, q in enumerate(self.params):
            s = q.pxx + float(r[i])
            k1, k2 = q.pxx / s, q.pxv / s
            nu = float(innov[i])
            q.x += k1 * nu
            q.v += k2 * nu
            q.pvv -= k2 * q.pxv
            q.pxx *= 1.0 - k1
            q.pxv *= 1.0 - k1
            q.drift += DRIFT_ALPHA * (float(u[i]) - q.drift)
            if abs(q.drift) > DRIFT_LIMIT * drift_sd:
                # the parameter runs away from the model (it accelerates, or the object
                # changes slowly): widen what is uncertain so the filter catches up
                window = dt / DRIFT_ALPHA
                if q.moving:
                    q.pvv = max(q.pvv, (abs(q.drift) * math.sqrt(s) / window) ** 2 * 16.0)
                else:
                    q.pxx = max(q.pxx, s)
                q.drift = 0.0

    # -- the estimate ---------------------------------------------------------------------------

    def estimate(self, base: dict[str, Any]) -> dict[str, Any]:
        """The estimate's fit dict: ``base`` (the last fit's ``FitResult.to_json_dict()``, which
        gives the keys the tracker does not estimate: label, rms, ellipse, ...) with the
        tracked values, their 1-sigma, ``frames_used`` and the rates."""
        params = self.params
        assert params is not None and self.model is not None
        x = np.array([q.x for q in params])
        values, grad = report(self.model, x)
        sd = np.sqrt(np.array([q.pxx for q in params]) * self.excess)
        cov = self._corr * np.outer(sd, sd) + self.lin.systematic
        var = np.einsum("ij,jk,ik->i", grad, cov, grad)
        out = dict(base)
        reasons = dict(base.get("reasons") or {})
        std: dict[str, float | None] = {}
        base_std = base.get("std") or {}
        for i, key in enumerate(VALUE_KEYS):
            v = values.get(key)
            soft = base.get(key) is not None or str(reasons.get(key, "")).startswith(_SOFT)
            if not soft or v is None or not math.isfinite(var[i]):
                # not in this model, or withheld by the fit for what frames do not change (a
                # line contact's radius): stays as the fit said
                out[key] = base.get(key)
                std[key] = base_std.get(key)
                continue
            sd = math.sqrt(var[i])
            withheld = self._withheld(key, v, sd)
            if withheld:
                out[key], std[key] = None, None
                reasons[key] = withheld
                continue
            out[key], std[key] = v, sd
            if str(reasons.get(key, "")).startswith(_SOFT):
                del reasons[key]
        rates, rate_sd = self._rates(values, reasons)
        out.update(rates)
        std.update(rate_sd)
        out["std"] = std
        out["reasons"] = reasons
        out["frames_used"] = self.n
        return out

    def _withheld(self, key: str, v: float, sd: float) -> str | None:
        """Why ``key`` (value ``v``, 1-sigma ``sd`` over the frames used) is withheld, by the
        fitter's rules (tactiled.fit.fitter.Fitter._unobservable); None to report it."""
        if key == "angle_deg":
            if sd > MAX_ANGLE_SIGMA:
                return "orientation not observable: sigma above 45 deg"
            return None
        if key not in ("r1_mm", "r2_mm", "force_n") or v <= 0.0:
            return None
        rel = sd / v
        radius = key != "force_n"
        limit = self.withhold if radius and self.withhold is not None else math.inf
        if (rel > UNOBSERVABLE_RELATIVE_SIGMA or rel > limit
                or (radius and not RADIUS_LIMITS[0] <= v <= RADIUS_LIMITS[1])):
            what = "radius" if radius else "force"
            return (f"{TOO_LIGHT if radius else 'not observable'}: the sigma of the {what} over "
                    f"{self.n} frame(s) is {100 * rel:.0f} % of it")
        return None

    def _rates(self, values: dict[str, float | None],
               reasons: dict[str, str]) -> tuple[dict[str, float | None], dict[str, float | None]]:
        rates: dict[str, float | None] = dict.fromkeys(RATE_KEYS)
        sds: dict[str, float | None] = dict.fromkeys(RATE_KEYS)
        few = self.n < MIN_RATE_FRAMES
        for name, q in zip(self.names, self.params):
            key = _RATE_OF.get(name)
            if key is None:
                continue
            if few:
                reasons[key] = (f"the contact changed {self.n} frame(s) ago: too few frames for "
                                "a rate")
                continue
            scale = 1.0
            if name == "psi":
                scale = 180.0 / math.pi
            elif name == "ln_f":
                scale = values["force_n"] or 0.0
            rates[key] = q.v * scale
            sds[key] = math.sqrt(max(q.pvv, 0.0)) * abs(scale)
        if self.model == "sphere":
            reasons["angle_rate_deg_s"] = "undefined: sphere model"
        return rates, sds


def untracked(fit: dict[str, Any], frames_used: int, reason: str) -> dict[str, Any]:
    """``fit`` (a fit's JSON dict) with the tracker's keys for an estimate it did not make
    (no contact, tracking off): ``frames_used`` as given, the rates null with ``reason``."""
    out = dict(fit)
    out.update(dict.fromkeys(RATE_KEYS))
    out["frames_used"] = frames_used
    out["std"] = {**(fit.get("std") or {}), **dict.fromkeys(RATE_KEYS)}
    out["reasons"] = {**(fit.get("reasons") or {}), **{k: reason for k in RATE_KEYS}}
    return out

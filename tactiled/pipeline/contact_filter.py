"""The temporal tracker: every contact frame measured, a held contact sharpened, a moving one
followed without lag.
"""

# A fit describes one frame.  Between fits the tracker measures each new frame through the last
# fit's linearisation (:class:`tactiled.fit.linearize.Linearization`): one least-squares step,
# ``z = p + G (f - s(p))``, with the single-frame noise covariance ``R``.  Those measurements feed
# a Kalman filter per parameter of the model (the fitter's own parameters: ln R, psi, ln F, x0,
# y0, ...):
#
# * the **moving** parameters (orientation, force, position) follow a constant-velocity model
#   whose white-acceleration noise gives the filter a memory of about ``memory_s`` seconds; their
#   rates are the reported velocities;
# * the **curvatures** (ln R, beta: a property of the object) are held constant, with a memory
#   of ``hold_s``: on a held contact they average every frame, so their uncertainty shrinks like
#   1/sqrt(frames) until the model-error floor (:attr:`Linearization.systematic`, added to every
#   reported variance, never averaged) dominates.
#
# A change is caught three ways, each the moment it happens:
#
# * the frame leaves the linear range (the part of ``f - s(p)`` that ``J dz`` cannot explain is
#   beyond the noise: chi^2 over ``n - k`` degrees of freedom past ``LINEAR_Z`` sigmas): the frame
#   needs a fit of its own (:meth:`Tracker.step` says ``"refit"``);
# * a parameter jumps (its innovation beyond ``RESET_SIGMA`` of its predicted spread): the filter
#   restarts from this frame (``"reset"``: a step in force, a jump in place);
# * a parameter drifts away from the model (an exponentially weighted mean of its normalised
#   innovations beyond ``DRIFT_LIMIT`` of its spread: an acceleration): its rate's uncertainty is
#   widened so the filter catches up within tens of frames.
#
# The filters of different parameters run independently (a frame's measurements are correlated,
# ``R`` is not diagonal): on a held contact, whose ``R`` is the same every frame, that loses
# nothing (the joint estimate of a constant is the plain mean as well); the reported covariance
# puts the single-frame correlation back.  No I/O and no physics here: the main process runs
# it for every frame, in tens of microseconds.

from __future__ import annotations

import functools
import math
from dataclasses import replace
from collections.abc import Sequence
from typing import Any

import numpy as np

from tactiled.sensors.model import Geometry
from tactiled.fit.profile import FLAT, FLAT_ACROSS, TEST_RELATIVE_SIGMA
from tactiled.fit.verdict import sigma_reason
from tactiled.fit.params import (MAX_ANGLE_SIGMA, MOVING, PARAMS, RADIUS_LIMITS, TOO_LIGHT,
                                 UNOBSERVABLE_RELATIVE_SIGMA, VALUE_KEYS, radius_tied_force,
                                 wrap_deg)
from tactiled.pipeline.fit_sigmas import (beyond_tested, fit_widening, kept_by_limits,
                                          radius_force_variance, runaway_radius)
from tactiled.pipeline.kernels import (
    C_HIGH,
    C_LIN_SD,
    C_LOG,
    C_LOW,
    C_MOVING,
    C_POINT,
    C_R,
    DRIFT,
    MODEL_CODES,
    PVV,
    PXX,
    STEP_REFIT,
    STEP_RESTART,
    V,
    X,
    TrackStep,
    fold_residuals,
    linearization_constants,
    moved_from_point,
)

_I_FORCE, _I_R1 = VALUE_KEYS.index("force_n"), VALUE_KEYS.index("r1_mm")
_I_ANGLE = VALUE_KEYS.index("angle_deg")
#: the value (its index in VALUE_KEYS) each moving parameter's lag widens (kernels.lag_variance)
_LAG_KEY = dict(x0=VALUE_KEYS.index("x_mm"), y0=VALUE_KEYS.index("y_mm"), psi=VALUE_KEYS.index(
    "angle_deg"), ln_f=_I_FORCE)
#: the running mean's weight of the newest frame's innovation excess: about the last two
#: frames, as quick as a lag appears (a release at 30 frames/s lasts 15)
LAG_WEIGHT = 0.5
#: ... counted where it is beyond this many of its noise's sigmas (5 % of a held contact's
#: frames: it still averages down; at 3 a release on the 12x32 mat was caught only when the
#: estimate lagged by twice the mean innovation, its force published 4-6 sigmas high)
LAG_SIGNIFICANT = 2.0
#: the state a linearisation is adopted with before the filter has started (no column)
_NO_STATE = np.empty((DRIFT + 1, 0))

#: The linearity test's threshold: the chi^2 (dof n - k) quantile a frame of the contact
#: exceeds once in ~3.5 million (a normal deviate of 5, through Wilson-Hilferty).
LINEAR_Z = 5.0

#: A parameter's innovation beyond this many sigmas restarts the filter (a step, a jump).
RESET_SIGMA = 5.0
#: Weight of the newest normalised innovation in the drift detector's running mean.
DRIFT_ALPHA = 1.0 / 32.0
#: The drift detector's alarm, in standard deviations of its running mean.
DRIFT_LIMIT = 5.0
#: ... which is this, in units of the normalised innovation (the running mean's spread is
#: sqrt(alpha / (2 - alpha)) of one innovation's)
_DRIFT_ALARM = DRIFT_LIMIT * math.sqrt(DRIFT_ALPHA / (2.0 - DRIFT_ALPHA))
#: A moving parameter's running mean of normalised innovations beyond this many of its own
#: sigmas says the filter lags the motion (it departs from constant velocity: a press's
#: log-force decelerates) and its estimate trails the truth by about that mean times the
#: innovations' spread, an error its own variance does not hold: that lag is added to its
#: reported variance.
LAG_Z = 2.0
#: The frames' mean residual is tested for what averaging cannot remove (see
#: :meth:`Tracker._fold`) on the tactels that this many frames have measured.
MEAN_RESIDUAL_FRAMES = 16
#: ... at this normal deviate of its chi^2 (Wilson-Hilferty), over the last ~this many
#: seconds (an exponential memory: what the contact did a while ago says little of now).
MEAN_RESIDUAL_Z = 3.0
MEAN_RESIDUAL_S = 1.0
#: Frames whose residuals are buffered before they are folded into the sums and tested.
MEAN_RESIDUAL_FOLD = 8


#: Velocities are reported from this many frames after a (re)start of the filter.
MIN_RATE_FRAMES = 3
#: A gap in the device clock longer than this (s), or time running backwards (the device
#: restarted), restarts the filter: the motion model says nothing over it.
MAX_GAP_S = 0.25
#: The state moved from the linearisation point by this many single-frame sigmas (in any
#: parameter), or its own spread shrank below 1/``SHARPEN`` of the point's: time to
#: linearise again, where the contact now is.
RELINEARIZE_SIGMA = 1.0
#: A force measured more than a factor e^3 from the linearisation point needs a fit, however
#: uncertain one frame leaves it (the radius has no such cap: it is only held in its box).
MAX_LOG_FORCE_STEP = 3.0
SHARPEN = 2.0

#: Reasons of the fitter's for a value it withheld that the tracker judges again on the frames
#: it has gathered (a radius too uncertain in one light frame may be sharp in a hundred).
_SOFT = (TOO_LIGHT, "poorly determined", "orientation not observable")

#: Estimate keys the tracker adds: rates (their 1-sigma in ``std`` under the same key).
RATE_KEYS = ("vx_mm_s", "vy_mm_s", "angle_rate_deg_s", "force_rate_n_s")
_NO_RATES = dict.fromkeys(RATE_KEYS)
_RATE_OF = {"x0": "vx_mm_s", "y0": "vy_mm_s", "psi": "angle_rate_deg_s",
            "ln_f": "force_rate_n_s"}


#: A fit (or a worker's linearisation) starts from the tracker's state only within what a
#: finger carries: a force of MIN_FORCE_N..MAX_FORCE_N (N), a centre at most OFF_ARRAY_MM
#: outside the array, a radius within the fitter's own search bounds (half and twice
#: ``RADIUS_LIMITS``).  A filter on a light edge can run its radius off to ln R of -50 and
#: beyond (unobservable there, so nothing holds it); an evaluation at such a point, or at a
#: contact larger than the array, outlasts a worker's deadline.
MIN_FORCE_N, MAX_FORCE_N = 1e-4, 100.0
OFF_ARRAY_MM = 5.0
LN_R_BOUNDS = (math.log(0.5 * RADIUS_LIMITS[0]), math.log(2.0 * RADIUS_LIMITS[1]))
LN_F_BOUNDS = (math.log(MIN_FORCE_N), math.log(MAX_FORCE_N))
#: why a tracked position is withheld (Tracker._withheld)
_OFF_ARRAY = f"position not observable: sigma above {OFF_ARRAY_MM:g} mm"


def reasonable_bounds(names: tuple[str, ...], geometry) -> list[tuple[int, float, float]]:
    """``(index, low, high)`` for each parameter of ``names`` (a model's internal parameters)
    that a finger bounds on ``geometry`` (a ``config.Geometry``): a radius, the force, the
    centre; the others (an angle, a shape ratio) are free."""
    x_hi = (geometry.rows - 1) * geometry.dx + OFF_ARRAY_MM
    y_hi = (geometry.cols - 1) * geometry.dy + OFF_ARRAY_MM
    box = {"ln_r": LN_R_BOUNDS, "ln_ra": LN_R_BOUNDS, "ln_f": LN_F_BOUNDS,
           "x0": (-OFF_ARRAY_MM, x_hi), "y0": (-OFF_ARRAY_MM, y_hi)}
    return [(i, *box[n]) for i, n in enumerate(names) if n in box]


@functools.lru_cache(maxsize=64)
def _vector_bounds(size: int, geometry) -> tuple[tuple[int, float, float], ...]:
    """:func:`reasonable_bounds` of a model's internal vector of ``size`` parameters
    (``(ln_r.., .., ln_f, x0, y0)``)."""
    names = ("ln_r",) + ("",) * (size - 4) + ("ln_f", "x0", "y0")
    return tuple(reasonable_bounds(names, geometry))


def within_reason(p: Sequence[float], geometry) -> list[float]:
    """A model's internal vector ``p`` (``(ln_r.., .., ln_f, x0, y0)``) with its radius, force
    and centre clipped to what a finger carries on ``geometry`` (a ``config.Geometry``)."""
    q = [float(v) for v in p]
    for i, lo, hi in _vector_bounds(len(q), geometry):
        q[i] = min(max(q[i], lo), hi)
    return q


@functools.lru_cache(maxsize=64)
def _model_constants(names: tuple[str, ...], geometry) -> tuple[
        list[bool], int, list[tuple[int, str, str]], np.ndarray]:
    """What the tracker reads of a model's parameters ``names`` on ``geometry``, the same at
    every linearisation: which move, the force's index, which carry a rate (index, estimate
    key, name), and the kernels' constants table with the rows that depend on the model only
    filled in (which move, which are logarithms, the box each is kept in).  (Read only.)"""
    moving = [n in MOVING for n in names]
    table = np.full((C_LIN_SD + 1, len(names)), math.nan)
    table[C_MOVING] = moving
    table[C_LOG] = [n.startswith("ln_") for n in names]
    table[C_LOW], table[C_HIGH] = -math.inf, math.inf
    for i, lo, hi in reasonable_bounds(names, geometry):
        table[C_LOW, i], table[C_HIGH, i] = lo, hi
    table.flags.writeable = False
    return (moving, names.index("ln_f"),
            [(i, _RATE_OF[n], n) for i, n in enumerate(names) if n in _RATE_OF], table)


@functools.lru_cache(maxsize=1024)
def chi2_limit(dof: int, z: float = LINEAR_Z) -> float:
    """The chi^2 quantile of ``dof`` degrees of freedom at the normal deviate ``z``
    (Wilson-Hilferty: 5 % above the exact one at 5 degrees of freedom, 1 % at 30)."""
    a = 2.0 / (9.0 * dof)
    return dof * (1.0 - a + z * math.sqrt(a)) ** 3


class Tracker:
    """Tracks one sensor's contact through the frames between fits (see the module's doc).

    ``memory_s``: how far back the moving parameters' filter looks (s); ``hold_s``: the same
    for the curvatures.  Times are the device's clock in seconds.  The per-parameter state is
    one small array (``_s``, rows ``kernels.X .. DRIFT``) that the compiled
    :class:`~tactiled.pipeline.kernels.TrackStep` measures, filters and tests in one call
    per frame, and reports in one more; the rules that withhold a value stay here, in Python.
    """

    def __init__(self, memory_s: float = 0.1, hold_s: float = 30.0,
                 withhold_relative_sigma: float | None = None, geometry=None) -> None:
        if not (memory_s > 0 and hold_s > 0):
            raise ValueError(f"memory_s and hold_s must be positive, got {memory_s}, {hold_s}")
        #: the array (a ``config.Geometry``; default the paper's): where a centre can be
        self.geometry = geometry if geometry is not None else Geometry()
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
        self.model: str | None = None
        self.names: tuple[str, ...] = ()
        self.t: float | None = None
        self.n = 0  # frames the estimate rests on since the filter (re)started
        # per parameter (a column): value, rate, covariance [[pxx, pxv], [pxv, pvv]], drift
        # detector; None until the filter starts
        self._s: np.ndarray | None = None
        #: how far the mean of the frames departs from the model beyond their noise: the
        #: reported variances are multiplied by it (1: not at all)
        self.excess = 1.0
        self._esum: np.ndarray | None = None  # per tactel: the residuals' sum, their count
        self._ecount: np.ndarray | None = None
        self._ebuf: np.ndarray | None = None  # residuals not yet folded into the sums
        self._eframes, self._edt = 0, 0.0
        self._judged_memo: tuple[dict[str, Any], float | None, Any] | None = None
        self._share_memo: tuple[Any, float] | None = None
        self._constants: tuple[tuple[str, ...], Any] = ((), None)
        self._beta_floor: tuple[int, float] | None = None
        #: per value key (VALUE_KEYS order): the fit's sigma over its linearised single-frame
        #: sigma at its point, where over 1 (its profile test widened it): the tracked sigma is
        #: multiplied by it (:func:`fit_widening`)
        self._widen: list[float] = [1.0] * len(VALUE_KEYS)
        #: the frame's kernel on the arrays above (kernels.TrackStep; None: built at next use)
        self._k: Any = None

    @property
    def x(self) -> np.ndarray | None:
        """The filter's parameters (the model's internal vector), None before it starts."""
        return None if self._s is None else self._s[X]

    @property
    def active(self) -> bool:
        """True when frames can be measured (a linearisation is held)."""
        return self.lin is not None

    @property
    def started(self) -> bool:
        """True when the filter holds an estimate."""
        return self._s is not None

    def adopt(self, lin, zero_var: float = 0.0, fit: dict[str, Any] | None = None) -> None:
        """Measure the following frames through ``lin`` (a new fit's, or a relinearisation's).
        A different model than the filter's restarts it at the next frame.  ``zero_var``: the
        variance (strain^2) of each tactel's zero (``Zeroer.baseline_var``), an error every
        frame of the contact shares: systematic, ``zero_var / sigma^2`` times ``lin.cov``.
        ``fit``: the fit's JSON dict when ``lin`` is that fit's (its sigmas over the
        linearised ones at its point are kept: :func:`fit_widening`); None for a
        relinearisation (what the last fit's gave is kept)."""
        if fit is not None:
            self._widen = fit_widening(fit, lin)
        if self.model is not None and lin.model != self.model:
            self._s, self.t, self.n = None, None, 0
        names = PARAMS[lin.model]
        if self._s is not None and "beta" in names and _swapped(self._s[X], lin.p, names):
            # the state's psi names the other principal axis than the linearisation's
            self._s, self.t, self.n = None, None, 0
        if self._s is not None and "psi" in names:
            # psi is periodic by pi: take the linearisation's psi next to the state's
            i = names.index("psi")
            turns = round((float(self._s[X, i]) - float(lin.p[i])) / math.pi)
            if turns:
                p = lin.p.copy()
                p[i] += turns * math.pi
                lin = replace(lin, p=p)
        self._fold()
        self.lin, self.model, self.names = lin, lin.model, names
        if self._esum is None:
            size = max(int(lin.index.max()) + 1 if lin.index.size else 0,
                       self.geometry.rows * self.geometry.cols)
            self._esum, self._ecount = np.zeros(size), np.zeros(size)
        self._ebuf = np.zeros(lin.index.size)
        # the linearisation as the measuring kernel takes it (contiguous, its dtypes)
        self._at = np.ascontiguousarray(lin.strain, dtype=np.float64)
        self._index = np.ascontiguousarray(lin.index, dtype=np.intp)
        self._gain = np.ascontiguousarray(lin.gain, dtype=np.float64)
        self._jacobian = np.ascontiguousarray(lin.jacobian, dtype=np.float64)
        self._weight = np.ascontiguousarray(lin.weight, dtype=np.float64)
        if self._constants[0] is not names:  # (a relinearisation keeps the model)
            self._constants = (names, _model_constants(names, self.geometry))
        self._moving, self._ln_f, self._rate_of, table = self._constants[1]
        self._limit = chi2_limit(max(lin.dof, 1))
        # The single frame's covariance as variances and correlations, and the systematic
        # part, for the estimate's delta method (kernels.estimate_numbers)
        self._c, self._corr, self._sys, self._has_sys = linearization_constants(
            table, np.asarray(lin.cov, dtype=np.float64),
            np.ascontiguousarray(lin.p, dtype=np.float64),
            _NO_STATE if self._s is None else self._s,
            np.asarray(lin.systematic, dtype=np.float64), zero_var / (lin.sigma * lin.sigma))
        self._r = self._c[C_R].tolist()
        self._model_code = MODEL_CODES[lin.model]
        self._beta_floor = None
        if "beta" in names:
            # a measurement keeps an elongated contact's axes (see _swapped); near a circle
            # the two sides are the same ellipse, and a box there would bias it
            i = names.index("beta")
            if abs(float(lin.p[i])) <= 0.5:
                self._c[C_LOW, i], self._c[C_HIGH, i] = -1.0, 1.0
            elif abs(float(lin.p[i])) >= 2.0:
                self._beta_floor = (i, math.copysign(1.0, float(lin.p[i])))
        self._k = None

    def wants_linearization(self) -> tuple[str, np.ndarray] | None:
        """``(model, p)``: where to linearise again, when the state has moved from the
        linearisation point, or has sharpened well past it; None while the point serves."""
        if self.lin is None or self._s is None:
            return None
        if moved_from_point(self._s, self._c, RELINEARIZE_SIGMA, SHARPEN):
            return self.model, self._s[X].copy()
        return None

    def predicted(self, t: float) -> tuple[str, tuple[float, ...]] | None:
        """``(model, params)`` of the contact predicted at ``t``: a warm start for a fit."""
        if self._s is None or self.t is None:
            return None
        dt = t - self.t
        dt = dt if 0.0 < dt < MAX_GAP_S else 0.0
        x, v = self._s[X].tolist(), self._s[V].tolist()
        return self.model, tuple(xi + vi * dt for xi, vi in zip(x, v))

    # -- a frame --------------------------------------------------------------------------------

    def step(self, strain: np.ndarray, t: float, fitted: bool = False,
             measured: bool = False) -> str:
        """Measure one zeroed frame (flattened row-major, strain) taken at device time ``t``
        (s) and update the estimate: ``"tracked"``, ``"reset"`` (a change: the filter restarted
        from this frame) or ``"refit"`` (it needs a fit of its own: outside the linear range,
        or a jump the linearisation would measure poorly; the estimate is unchanged).
        ``fitted``: the frame is the one the current linearisation was fitted on (it is
        measured exactly there, and a jump restarts the filter).  ``measured``: the caller
        has measured the frame already (:meth:`measure_at`).  One call into the kernels
        (:class:`~tactiled.pipeline.kernels.TrackStep`): the measurement, the residual, the
        filters and the lag; the filter's (re)start and the residuals' test stay here."""
        k = self._kernel()
        if fitted:
            k.z[:] = self._c[C_POINT]  # the fit itself: the frame's own measurement
        elif not (measured or k.measure(np.ascontiguousarray(strain, dtype=np.float64),
                                        self._at)):
            return "refit"
        started = self._s is not None and self.t is not None
        last = self.t
        code = k.advance(t - last if started else math.nan, fitted)
        if not fitted:
            self._eframes += 1
            self._edt += 0.0 if last is None else max(t - last, 0.0)
            if self._eframes >= MEAN_RESIDUAL_FOLD:
                self._fold()
        if code == 0:
            self.t = t
            self.n += 1
            return "tracked"
        if code == STEP_REFIT:  # the estimate is unchanged (its fit will be measured from there)
            return "refit"
        z = k.z.tolist()
        if code == STEP_RESTART:  # not started, or a gap in the clock: the motion model says nothing
            self._start(z, t)
            if not started:
                return "tracked"
        else:
            # a change: the moving parameters start again from this frame; a curvature only
            # if it changed itself (a force step does not change the object)
            self._start(z, t, keep=[not (m or code >> i & 1) for i, m in enumerate(self._moving)])
        self.resets += 1
        return "reset"

    def measure(self, strain: np.ndarray) -> bool:
        """One frame measured through the linearisation (:meth:`measure_at`)."""
        frame = np.ascontiguousarray(strain, dtype=np.float64)
        return self.measure_at(frame, self._at)

    def measure_at(self, frame: np.ndarray, at: np.ndarray) -> bool:
        """``frame`` (flat, float64) measured on the window less ``at`` (the linearisation's
        strains there, and whatever else the caller takes out): True with the measurement
        held for :meth:`step` (``measured=True``), False when the frame needs a fit of its
        own (outside the linear range, or a step no linearisation reaches).  Changes nothing
        the estimate reads."""
        # The kernel's tests of the step (kernels.measure_point): a log radius or force moved
        # by more than a factor e from the point: no linear range reaches that far (a
        # release: force to zero), whatever the residual says.  Unless the step is within
        # the noise (RESET_SIGMA single-frame sigmas): a value one frame barely determines
        # (the radius of a light contact, of one at the noise), which the filter weighs as
        # such; a fit would give as uncertain a value.  The force, though, never by more
        # than a factor e^MAX_LOG_FORCE_STEP: a contact letting go (its fit may find nothing
        # left to place), or a filter gone astray (a point so far from the contact that its
        # linearisation measures nothing, and every step passes as noise: seen as 577 N off
        # the array on a held 1.2 N contact).  And a value the frame does not bound is kept
        # within what a finger carries (within_reason's box): a radius, force or centre no
        # frame determines (a contact at the noise, letting go) would otherwise random-walk,
        # to exp() overflow and centres a kilometre off the array (seen on release residuals).
        return self._kernel().measure(frame, at)

    def _kernel(self) -> Any:
        """The frame's kernel on the tracker's current arrays (built when a linearisation is
        adopted or the filter (re)starts, the next frame)."""
        k = self._k
        if k is None:
            size = self._c.shape[1]
            started = self._s is not None
            beta_i, beta_sign = self._beta_floor if self._beta_floor is not None else (-1, 1.0)
            self._k = k = TrackStep(
                self._s if started else np.zeros((DRIFT + 1, size)),
                self._lag if started else np.zeros((2, size)), self._c, np.zeros(size),
                self._ebuf, self._index, self._at, self._gain, self._jacobian, self._weight,
                self._corr, self._sys,
                np.array([_LAG_KEY.get(n, -1) for n in self.names], dtype=np.intp),
                (self._limit, self._ln_f, RESET_SIGMA, MAX_LOG_FORCE_STEP, beta_i, beta_sign,
                 self.memory_s, self.hold_s, DRIFT_ALPHA, _DRIFT_ALARM, LAG_WEIGHT,
                 LAG_SIGNIFICANT, MAX_GAP_S, self._model_code, float(self._has_sys),
                 LAG_Z * LAG_Z * DRIFT_ALPHA / (2.0 - DRIFT_ALPHA)))
        return k

    def stepped(self, t: float) -> None:
        """What :meth:`step` keeps of a frame at ``t`` (s) the tracked run stepped, tracked."""
        self._eframes += 1
        self._edt += max(t - self.t, 0.0)
        self.t, self.n = t, self.n + 1

    def skip(self) -> None:
        """A frame the tracker must not use (non-finite tactels): counted, nothing learnt."""
        self.skipped += 1

    def _fold(self) -> None:
        """Fold the buffered residuals into the per-tactel sums (every MEAN_RESIDUAL_FOLD
        frames, to keep the per-frame cost down) and test the frames' mean residual.

        Model error that no single frame shows can dominate an average of thousands (a
        tactel's zero drifting under a held contact, the rubber's hysteresis behind a rolling
        one, a finger that departs from its model): the residual of the frames' mean, whose
        noise is sigma / sqrt(m), reveals it.  Summed per tactel over the last
        ``MEAN_RESIDUAL_S``; when its chi^2 is beyond the noise's, the reported variances are
        scaled by chi^2 / dof (the Birge ratio), so the uncertainty stops shrinking where the
        data stop agreeing."""
        lin, m = self.lin, self._eframes
        if lin is None or m == 0:
            return
        used, chi2 = fold_residuals(self._esum, self._ecount, self._index, self._ebuf, float(m),
                                    math.exp(-self._edt / MEAN_RESIDUAL_S),
                                    float(MEAN_RESIDUAL_FRAMES))
        self._eframes, self._edt = 0, 0.0
        dof = used - lin.p.size
        if dof < 1:
            return
        chi2 /= lin.sigma * lin.sigma
        self.excess = chi2 / dof if chi2 > chi2_limit(dof, MEAN_RESIDUAL_Z) else 1.0

    def _start(self, z: np.ndarray | list[float], t: float,
               keep: list[bool] | None = None) -> None:
        """(Re)start the filter at measurement ``z``; ``keep`` marks parameters whose filter
        goes on (updated with this frame)."""
        r = self._r
        z = [float(zi) for zi in z]
        old = None if self._s is None else (self._s[X].tolist(), self._s[PXX].tolist())
        x, pxx = list(z), list(r)
        if old is not None and keep is not None:
            for i, kept in enumerate(keep):
                if kept:
                    x0, p0 = old[0][i], old[1][i]
                    gain = p0 / (p0 + r[i])
                    x[i] = x0 + gain * (z[i] - x0)
                    pxx[i] = p0 * (1.0 - gain)
        s = np.zeros((DRIFT + 1, len(z)))
        s[X], s[PXX] = x, pxx
        # The rate is unknown: a prior wide enough for any contact the scenes move (it is
        # learnt from the next frames; velocities are reported after MIN_RATE_FRAMES).
        s[PVV] = [1e6 * ri if m else 0.0 for ri, m in zip(r, self._moving)]
        self._s = s
        self._lag = np.zeros((2, len(z)))  # running means of the innovations, their variances
        self._k = None
        self.t, self.n = t, 1
        self._c[C_LIN_SD] = np.sqrt(s[PXX])

    # -- the estimate ---------------------------------------------------------------------------

    def estimate(self, base: dict[str, Any], at: float | None = None) -> dict[str, Any]:
        """The estimate's fit dict: ``base`` (the last fit's ``FitResult.to_json_dict()``, which
        gives the keys the tracker does not estimate: label, rms, ellipse, ...) with the
        tracked values, their 1-sigma, ``frames_used`` and the rates.  ``at``: predicted to
        that device time (s) from the last frame measured (a frame it could not measure)."""
        assert self._s is not None and self.model is not None
        dt = 0.0 if at is None or self.t is None else at - self.t
        dt = dt if 0.0 < dt < MAX_GAP_S else 0.0
        # The delta method term by term: sd_a sd_b corr_ab (the filters' variances with the
        # drift detector's lag, the single frame's correlation) plus the systematic part, then
        # each moving value's lag (kernels.TrackStep.estimate).  A runaway value overflows to
        # inf (withheld).
        numbers, var, cov_rf, absent = self._kernel().estimate(dt, self.excess)
        rows = self._s.tolist()
        return self.estimate_from(base, numbers, var, cov_rf, absent, rows[V], rows[PVV])

    def estimate_from(self, base: dict[str, Any], numbers: list[float], var: list[float],
                      cov_rf: float, absent: int, rate: list[float],
                      pvv: list[float]) -> dict[str, Any]:
        """:meth:`estimate` from ``TrackStep.estimate``'s numbers and the state's ``rate`` and
        ``pvv`` rows (as :mod:`tactiled.pipeline.tracked_run` gets them from the core)."""
        values: list[float | None] = [None if absent >> i & 1 else v  # (VALUE_KEYS order)
                                      for i, v in enumerate(numbers)] if absent else list(numbers)
        if values[_I_ANGLE] is not None:
            values[_I_ANGLE] = wrap_deg(values[_I_ANGLE])
        i_f, i_r = _I_FORCE, _I_R1
        out = dict(base)
        soft_keys, lifted, base_reasons, base_std, flat, std0, slots, lims = self._judged(base)
        reasons = dict(base_reasons)
        std: dict[str, float | None] = dict(std0)  # (a value not judged again: the fit's sigma)
        for i, key in slots:  # (VALUE_KEYS order: the judged values, and any base lacks)
            v = values[i]
            if not soft_keys[i] or v is None or not math.isfinite(var[i]):
                # not in this model, or withheld by the fit for what frames do not change (a
                # line contact's radius): stays as the fit said
                out[key] = base.get(key)
                continue
            sd_i = math.sqrt(var[i]) * self._widen[i]
            withheld = (None if kept_by_limits(i, v, sd_i, lims[i])
                        else self._withheld(key, v, sd_i, flat[i]))
            tied = None
            if not withheld and i == i_f and math.isfinite(var[i_r]) and math.isfinite(cov_rf):
                r1, sd_r = values[i_r], math.sqrt(var[i_r])
                # a radius this estimate withholds (below) is as unresolved as one whose
                # interval reaches zero: the frames pooled do not tell it better than one
                # frame, so the part of the force's variance that is the radius's is one
                # frame's, not averaged (radius_force_variance)
                unresolved = (soft_keys[i_r] and r1 is not None
                              and not kept_by_limits(i_r, r1, sd_r, lims[i_r])
                              and self._withheld("r1_mm", r1, sd_r, flat[i_r]) is not None)
                if unresolved or radius_tied_force(r1, sd_r, sd_i, cov_rf) is not None:
                    # at least the fit's relative sigma, too: it holds the radius's
                    # uncertainty where the fit found it, which the frames' linearisations,
                    # taken wherever the filter has since drifted along that valley, do not
                    f0, sd0 = base.get(key), base_std.get(key)
                    rel0 = sd0 / f0 if f0 and sd0 and f0 > 0.0 else 0.0
                    sd_i = max(math.sqrt(sd_i * sd_i + v * v * self.excess * self._radius_share()),
                               v * rel0)
                    withheld = self._withheld(key, v, sd_i) or runaway_radius(r1)
                    tied = (f"poorly determined ({TOO_LIGHT}: the force rests on a radius the "
                            f"frames do not resolve: its sigma holds one frame's uncertainty "
                            f"of that radius, {100 * sd_i / v:.0f} % of it)")
            if withheld:
                out[key], std[key] = None, None
                reasons[key] = withheld
                continue
            out[key], std[key] = v, sd_i
            if tied is not None:
                reasons[key] = tied
            elif lifted[i] and self._widen[i] <= 1.0:
                del reasons[key]
        self._rates(values[i_f], reasons, rate, pvv, out, std)
        out["std"] = std
        out["reasons"] = reasons
        out["frames_used"] = self.n
        return out

    def _radius_share(self) -> float:
        """The part of one frame's variance of ln F that its radii (``ln_r``, ``ln_ra``,
        ``beta``) explain, ``c_fR C_RR^-1 c_Rf`` of the linearisation's covariance: what
        pooling frames does not average away while the radius is not resolved."""
        lin = self.lin
        assert lin is not None
        memo = self._share_memo  # (it depends on the linearisation only)
        if memo is None or memo[0] is not lin:
            memo = self._share_memo = (lin, radius_force_variance(
                np.asarray(lin.cov, dtype=np.float64), self.names))
        return memo[1]

    def _judged(self, base: dict[str, Any]) -> tuple[Any, ...]:
        """What of ``base`` (the fit the estimates rest on) the tracker judges again, per value
        key: a value the fit gave, or withheld for a reason the frames gathered since may
        lift (``_SOFT``); which of those reasons to drop once lifted; the fit's reasons and
        1-sigma; what a frame's estimate starts from.  Kept while the same fit dict is the
        base (every frame of a contact)."""
        memo = self._judged_memo
        if memo is not None and memo[0] is base and memo[1] == self.withhold:
            return memo[2]
        reasons = base.get("reasons") or {}
        # (not an orientation the fit's profile found flat across the half-turn: the frames
        # pooled are linearised at a point that likelihood does not single out, as a circle's)
        why = [str(reasons.get(key, "")).startswith(_SOFT)
               and FLAT_ACROSS not in str(reasons.get(key, "")) for key in VALUE_KEYS]
        soft = [base.get(key) is not None or w for key, w in zip(VALUE_KEYS, why)]
        # a radius whose fit left it beyond the linearised sigma's tested range (its relative
        # sigma over TEST_RELATIVE_SIGMA: a likelihood not shown quadratic, the regime where a
        # weak frame's radius lands at 20-40 times the truth with a sigma of 50 %), or that the
        # fit found flat below it: the filter pools linearised steps from such a point, so its
        # value is published only once the frames bring its sigma within that range
        std0 = base.get("std") or {}
        flat = [FLAT in str(reasons.get(key, "")) or (
            key in ("r1_mm", "r2_mm") and beyond_tested(base.get(key), std0.get(key)))
            for key in VALUE_KEYS]
        # the values a frame writes (those judged again, any the base lacks), the fit's
        # sigmas, each value's sigma limit (kept_by_limits: a force's or radius's relative)
        slots = tuple((i, key) for i, key in enumerate(VALUE_KEYS) if soft[i] or key not in base)
        limit = math.inf if self.withhold is None else self.withhold
        lims = [OFF_ARRAY_MM if k in ("x_mm", "y_mm") else MAX_ANGLE_SIGMA if k == "angle_deg"
                else min(UNOBSERVABLE_RELATIVE_SIGMA, min(limit, TEST_RELATIVE_SIGMA) if f else
                         limit) if k in ("r1_mm", "r2_mm") else UNOBSERVABLE_RELATIVE_SIGMA
                for k, f in zip(VALUE_KEYS, flat)]
        judged = (soft, why, reasons, std0, flat, {k: std0.get(k) for k in VALUE_KEYS}, slots,
                  lims)
        self._judged_memo = (base, self.withhold, judged)  # (holds base: its id is not reused)
        return judged

    def _withheld(self, key: str, v: float, sd: float, flat: bool = False) -> str | None:
        """Why ``key`` (value ``v``, 1-sigma ``sd`` over the frames used) is withheld, by the
        fitter's rules (tactiled.fit.uncertainty.unobservable); None to report it.
        ``flat``: the fit found the likelihood flat below this radius
        (:mod:`tactiled.fit.profile`), or left it outside the range that test vouches for
        (a relative sigma over ``TEST_RELATIVE_SIGMA``), or withheld it: reported only once
        the frames give it a relative sigma within ``TEST_RELATIVE_SIGMA``, where its sigma is
        not in question."""
        if key in ("x_mm", "y_mm"):
            return _OFF_ARRAY if sd > OFF_ARRAY_MM else None
        if key not in ("r1_mm", "r2_mm", "force_n", "angle_deg") or (key != "angle_deg" and v <= 0.0):
            return None
        limit = self.withhold
        if flat and key != "force_n":
            limit = min(limit if limit is not None else math.inf, TEST_RELATIVE_SIGMA)
        return sigma_reason(key, v, sd, None, limit, f" over {self.n} frame(s)")

    def _rates(self, force: float | None, reasons: dict[str, str], v: list[float],
               pvv: list[float], out: dict[str, Any], std: dict[str, Any]) -> None:
        """The rates (``RATE_KEYS``, null where not given) into ``out``, their 1-sigma into
        ``std``, from the state's rates ``v`` and their variances ``pvv``."""
        out.update(_NO_RATES)
        std.update(_NO_RATES)
        if self.n < MIN_RATE_FRAMES:
            why = f"the contact changed {self.n} frame(s) ago: too few frames for a rate"
            for _, key, _ in self._rate_of:
                reasons[key] = why
        else:
            excess = self.excess
            for i, key, name in self._rate_of:
                scale = (180.0 / math.pi if name == "psi"
                         else (force or 0.0) if name == "ln_f" else 1.0)
                out[key] = v[i] * scale
                std[key] = math.sqrt(max(pvv[i] * excess, 0.0)) * abs(scale)
        if self.model == "sphere":
            reasons["angle_rate_deg_s"] = "undefined: sphere model"


def _swapped(x: np.ndarray, p: np.ndarray, names: tuple[str, ...]) -> bool:
    """True when the general model's vectors ``x`` and ``p`` lie on different sides of
    ``|beta| = 1`` (or beyond it with opposite signs): their psi name different principal
    axes, 90 degrees apart, and cannot be averaged (docs/concepts/tracking.md)."""
    i = names.index("beta")
    a, b = float(x[i]), float(p[i])
    return (abs(a) > 1.0) != (abs(b) > 1.0) or (abs(a) > 1.0 and a * b < 0.0)


def untracked(fit: dict[str, Any], frames_used: int, reason: str) -> dict[str, Any]:
    """``fit`` (a fit's JSON dict) with the tracker's keys for an estimate it did not make
    (no contact, tracking off): ``frames_used`` as given, the rates null with ``reason``."""
    out = dict(fit)
    out.update(_NO_RATES)
    out["frames_used"] = frames_used
    out["std"] = {**(fit.get("std") or {}), **_NO_RATES}
    out["reasons"] = {**(fit.get("reasons") or {}), **{k: reason for k in RATE_KEYS}}
    return out

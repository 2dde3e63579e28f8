"""The curvature fitter: a strain frame in, a FitResult out (paper secs. 6-7).

Residuals are taken over a window around the peak (4x4 by default), normalised by the peak
strain; the damped least-squares solver works on each model's unconstrained parameters with the
forward model's exact Jacobian.  Uncertainties are the Cramer-Rao bound ``sigma^2 (J^T J)^-1``
with J the Jacobian of the window strains and sigma the sensor's noise, carried to user units by
the delta method.  No I/O here, and nothing raises on bad data: every outcome is a FitResult.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import gammaincinv

from tactiled.sensors.model import SensorModel
from tactiled.fit import budget as fit_budget
from tactiled.fit import compiled
from tactiled.fit import flatfield
from tactiled.fit.budget import EXHAUSTED, Budget
from tactiled.fit.flatfield import FlatField
from tactiled.fit.floor import FloorLearner
from tactiled.fit.line import FORCE_REASON as LINE_FORCE_REASON
from tactiled.fit.line import PARAMS as LINE_PARAMS
from tactiled.fit.line import STEPS as LINE_STEPS
from tactiled.fit.line import LineProblem
from tactiled.fit.linewindow import chi2_on_band, line_frame
from tactiled.fit.models import VALUE_KEYS, Model, get_model
from tactiled.fit.params import (
    MAX_ANGLE_SIGMA,
    POOR_RELATIVE_SIGMA,
    RADIUS_LIMITS,
    TOO_LIGHT,
    UNOBSERVABLE_RELATIVE_SIGMA,
    radius_tied_force,
)
from tactiled.fit.profile import angle_profile, flat_below, withhold_flat
from tactiled.fit.result import FitResult
from tactiled.fit.verdict import ArrayLimits, judge_values
from tactiled.fit.solver import BUDGET_MESSAGE, TIME_BUDGET_EXCEEDED, SolveResult, levenberg_marquardt
from tactiled.fit.start import StartTable, force_constants, start_point, start_table
from tactiled.fit.window import choose_window, plain_frame, plain_window
from tactiled.physics.contact import Contact, LineContact
from tactiled.physics.hertz import Ellipse
from tactiled.physics.kernels import cramer_rao as crb_kernel
from tactiled.physics.strain import StrainModel, warm_rules

#: Singular values below this fraction of the largest make J^T J numerically singular.
SINGULAR_CONDITION = 1e12
#: Above this the fit is reported but flagged as ill-conditioned.
ILL_CONDITION = 1e7

#: A peak below this is no contact at all (far below any sensor's noise).
MIN_PEAK = 1e-9
#: Strain magnitudes above this are broken readings, not contact (1000 % compression).
MAX_STRAIN = 10.0
#: A contact whose major axis lies within this angle (degrees) of the finger axis and which is
#: longer than LINE_CONTACT_LENGTH times the array along it is a line contact (see
#: Fitter._line_contact).  The rubber runs on past the array, so a contact somewhat longer than
#: the array still lies on the finger (flagged, not withheld); 1.5x is where it runs off it.
LINE_CONTACT_ANGLE = 30.0
LINE_CONTACT_LENGTH = 1.5

#: A full fit stops once the next step would lower chi^2 by less than this (units of the
#: noise: 1e-4 moves no parameter by more than 0.01 of its sigma; measured on warm fits, 1e-6
#: took 4 evaluations at the median, 1e-4 takes 3).
STOP_CHI2 = 1e-4
#: Iteration cap of auto's candidate fits (see Fitter._fit_model's ``scouting``).
SCOUT_ITERATIONS = 25
#: A fit is converged when one more solver step (the Gauss-Newton step within the step caps)
#: could lower chi^2 by less than this: at the minimum's doorstep that puts every parameter
#: within 0.1 of its 1-sigma bound of it, and rounding (~1e-10 of chi^2) cannot cross it
#: (levenberg_marquardt's ``verdict_tol``; docs/concepts/fitting.md).
CONVERGED_CHI2 = 0.01

#: The solver keeps a radius within these (mm): half and twice RADIUS_LIMITS, beyond which a
#: radius is withheld as an artefact anyway.  Unbounded, a frame too light for curvature sent
#: ln R crawling towards -inf one capped step per iteration until the iteration cap, the other
#: parameters unfinished, and where that crawl ended hung on the last bits of the data.
_LN_R_BOUNDS = (math.log(0.5 * RADIUS_LIMITS[0]), math.log(2.0 * RADIUS_LIMITS[1]))
_LOG_RADII = ("ln_r", "ln_ra")

#: A fit's excess residual feeds the floor learner capped at this multiple of what it expects.
OUTLIER_FACTOR = 10.0
#: chi^2 above its quantile of this level flags a fit whose residuals exceed the noise.
MISMATCH_LEVEL = 0.99


@lru_cache(maxsize=None)
def _chi2_limit(dof: int) -> float:
    """The ``MISMATCH_LEVEL`` quantile of chi^2 with ``dof`` degrees of freedom: scipy.stats'
    ``chi2.ppf``, bit for bit, from scipy.special (scipy.stats costs a second to import)."""
    return float(2.0 * gammaincinv(dof / 2.0, MISMATCH_LEVEL))


_STEP = {"ln_r": 1.0, "ln_ra": 1.0, "beta": 0.5, "psi": 0.5, "ln_f": 0.7, "x0": 2.0, "y0": 2.0}


@dataclass(frozen=True)
class FitOptions:
    """Knobs of a fit.  ``window`` is the side of the square window (clipped to the array);
    ``tol`` the forward model's quadrature accuracy; ``max_starts`` caps cold starts."""

    window: int = 4
    tol: float = 1e-9  # chosen by `tactiled bench --suite configs` (docs/performance/benchmarks.md)
    max_iter: int = 60
    max_starts: int = 3
    #: Withhold (null, with the reason "force too low for curvature") a radius whose Cramer-Rao
    #: sigma exceeds this fraction of it.  None: report it, flagged, down to the degenerate
    #: limit.  The daemon sets 0.5 (the paper: radius unusable below ~0.5 N).
    withhold_relative_sigma: float | None = None
    #: "exact" (analytic chain rule through the quadrature) or "fd" (forward differences of
    #: the residual; for benchmarking what the exact Jacobian buys).
    jacobian: str = "exact"
    #: Learn from the fits' residuals how far the finger departs from its model and widen the
    #: uncertainties of later fits to match (tactiled.fit.floor).  On for a stream of one
    #: sensor's frames (the daemon); off, each fit stands alone (``tactiled fit``, whose chunks
    #: run in parallel).
    learn_floor: bool = False
    #: The fit's budget (:mod:`tactiled.fit.budget`): solver iterations summed over every
    #: start and model, and model-evaluation work (quadrature nodes x window tactels); None:
    #: unlimited.  A fit that spends either stops there, not converged, and says so.
    budget_iterations: int | None = fit_budget.DEFAULT_ITERATIONS
    budget_work: int | None = fit_budget.DEFAULT_WORK

    def __post_init__(self) -> None:
        for name in ("budget_iterations", "budget_work"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, int) and value >= 1):
                raise ValueError(f"{name} must be a positive whole number or None, got {value!r}")
        if self.window < 2:
            raise ValueError(f"window must be at least 2 tactels, got {self.window}")
        if not (0 < self.tol < 1):
            raise ValueError(f"tol must lie in (0, 1), got {self.tol!r}")
        if self.jacobian not in ("exact", "fd"):
            raise ValueError(f"jacobian must be 'exact' or 'fd', got {self.jacobian!r}")


def _forward_difference(residual):
    """Wrap a residual function so its Jacobian comes from forward differences (k extra
    evaluations per call, step ``sqrt(eps) * max(1, |p|)``)."""
    h0 = math.sqrt(np.finfo(float).eps)

    def fd(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, _ = residual(p)
        jac = np.empty((r.size, p.size))
        for i in range(p.size):
            q = p.copy()
            h = h0 * max(1.0, abs(p[i]))
            q[i] += h
            jac[:, i] = (residual(q)[0] - r) / h
        return r, jac

    return fd


@dataclass
class _Frame:
    """A frame's window, shared by the models fitted to it (see ``Fitter._frame``)."""

    clean: np.ndarray  # the frame, unusable tactels zeroed
    peak_idx: tuple[int, int]
    peak: float
    win: tuple[int, int, int, int]
    xs: np.ndarray  # the window's tactel coordinates on the grid, mm
    ys: np.ndarray
    target: np.ndarray  # the window's strains, flattened
    valid: np.ndarray  # usable tactels of the window, flattened
    n_points: int
    inv_scale: np.ndarray  # per tactel: 1 / (peak x its sd relative to the noise)
    zdata: np.ndarray  # the usable tactels' strains in units of their sd
    ex: np.ndarray  # the window's tactel displacements from the grid, mm
    ey: np.ndarray


@lru_cache(maxsize=None)
def _steps(model: Model) -> np.ndarray:
    """The step caps of ``model``'s parameters (read-only, shared)."""
    out = np.array([_STEP[name] for name in model.params])
    out.setflags(write=False)
    return out


@lru_cache(maxsize=None)
def _bounds(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """The solver's box on ``model``'s parameters: its log radii within ``_LN_R_BOUNDS``."""
    radius = np.array([name in _LOG_RADII for name in model.params])
    lo = np.where(radius, _LN_R_BOUNDS[0], -np.inf)
    hi = np.where(radius, _LN_R_BOUNDS[1], np.inf)
    for arr in (lo, hi):
        arr.setflags(write=False)
    return lo, hi


#: The line model (a cylinder on a flat array) as the window check sees it.
_LINE_MODEL = Model("line", LINE_PARAMS)
_LINE_BOUNDS = (np.array([_LN_R_BOUNDS[0], -np.inf, -np.inf, -np.inf]),
                np.array([_LN_R_BOUNDS[1], np.inf, np.inf, np.inf]))


def _covariance(jraw: np.ndarray, sigma: float) -> tuple[np.ndarray | None, float | None]:
    """``sigma^2 (J^T J)^-1`` of a Jacobian of strains, and J's condition number; None for a
    singular J."""
    try:
        sv = np.linalg.svd(jraw, compute_uv=False)
    except np.linalg.LinAlgError:
        return None, None
    if sv.size == 0 or not np.all(np.isfinite(sv)) or sv[-1] <= 0.0:  # size 0: no evaluation
        return None, None
    condition = float(sv[0] / sv[-1])
    if condition > SINGULAR_CONDITION:
        return None, condition
    return sigma * sigma * np.linalg.inv(jraw.T @ jraw), condition


class Fitter:
    """Fits contact models to strain frames of one sensor."""

    def __init__(
        self, sensor: SensorModel | None = None, options: FitOptions | None = None, warm: bool = True
    ) -> None:
        self.sensor = sensor or SensorModel()
        self._line_scouted = False  # set by _fit_line: auto's line stayed a scout
        self._line_point: tuple[float, float, float] | None = None  # set by _fit_line
        self.options = options or FitOptions()
        self.model = StrainModel(self.sensor, tol=self.options.tol)
        self.sigma = self.sensor.noise.effective_sigma  # of the frame being fitted
        self._sigma1 = self.sigma  # of one frame
        g = self.sensor.geometry
        self._span = max(g.span_x, g.span_y)
        self.limits = ArrayLimits.of(self.sensor)
        self._all_ok = np.ones((g.rows, g.cols), bool)
        self._all_ok.setflags(write=False)
        self._deadline: float | None = None  # time.perf_counter() s; set by fit(budget_s=)
        self._budget: Budget | None = None  # what is left of the fit's budget, during fit()
        o = self.options
        iterations, work = o.budget_iterations, o.budget_work
        reserve = 0.0
        if g.flat:  # dearer models: an allowance for the fits that earn it (FLAT_WORK_FACTOR)
            iterations = None if iterations is None else iterations * fit_budget.FLAT_ITERATION_FACTOR
            reserve = 0.0 if work is None else float(work * (fit_budget.FLAT_WORK_FACTOR - 1))
        #: this sensor's budget of a fit: ``(iterations, work)``, the work with its allowance
        self.budget_limits = (iterations, None if work is None else work + reserve)
        #: the work a fit may earn on top of the options' (``tactiled.fit.budget.Budget``)
        self.allowance = reserve
        #: what the last fit spent: ``(iterations, work)`` (:mod:`tactiled.fit.budget`)
        self.spent: tuple[int, float] = (0, 0.0)
        m = self.model
        self._model_args = (m._rf, m._k, m._scale, m._dmin, m._imp)
        self._in_fit = False
        self._frame_memo: tuple[tuple[int, int], _Frame | FitResult] | None = None
        self._starts: StartTable | None = None  # start_table(sensor), once it is needed
        self._force_constants = force_constants(self.sensor)
        #: what the sensor's recent fits say of its departure from the model (see _mismatch)
        self.floor = FloorLearner()
        #: each tactel's gain and position as this finger's fits show them (see _mismatch)
        self.flat = (FlatField(g.rows, g.cols)
                     if self.options.learn_floor and g.rows * g.cols <= flatfield.MAX_TACTELS else None)
        #: use what was learned, learn no more (:meth:`adopt`)
        self.frozen = False
        if warm:
            self._warm_up()

    def adopt(self, floor: FloorLearner, flat: FlatField | None) -> None:
        """Fit with what another fitter of this finger learned (its model-error floor and
        flat field), and learn no more: every frame then gets the same treatment whatever came
        before it (``tactiled fit``, whose chunks run in parallel, learns in a first pass)."""
        self.floor, self.flat, self.frozen = floor, flat, True

    def _warm_up(self) -> None:
        """Build the start table and load the compiled kernels now, so the first frame's
        fit time is a fit's and not a start-up's."""
        start_table(self.sensor)
        warm_rules()
        g = self.sensor.geometry
        if g.flat:
            frame = self.model.predict(LineContact(8.0, 80.0, 0.1, g.span_x / 2, g.span_y / 2))
            self._fit_line(frame, None, None)
            names: tuple[str, ...] = ("sphere", "general")
        else:
            frame = self.model.predict(Contact(8.0, math.inf, 80.0, 1.0, g.span_x / 2, g.span_y / 2))
            names = ("cylinder", "sphere", "general")
        for name in names:
            model = get_model(name)
            done = self._fit_model(frame, model, None, None)
            # the Python solver too (contacts past the compiled rules; frames the model cannot
            # explain wander there): its kernels' first load cost 0.1-0.6 s of the first such fit
            fr = self._frame(frame, None)
            if not isinstance(fr, FitResult) and done.params is not None:
                p0 = np.asarray(done.params, dtype=float)
                levenberg_marquardt(self._residual(fr, model), p0, max_step=_steps(model),
                                    max_iter=2, bounds=_bounds(model), verdict_tol=1e-12)
        # a made-up frame teaches nothing of this finger
        self.floor.reset()
        if self.flat is not None:
            self.flat.reset()

    # ------------------------------------------------------------------------------------
    def fit(
        self,
        strain: np.ndarray,
        model: str = "cylinder",
        start: np.ndarray | None = None,
        mask: np.ndarray | None = None,
        warm: tuple[str, tuple[float, ...]] | None = None,
        budget_s: float | None = None,
        frames: int = 1,
    ) -> FitResult:
        """Fit ``model`` ('cylinder', 'sphere', 'general' or 'auto') to a zeroed strain frame.

        ``frames`` > 1 says the frame is the mean of that many frames of one contact: its noise
        is the sensor's over ``sqrt(frames)`` (the model-error floor does not average away),
        and chi^2, the weights and the uncertainties follow.

        ``start`` is an internal parameter vector of that model; ``warm`` is the previous
        frame's ``(result.model, result.params)`` on a persisting contact: it starts the same
        model there, and under 'auto' keeps the model the data chose while its fit stays
        consistent with the noise (the full choice is made again otherwise).  ``mask`` marks
        usable tactels (False for dead, saturated or non-finite ones; non-finite entries are
        masked automatically).

        ``budget_s`` bounds the search (seconds of wall time): past it no further model
        evaluation starts, and the result is the best point so far, not converged, with the
        reason "time budget exceeded".  A fit normally takes about a millisecond; a frame far
        outside the model (every tactel saturated: a contact the size of the finger) costs
        ~150 ms per evaluation and would run for seconds.  The overrun is at most one
        evaluation.  Within it, the options' iteration and work budget
        (:mod:`tactiled.fit.budget`) bounds the fit on every machine alike; a fit either budget
        stopped is not converged, its ``reasons["fit"]`` begins "fit budget exhausted", and its
        sigmas are widened by the distance left to the minimum, or its values withheld.
        """
        self.catch_up()  # a worker runs it after its last answer; anyone else, here
        t0 = time.perf_counter()
        self._deadline = None if budget_s is None else t0 + budget_s
        self._budget = Budget(self.budget_limits[0], self.options.budget_work, self.allowance)
        self._in_fit = True
        if frames != 1:
            if not (isinstance(frames, int) and frames >= 1):
                raise ValueError(f"frames must be a positive whole number, got {frames!r}")
            self.sigma = self._sigma1 / math.sqrt(frames)
        strain = self.flattened(strain)
        try:
            if model == "auto":
                res = self._fit_auto(strain, mask, warm)
            else:
                get_model(model)  # ValueError naming the choices
                if start is None and warm is not None and warm[0] == model and warm[1]:
                    start = np.asarray(warm[1], dtype=float)
                res = (self._fit_cylinder(strain, start, mask) if model == "cylinder"
                       else self._fit_model(strain, get_model(model), start, mask))
            if self._budget.exhausted and res.converged:
                # a converged search, but the fit's other starts or models were cut short
                res.converged = False
                res.reasons["fit"] = (f"{EXHAUSTED} before the fit ended: the {res.model} fit "
                                      "kept converged, the other starts or models were not tried out")
        finally:
            self._deadline = None
            self.spent = (self._budget.used_iterations, self._budget.used_work)
            self._budget = None
            self._in_fit = False
            self.sigma = self._sigma1
            self._frame_memo = None  # the memo must not outlive the frame (ids are reused)
        if res.contact:
            # the one rule before anything leaves the fitter (tactiled.fit.verdict)
            judge_values(res.values, res.std, res.reasons, self.limits, label=res.label,
                         withhold_relative_sigma=self.options.withhold_relative_sigma)
            if "ellipse" in res.reasons:
                res.ellipse = None
        res.fit_ms = (time.perf_counter() - t0) * 1e3
        return res

    def catch_up(self) -> bool:
        """Run the learning the last fits left due (the flat field's re-solve, 1-3 ms on an
        8x8 array), which a fit defers so that its answer never waits for it: a daemon worker
        calls this after sending the answer, and :meth:`fit` before fitting.  True if
        something ran."""
        return self.flat is not None and not self.frozen and self.flat.catch_up()

    def flattened(self, strain: np.ndarray) -> np.ndarray:
        """The frame as the fits read it: divided by the tactel gains this finger's fits have
        shown (:mod:`tactiled.fit.flatfield`), once they are significant; else as it is."""
        f = self.flat
        if f is None or not f.active:
            return strain
        s = np.asarray(strain, dtype=float)
        return s * f.inverse_gain if s.shape == f.gain.shape else s  # _frame names a bad shape

    def _window_shift(self, win: tuple[int, int, int, int], nr: int, nc: int) -> tuple[np.ndarray, np.ndarray]:
        """The window's tactel displacements (mm, flattened row-major): the sensor model's
        plus what this finger's fits have shown (:mod:`tactiled.fit.flatfield`)."""
        ex, ey = self.model.window_shift(win, nr, nc)
        f = self.flat
        if f is not None and f.active:
            r0, c0 = win[0], win[1]
            ex = ex + f.dx[r0:r0 + nr, c0:c0 + nc].ravel()
            ey = ey + f.dy[r0:r0 + nr, c0:c0 + nc].ravel()
        return ex, ey

    def _out_of_time(self) -> bool:
        """The fit's budget is spent (its iterations, work or wall time): start nothing more."""
        b = self._budget
        return (b is not None and b.spent) or (
            self._deadline is not None and time.perf_counter() > self._deadline)

    # ------------------------------------------------------------------------------------
    def _prepare(self, strain: np.ndarray, mask: np.ndarray | None):
        """``(frame with unusable tactels zeroed, usable mask)``.  Non-finite entries and
        strains beyond ``MAX_STRAIN`` (no rubber survives them: a broken reading) are unusable."""
        s = np.asarray(strain, dtype=float)
        total = float(np.abs(s).max()) if s.size else 0.0
        if mask is None and total <= MAX_STRAIN:  # the common case (NaN fails the test too)
            return s, self._all_ok if s.shape == self._all_ok.shape else np.ones(s.shape, bool)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(s) & (np.abs(s) <= MAX_STRAIN)
        if mask is not None:
            ok &= np.asarray(mask, dtype=bool)
        return np.where(ok, s, 0.0), ok

    def _fit_model(
        self,
        strain: np.ndarray,
        model: Model,
        start: np.ndarray | None,
        mask: np.ndarray | None,
        scouting: bool = False,
        start_chi2: float | None = None,
    ) -> FitResult:
        """Fit one model.  ``scouting`` (auto's candidate models) stops at a chi^2 decrease
        below 0.01 and after ``SCOUT_ITERATIONS``: enough to rank models by an information
        criterion, whose differences that matter are units of chi^2; the chosen one is then
        solved fully.  ``start_chi2``: the chi^2 at ``start``, where a scout left it."""
        fr = self._window(strain, model, mask)
        if isinstance(fr, FitResult):
            return fr
        peak, win, n_points = fr.peak, fr.win, fr.n_points
        starts = [start] if start is not None else self._cold_starts(fr.clean, fr.peak_idx, model)
        cap = SCOUT_ITERATIONS if scouting else self.options.max_iter
        # stop once the next step would lower chi^2 by less than STOP_CHI2 (0.01 scouting): a
        # parameter then moves by under 0.01 of its sigma, and a warm fit saves an evaluation
        best, tried = self._search(fr, compiled.KINDS[model.name], starts, _steps(model),
                                   _bounds(model), cap, 1e-2 if scouting else STOP_CHI2,
                                   lambda: self._residual(fr, model), start_chi2)
        if scouting:  # only ranked by chi^2, then solved again in full if chosen: no report
            return FitResult(contact=True, model=model.name, chi2=best.cost * peak * peak / self.sigma**2,
                             iterations=best.iterations, evaluations=best.evaluations,
                             converged=best.converged, peak=peak, n_points=n_points, window=win,
                             starts=tried, message=best.message,
                             params=tuple(best.p.tolist()))
        res = self._result(model, best, peak, win, n_points, tried, fr.zdata, fr.valid)
        r1 = res.values.get("r1_mm")
        if best.converged and r1 is not None and abs(math.log(r1) - best.p[0]) < 1e-9:
            # every model's first parameter is a log radius: r1's, or the general's r_a
            withhold_flat(res.values, res.std, res.reasons, flat_below(
                self, fr, compiled.KINDS[model.name], best.p, _steps(model), _bounds(model),
                lambda: self._residual(fr, model), res.chi2, res.values.get("r1_mm"),
                res.std.get("r1_mm")))
        return res

    def _search(self, fr: _Frame, kind: int, starts: list[np.ndarray], steps: np.ndarray,
                bounds: tuple[np.ndarray, np.ndarray], cap: int, stop_chi2: float,
                python_residual, start_chi2: float | None = None) -> tuple[SolveResult, int]:
        """Search from each start in turn (the compiled search; the Python solver on
        ``python_residual()`` where that hands back) until one explains the window to the
        noise or the budget is spent: ``(best search, starts tried)``.  Each stops once the
        next step would lower chi^2 by less than ``stop_chi2``.

        Beyond the chi^2 a right model exceeds ``1 - MISMATCH_LEVEL`` of the time, that
        tolerance and the verdict's grow with chi^2 over it (``levenberg_marquardt``'s
        ``noise_cost``): a window the model does not explain (a sphere's blob under the line
        model, several contacts, a hand print) has its minimum far above the noise, and the
        search crept towards it for tens of iterations, each step lowering chi^2 by a sliver
        of it, moving the values by a sliver of the errors such a fit has (its sigmas are
        widened by that excess: :meth:`_mismatch`).  Fits the model explains are untouched.

        On a flat array a search that has spent the fit's base work goes on into the flat
        allowance only while its chi^2 is within ``GRANT_CHI2_FACTOR`` times a right model's
        (``Budget.grant_cost``); ``start_chi2``, the first start's chi^2 where a scout left
        it, lets its first evaluation draw on the allowance when it is within that."""
        peak = fr.peak
        budget = self._budget
        unit = (self.sigma / peak) ** 2  # the cost of chi^2 = 1
        atol = stop_chi2 * unit
        verdict_tol = CONVERGED_CHI2 * unit
        dof = max(fr.n_points - len(starts[0]), 1)
        noise_cost = _chi2_limit(dof) * unit
        exact = kind == compiled.LINE or self.options.jacobian == "exact"
        window = (fr.xs, fr.ys, fr.target, fr.valid, fr.inv_scale, fr.ex, fr.ey)
        residual = None  # the Python solver's residual function, built only if it is needed
        best: SolveResult | None = None
        tried = 0
        for p0 in starts:
            max_iter = self._iterations_for(cap)
            if tried and (max_iter == 0 or self._out_of_time()):
                break
            tried += 1
            sol = None
            if exact:  # the whole search compiled (falls back on huge contacts)
                grant = -1.0 if budget is None else budget.grant_cost(dof, unit)
                sol = compiled.solve(kind, p0, steps, max_iter, atol, self._model_args, window,
                                     self.options.tol, bounds=bounds, verdict_tol=verdict_tol,
                                     budget=budget, noise_cost=noise_cost, grant_cost=grant,
                                     start_ok=tried == 1 and start_chi2 is not None
                                     and start_chi2 * unit <= grant)
            if sol is None:
                if residual is None:
                    residual = python_residual()
                sol = levenberg_marquardt(residual, p0, max_step=steps, max_iter=max_iter, atol=atol,
                                          deadline=self._deadline, verdict_tol=verdict_tol,
                                          bounds=bounds, noise_cost=noise_cost)
                if budget is not None:
                    budget.charge(sol.iterations, 0.0)
            self._ran_out(sol, max_iter, cap)
            if best is None or sol.cost < best.cost:
                best = sol
            if self._good_enough(best, peak, fr.n_points) or self._out_of_time():
                break
        assert best is not None
        return best, tried

    def _iterations_for(self, cap: int) -> int:
        """The iteration cap of the next search: ``cap``, or what the fit's budget has left."""
        return cap if self._budget is None else self._budget.iterations_for(cap)

    def _ran_out(self, sol: SolveResult, max_iter: int, cap: int) -> None:
        """Mark a search the fit's iterations stopped (not its own cap) as the budget's."""
        if self._budget is not None and max_iter < cap and sol.iterations >= max_iter \
                and not sol.converged:
            self._budget.exhausted = True
            sol.message = f"{EXHAUSTED} ({self.options.budget_iterations} iterations)"

    @staticmethod
    def _stopped(sol: SolveResult) -> bool:
        """The fit's budget (iterations, work or wall time) stopped this search."""
        return sol.message is BUDGET_MESSAGE or sol.message is TIME_BUDGET_EXCEEDED or (
            sol.message.startswith(EXHAUSTED))
    def _fit_cylinder(self, strain: np.ndarray, start: np.ndarray | None,
                      mask: np.ndarray | None) -> FitResult:
        """The cylinder model: on a curved finger the Hertz ellipse's; on a flat array a line
        contact's (:mod:`tactiled.fit.line`), reported as model 'cylinder', label 'line'."""
        if self.sensor.geometry.flat:
            return self._fit_line(strain, start, mask)
        return self._fit_model(strain, get_model("cylinder"), start, mask)

    def _cylinder_as_point(self, cyl: FitResult) -> tuple[float, float, float, float, float]:
        """A cylinder fit as ``(ln R, psi, ln F, x0, y0)``, a start for the other models: on a
        flat array the line's point nearest the window's peak, with the load over one cover
        depth's length (the part of the line a sphere's start should explain)."""
        p = cyl.params
        if not self.sensor.geometry.flat:
            return tuple(p)  # type: ignore[return-value]
        x, y = cyl.values.get("x_mm"), cyl.values.get("y_mm")
        load = (cyl.line or {}).get("load_n_per_mm") or 0.1
        if (x is None or y is None) and self._line_point is not None:
            x, y, load = self._line_point  # a line stopped short: its values withheld, not its place
        if x is None or y is None:
            g = self.sensor.geometry
            x, y = 0.5 * g.span_x, 0.5 * g.span_y
        if cyl.window is not None:  # slide along the line to the window's centre
            r0, c0, nr, nc = cyl.window
            g = self.sensor.geometry
            wx, wy = (r0 + 0.5 * (nr - 1)) * g.dx, (c0 + 0.5 * (nc - 1)) * g.dy
            c, s = math.cos(p[1]), math.sin(p[1])
            t = (wx - x) * c + (wy - y) * s
            x, y = x + t * c, y + t * s
        depth = min(self.sensor.impulse.depth_x, self.sensor.impulse.depth_y)
        return p[0], p[1], math.log(load * 4.0 * depth), x, y

    def _line_explains(self, cyl: FitResult) -> bool:
        """On a flat array: the line fit converged with chi^2 consistent with the noise (the
        test a warm fit's model is kept by).  Auto then keeps it without scouting the sphere
        and the general ellipse: where the window shows a line, those can only follow it
        into ever larger contacts (a circle, an ellipse running off the array), the costliest
        searches a flat array's fit has, to land on what :meth:`_runs_off` turns back into
        the line."""
        return self.sensor.geometry.flat and cyl.converged and self._consistent(cyl)

    def _line_ruled_out(self, converged: bool, chi2: float, n_points: int) -> bool:
        """The line's scout converged (the next step would lower chi^2 by under its
        tolerance: it sits at a minimum) with chi^2 over twice the most a right model reaches
        (:meth:`_consistent`): solving on cannot bring it to the noise, so the window shows
        no line (a ball's blob: tens to hundreds of times its degrees of freedom) and the
        line stays a scout, ranked with the others and solved fully only if chosen."""
        dof = max(n_points - len(LINE_PARAMS), 1)
        return converged and chi2 > 2.0 * (dof + 3.0 * math.sqrt(2.0 * dof))

    def _runs_off(self, res: FitResult) -> bool:
        """On a flat array: ``res`` (a general or sphere fit) is an ellipse whose both ends lie
        off the array (beyond a pitch of its edge), which within the array is a line contact:
        the line model says the same with fewer parameters and without a force or ends that
        nothing measured."""
        if not self.sensor.geometry.flat or res.params is None or res.model not in compiled.KINDS:
            return False
        a, _, theta, _ = compiled.ellipse_at(compiled.KINDS[res.model], np.asarray(res.params),
                                             self.model._rf, self.model._k)
        if a < 0.0:
            return True
        g = self.sensor.geometry
        x0, y0 = res.params[-2], res.params[-1]
        ends = ((x0 + s * a * math.cos(theta), y0 + s * a * math.sin(theta)) for s in (-1.0, 1.0))
        return all(not (-g.dx <= x <= g.span_x + g.dx and -g.dy <= y <= g.span_y + g.dy)
                   for x, y in ends)

    def _fit_line(self, strain: np.ndarray, start: np.ndarray | None,
                  mask: np.ndarray | None, scout_first: bool = False,
                  start_chi2: float | None = None) -> FitResult:
        """A cylinder on a flat array: the line model on this frame's window.

        ``scout_first`` (auto, cold): the first cold start is searched with a scout's iteration
        cap and tolerance (:meth:`_fit_model`); where that rules the line out
        (:meth:`_line_ruled_out`) the scout is the answer and ``self._line_scouted`` is set,
        else the search goes on from where it stopped, as a full fit."""
        self._line_scouted = False
        self._line_point = None
        fr = self._line_frame(strain, mask)
        if isinstance(fr, FitResult):
            fr.model = "cylinder"
            return fr
        peak = fr.peak
        prob = self._line_problem(fr)
        if start is not None and np.shape(start) != (len(LINE_PARAMS),):
            start = None  # a start of another model (a curved finger's cylinder): start cold
        starts = ([np.asarray(start, dtype=float)] if start is not None
                  else prob.starts(fr.clean, self.model.xs_full, self.model.ys_full, peak))
        scout = None
        if scout_first:
            scout, _ = self._search(fr, compiled.LINE, starts[:1], LINE_STEPS, _LINE_BOUNDS,
                                    SCOUT_ITERATIONS, 1e-2, lambda: prob.residual_and_jacobian)
            start_chi2 = scout.cost * peak * peak / self.sigma**2
            # (a scout denied the flat allowance is over GRANT_CHI2_FACTOR >= 2 times a right
            # model's chi^2: as far from a line as a converged scout the test rules out)
            self._line_scouted = self._line_ruled_out(scout.converged, start_chi2, fr.n_points) \
                or scout.message == fit_budget.DENIED
            starts = [scout.p, *starts[1:]]
        if self._line_scouted:
            best, tried = scout, 1
        else:
            best, tried = self._search(fr, compiled.LINE, starts, LINE_STEPS, _LINE_BOUNDS,
                                       self.options.max_iter, STOP_CHI2,
                                       lambda: prob.residual_and_jacobian,
                                       start_chi2)
            if scout is not None:
                if best.jacobian.size == 0 and scout.jacobian.size:
                    # the budget refused the search's first evaluation: the scout's point stands
                    best = SolveResult(scout.p, scout.residual, scout.jacobian, scout.cost, 0, 0,
                                       False, best.message)
                best.iterations += scout.iterations
                best.evaluations += scout.evaluations
        reasons: dict[str, str] = {}
        jraw = best.jacobian * peak
        cov, condition = _covariance(jraw, self.sigma)
        if cov is None:
            reasons.update(dict.fromkeys(("x_mm", "y_mm", "r1_mm", "angle_deg"),
                                         "Jacobian singular: parameter not identifiable from this window"))
        elif condition > ILL_CONDITION:
            reasons["condition"] = f"ill-conditioned fit (condition number {condition:.3g})"
        values, std, line = prob.report(best.p, cov)
        # where the line passes and its load, even if withheld below (auto's other starts)
        self._line_point = (values["x_mm"], values["y_mm"], line["load_n_per_mm"])
        reasons["force_n"] = LINE_FORCE_REASON
        reasons["r2_mm"] = "infinite: cylinder model"
        if self._stopped(best):
            self._unsettled(best, peak, values, std, reasons)
            if all(values.get(k) is None for k in VALUE_KEYS):
                line = None  # the load and offset of a search stopped short are no measurement
        self._unobservable(values, std, reasons)
        if best.converged:
            withhold_flat(values, std, reasons, flat_below(
                self, fr, compiled.LINE, best.p, LINE_STEPS, _LINE_BOUNDS,
                lambda: prob.residual_and_jacobian, best.cost * peak * peak / self.sigma**2,
                values.get("r1_mm"), std.get("r1_mm")))
            withhold_flat(values, std, reasons, angle_profile(
                self, fr, compiled.LINE, best.p, LINE_STEPS, _LINE_BOUNDS,
                lambda: prob.residual_and_jacobian, best.cost * peak * peak / self.sigma**2,
                LINE_PARAMS.index("psi"), std.get("angle_deg")), "angle_deg")
        else:
            reasons.setdefault("fit", best.message)
        label = self._label(values, "line")
        if line is None:  # withheld: a search its budget stopped far from any line
            label = None
        return FitResult(
            contact=True, model="cylinder", label="line" if label == "plane" else label,
            values=values, std=std,
            rms=math.sqrt(best.cost / max(fr.n_points, 1)),
            chi2=best.cost * peak * peak / self.sigma**2,
            iterations=best.iterations, evaluations=best.evaluations, converged=best.converged,
            condition=condition, peak=peak, n_points=fr.n_points, window=fr.win, starts=tried,
            message=best.message, reasons=reasons, params=tuple(best.p.tolist()), line=line,
        )

    def _window(self, strain: np.ndarray, model: Model, mask: np.ndarray | None) -> _Frame | FitResult:
        """This frame's window (:meth:`_frame`) when it can hold ``model``, else a FitResult
        saying why there is no problem to solve."""
        fr = self._frame(strain, mask)
        if isinstance(fr, FitResult):
            return fr
        if fr.n_points <= model.size:
            return FitResult(
                contact=True, model=model.name, peak=fr.peak, window=fr.win, n_points=fr.n_points,
                message=f"only {fr.n_points} usable tactels in the window for {model.size} parameters",
                reasons={k: "too few usable tactels in the window" for k in VALUE_KEYS},
            )
        return fr

    def _residual(self, fr: _Frame, model: Model):
        """The residual function of ``model`` on the window ``fr`` (for the Python solver),
        charging each evaluation to the fit's budget."""
        residual = self.model.window_residual_function(
            model.physical, fr.xs, fr.ys, fr.target, fr.valid, fr.inv_scale, fr.ex, fr.ey,
            charge=None if self._budget is None else self._budget.charger())
        if self.options.jacobian == "fd":
            residual = _forward_difference(residual)
        return residual

    def _problem(self, strain: np.ndarray, model: Model, mask: np.ndarray | None):
        """The least-squares problem on this frame: ``(residual, clean frame, peak, peak index,
        window, usable points, window strains in units of their sd)``, or a FitResult saying
        why there is none."""
        fr = self._window(strain, model, mask)
        if isinstance(fr, FitResult):
            return fr
        return (self._residual(fr, model), fr.clean, fr.peak, fr.peak_idx, fr.win, fr.n_points,
                fr.zdata)

    def _frame(self, strain: np.ndarray, mask: np.ndarray | None) -> _Frame | FitResult:
        """What every model's problem on this frame shares (computed once per :meth:`fit`,
        which auto's several models reuse), or a FitResult saying there is no problem."""
        key = (id(strain), id(mask))
        if self._frame_memo is not None and self._frame_memo[0] == key:
            return self._frame_memo[1]
        out = self._plain_frame(strain) if mask is None else None
        if out is None:
            out = self._general_frame(strain, mask)
        if self._deadline is not None or self._in_fit:
            self._frame_memo = (key, out)
        return out

    def _plain_frame(self, strain: np.ndarray) -> _Frame | None:
        """:meth:`_frame` for the common frame (no mask, every tactel usable, a peak above
        ``MIN_PEAK``), its peak and window found in one compiled pass; None otherwise."""
        s = strain if (type(strain) is np.ndarray and strain.dtype == np.float64
                       and strain.flags.c_contiguous) else np.ascontiguousarray(strain, dtype=float)
        if s.shape != self._all_ok.shape:
            return None
        if not self.sensor.model_error.zero:
            usable, m, n, r0, c0, nr, nc = plain_window(s, self.options.window, MAX_STRAIN)
            peak = float(s[m, n])
            if not usable or not peak > MIN_PEAK:
                return None
            return self._window_arrays(s, self._all_ok, (m, n), peak, (r0, c0, nr, nc))
        # the common sensor: the window's arrays in the same compiled pass
        usable, m, n, r0, c0, nr, nc, peak, target, valid, inv_scale, zdata = plain_frame(
            s, self.options.window, MAX_STRAIN, MIN_PEAK, self.sigma)
        if not usable:
            return None
        win = (r0, c0, nr, nc)
        ex, ey = self._window_shift(win, nr, nc)
        return _Frame(s, (m, n), peak, win, self.model.xs_full[r0:r0 + nr],
                      self.model.ys_full[c0:c0 + nc], target, valid, nr * nc, inv_scale, zdata, ex, ey)

    def _general_frame(self, strain: np.ndarray, mask: np.ndarray | None) -> _Frame | FitResult:
        clean, ok = self._prepare(strain, mask)
        g = self.sensor.geometry
        if clean.shape != (g.rows, g.cols):
            raise ValueError(f"frame shape {clean.shape} does not match the sensor's {(g.rows, g.cols)}")
        out: _Frame | FitResult
        if not ok.any():
            out = FitResult(contact=False, message="no usable tactels", reasons={"frame": "all tactels masked"})
        else:
            flat = int(np.argmax(clean if ok is self._all_ok else np.where(ok, clean, -np.inf)))
            peak_idx = divmod(flat, clean.shape[1])
            peak = float(clean[peak_idx])
            if not peak > MIN_PEAK:
                out = FitResult(contact=False, peak=peak, message=f"no strain above {MIN_PEAK:g}")
            else:
                out = self._window_arrays(clean, ok, peak_idx, peak,
                                          choose_window(clean, peak_idx, self.options.window))
        return out

    def _window_arrays(self, clean: np.ndarray, ok: np.ndarray, peak_idx: tuple[int, int], peak: float,
                       win: tuple[int, int, int, int]) -> _Frame:
        r0, c0, nr, nc = win
        target = clean[r0:r0 + nr, c0:c0 + nc].flatten()
        valid = ok[r0:r0 + nr, c0:c0 + nc].flatten()
        if self.sensor.model_error.zero:
            inv_scale = np.full(target.size, 1.0 / peak)
            zdata = (target if ok is self._all_ok else target[valid]) / self.sigma
        else:
            # each tactel weighted by its noise plus the model-error floor (relative to the
            # noise, so chi^2 = cost (peak/sigma)^2 still holds)
            sd = self._tactel_sd(target)
            inv_scale = (1.0 / peak) * (self.sigma / sd)
            zdata = target[valid] / sd[valid]
        ex, ey = self._window_shift(win, nr, nc)
        return _Frame(clean, peak_idx, peak, win, self.model.xs_full[r0:r0 + nr],
                      self.model.ys_full[c0:c0 + nc], target, valid, int(valid.sum()), inv_scale,
                      zdata, ex, ey)

    def _tactel_sd(self, strain: np.ndarray) -> np.ndarray:
        """Standard deviation (strain) of each tactel's reading about the model: the sensor
        noise and the model-error floor (``sensor.model_error``) in quadrature."""
        me = self.sensor.model_error
        return np.sqrt(self.sigma**2 + me.strain**2 + (me.relative * strain) ** 2)

    def _good_enough(self, sol: SolveResult, peak: float, n_points: int) -> bool:
        """Residual consistent with sensor noise (chi^2 per point under ~4 with slack for
        model error), so further starts cannot be expected to help."""
        if not math.isfinite(sol.cost):
            return False
        chi2 = sol.cost * peak * peak / (self.sigma * self.sigma)
        return chi2 <= 4.0 * n_points + 1e-4 * n_points * (peak / self.sigma) ** 2

    def _consistent(self, res: FitResult) -> bool:
        """chi^2 within 3 standard deviations of its expectation for a correct model (its
        own parameters: a flat array's line contact, reported as a cylinder, has four)."""
        k = len(res.params) if res.params is not None else get_model(res.model).size
        n = res.n_points
        dof = max(n - k, 1)
        return res.chi2 <= dof + 3.0 * math.sqrt(2.0 * dof)

    def _cold_starts(self, strain: np.ndarray, peak_idx: tuple[int, int], model: Model) -> list[np.ndarray]:
        # interpolated_peak, force_estimate and features in one compiled call
        x0, y0, f0, feat = start_point(strain, peak_idx[0], peak_idx[1], float(strain.sum()),
                                       *self._force_constants)
        if self._starts is None:
            self._starts = start_table(self.sensor)
        cands = self._starts.candidates(feat, count=self.options.max_starts)
        out = []
        for c in cands:
            if model.name == "general":
                out.append(model.from_values(c.radius, c.radius / 0.04, c.psi_deg, f0, x0, y0))
            else:
                out.append(model.from_values(c.radius, math.inf, c.psi_deg, f0, x0, y0))
            if model.name == "sphere":
                break  # orientation plays no part
        return out

    def _result(self, model: Model, sol: SolveResult, peak: float, win, n_points: int, starts: int,
                zdata: np.ndarray, valid: np.ndarray) -> FitResult:
        reasons: dict[str, str] = {}
        values, std, condition = self._uncertainty(model, sol.p, sol.jacobian * peak, reasons)
        chi2 = sol.cost * peak * peak / self.sigma**2
        stopped = self._stopped(sol)
        if condition is not None and std.get("x_mm") is not None:
            self._mismatch(model, sol, peak, zdata, chi2, std, reasons, win, valid, learn=not stopped)
        if stopped:
            self._unsettled(sol, peak, values, std, reasons)
        tied = self._tied_force(model, sol, values, std)  # before the radius may be withheld
        self._unobservable(values, std, reasons)
        if model.name == "cylinder":
            reasons.setdefault("r2_mm", "infinite: cylinder model")
        if model.name == "sphere":
            reasons.setdefault("angle_deg", "undefined: sphere model")
        if model.name == "general" and values.get("r2_mm") is None:
            reasons.setdefault("r2_mm", "infinite: fitted as a cylinder")
        ell = Ellipse(*compiled.ellipse_at(compiled.KINDS[model.name], sol.p, self.model._rf,
                                           self.model._k))
        line = ell.a >= 0.0 and self._line_contact(ell, values, std, reasons)
        if tied is not None and values.get("force_n") is not None:  # else withheld for another reason
            values["force_n"] = std["force_n"] = None
            reasons["force_n"] = tied
        if not sol.converged:
            reasons.setdefault("fit", sol.message)
        rms = math.sqrt(sol.cost / max(n_points, 1))
        return FitResult(
            contact=True,
            model=model.name,
            label="line" if line else self._label(values, model.name),
            values=values,
            std=std,
            rms=rms,
            chi2=chi2,
            iterations=sol.iterations,
            evaluations=sol.evaluations,
            converged=sol.converged,
            condition=condition,
            peak=peak,
            n_points=n_points,
            window=win,
            starts=starts,
            message=sol.message,
            reasons=reasons,
            params=tuple(sol.p.tolist()),
            ellipse=({"a_mm": ell.a, "b_mm": ell.b, "theta_deg": math.degrees(ell.theta) % 180.0}
                     if ell.a >= 0.0 else None),  # a < 0: an infinite line (an invalid start)
        )

    def _uncertainty(
        self, model: Model, p: np.ndarray, jraw: np.ndarray, reasons: dict[str, str]
    ) -> tuple[dict[str, float | None], dict[str, float | None], float | None]:
        """User-unit values at ``p``, their Cramer-Rao 1-sigma bounds from ``jraw`` (the
        Jacobian of the window strains, unnormalised) and the condition number of J."""
        values, grad = model.report(p)
        std: dict[str, float | None] = dict.fromkeys(VALUE_KEYS)
        sd, condition = crb_kernel(jraw if jraw.flags.c_contiguous else np.ascontiguousarray(jraw),
                                   grad, self.sigma)
        if not math.isfinite(condition) or condition > SINGULAR_CONDITION:
            for k in VALUE_KEYS:
                reasons[k] = "Jacobian singular: parameter not identifiable from this window"
            return values, std, (condition if math.isfinite(condition) else None)
        for k, v in zip(VALUE_KEYS, sd.tolist()):
            if v >= 0.0 and values.get(k) is not None:  # NaN (no such quantity) fails
                std[k] = v
        if condition > ILL_CONDITION:
            reasons["condition"] = f"ill-conditioned fit (condition number {condition:.3g})"
        return values, std, condition

    def _tied_force(self, model: Model, sol: SolveResult, values: dict[str, float | None],
                    std: dict[str, float | None]) -> str | None:
        """Why the force rests on a radius the window does not resolve
        (:func:`tactiled.fit.params.radius_tied_force`), or None: the radius's 1-sigma bound
        as reported, the correlation from the Cramer-Rao covariance at the solution."""
        r, sd_r, sd_f = values.get("r1_mm"), std.get("r1_mm"), std.get("force_n")
        if r is None or sd_r is None or sd_f is None or sd_r < r or sol.jacobian.size == 0:
            return None  # the common case: the radius is bounded away from zero
        try:
            cov = np.linalg.inv(sol.jacobian.T @ sol.jacobian)
        except np.linalg.LinAlgError:
            return None
        _, grad = model.report(sol.p)
        g_f, g_r = grad[VALUE_KEYS.index("force_n")], grad[VALUE_KEYS.index("r1_mm")]
        # the correlation only: the common scale of the covariance cancels
        c_ff, c_rr, c_rf = g_f @ cov @ g_f, g_r @ cov @ g_r, g_r @ cov @ g_f
        if not (c_ff > 0.0 and c_rr > 0.0):
            return None
        return radius_tied_force(r, sd_r, sd_f, float(c_rf / math.sqrt(c_rr * c_ff)) * sd_r * sd_f)

    def _unsettled(self, sol: SolveResult, peak: float, values: dict[str, float | None],
                   std: dict[str, float | None], reasons: dict[str, str]) -> None:
        """A fit its budget stopped is not at the least-squares minimum.  How far it is, the
        Gauss-Newton step at the stopping point says: it would lower chi^2 by ``D``, and moves
        each value by at most ``sqrt(D)`` of its Cramer-Rao sigma (Cauchy-Schwarz in the
        metric ``J^T J``).  Within ``MAX_REMAINING_CHI2`` every sigma becomes
        ``(1 + sqrt(D))`` times itself, covering that distance on top of the minimum's own
        error; beyond it (where the linear picture that bound rests on fails) the values are
        withheld."""
        if sol.jacobian.size == 0 or not math.isfinite(sol.cost):
            remaining = math.inf
        else:
            step = np.linalg.lstsq(sol.jacobian, -sol.residual, rcond=None)[0]
            moved = sol.jacobian @ step
            remaining = float(moved @ moved) * (peak / self.sigma) ** 2
        said = sol.message if sol.message.startswith(EXHAUSTED) else f"{EXHAUSTED} ({sol.message})"
        why = f"{said}: the fit stopped short of the least-squares minimum"
        if not math.isfinite(remaining) or remaining > fit_budget.MAX_REMAINING_CHI2:
            for k in VALUE_KEYS:
                if values.get(k) is not None:
                    values[k] = None
                    std[k] = None
                    reasons[k] = f"{why} (chi^2 {remaining:.3g} above it): not a measurement"
            reasons["fit"] = f"{why} (chi^2 {remaining:.3g} above it): values withheld"
            return
        widen = 1.0 + math.sqrt(remaining)
        for k in VALUE_KEYS:
            if std.get(k) is not None:
                std[k] *= widen
        reasons["fit"] = (f"{why} (chi^2 {remaining:.3g} above it): uncertainties widened "
                          f"{widen:.3g}x to cover the distance")

    def _mismatch(self, model: Model, sol: SolveResult, peak: float, zdata: np.ndarray,
                  chi2: float, std: dict[str, float | None], reasons: dict[str, str],
                  win: tuple[int, int, int, int], valid: np.ndarray, learn: bool = True) -> None:
        """Widen the uncertainties of a fit when residuals say the finger departs from its
        model (see :mod:`tactiled.fit.floor`): by what the sensor's recent fits have shown
        together, and by this frame's own excess when its chi^2 is beyond what the noise gives
        ``MISMATCH_LEVEL`` of the time.  Tactel ``i`` then has variance
        ``V_i = 1 + tau_s^2 z_i^2 + tau_g^2 |grad z_i|^2`` (units of its noise), and the
        covariance becomes the sandwich ``A^-1 J^T V J A^-1``, ``A = J^T J``: what the estimate
        really scatters by under that variance."""
        n, k = sol.jacobian.shape
        dof = n - k
        if dof < 1:
            return
        flagged = chi2 > _chi2_limit(dof)
        if not (flagged or self.options.learn_floor):
            return  # the common case of a lone fit that matches its model: nothing to do
        z = peak / self.sigma
        jz = sol.jacobian * z  # residual Jacobian in units of each tactel's sd
        rz = sol.residual * z
        try:
            ainv = np.linalg.inv(jz.T @ jz)
        except np.linalg.LinAlgError:
            return
        resid_op = np.eye(n) - jz @ ainv @ jz.T  # M = I - H: residuals are M times the errors
        lev = np.diag(resid_op).copy()  # M_ii = 1 - h_ii
        m2 = zdata * zdata
        g2 = jz[:, -2] ** 2 + jz[:, -1] ** 2  # every model's last two parameters are x0, y0
        msq = resid_op * resid_op
        rows = np.stack((msq @ m2, msq @ g2), axis=1)
        excess_i = rz * rz - lev
        excess = float(excess_i.sum())
        s_f, g_f = float(rows[:, 0].sum()), float(rows[:, 1].sum())
        ts, tg = self.floor.taus()
        corrections = None  # what the flat field's own uncertainty adds to the window's errors
        if not self.options.learn_floor:
            ts = tg = 0.0
        else:
            learning = learn and not self.frozen  # not from a fit its budget stopped short
            if learning:
                weight = self._learn(rows, excess_i, excess, s_f, g_f, dof, ts, tg)
            if self.flat is not None:
                r0, c0, nr, nc = win
                ii, jj = np.divmod(np.flatnonzero(valid), nc)
                tactels = (r0 + ii) * self.flat.cols + (c0 + jj)
                args = (tactels, zdata + rz, jz[:, -2], jz[:, -1])
                corrections = self.flat.error_covariance(*args)  # of the corrections in use
                if learning:
                    self.flat.add(*args[:1], resid_op, *args[1:], rz, weight)
        source = f"the sensor's last ~{self.floor.memory} fits"
        if flagged:
            expected = ts * s_f + tg * g_f
            if expected <= 0.0:  # nothing pooled yet: this frame's excess as gain-like error
                ts, tg = max(excess, 0.0) / max(s_f, 1e-300), 0.0
                source = "this frame's residuals"
            elif excess > expected:
                ts, tg = ts * excess / expected, tg * excess / expected
                source = "this frame's residuals"
        if ts <= 0.0 and tg <= 0.0 and corrections is None:
            return
        var = 1.0 + ts * m2 + tg * g2
        cov = ainv @ (jz.T * var) @ jz @ ainv
        if corrections is not None:
            cov += ainv @ jz.T @ corrections @ jz @ ainv
        _, grad = model.report(sol.p)
        for i, key in enumerate(VALUE_KEYS):
            if std.get(key) is None:
                continue
            v = float(grad[i] @ cov @ grad[i])
            if math.isfinite(v) and v > std[key] ** 2:
                std[key] = math.sqrt(v)
        reasons["uncertainty"] = (
            f"residuals exceed the noise (from {source}; chi^2 here {chi2:.3g} for {dof} degrees "
            f"of freedom): the finger departs from its model by ~{100 * math.sqrt(ts):.2g} % of "
            f"the strain and ~{1000 * math.sqrt(tg):.2g} um of tactel position"
            + ("" if corrections is None else
               " beyond the tactel gains and positions learned from its fits (and their own uncertainty)")
            + "; uncertainties widened to match"
            + (f" (flat field: {self.flat.note})" if corrections is not None else ""))

    def _learn(self, rows: np.ndarray, excess_i: np.ndarray, excess: float, s_f: float, g_f: float,
               dof: int, ts: float, tg: float) -> float:
        """Feed one fit to the floor learner.  Every fit feeds it (leaving out the flagged
        ones, the heavy frames, would bias it low), scaled down to a cap near what the pool
        already expects, so one contact far outside the model (an edge the size of the array)
        moves it by a bounded step.  Returns the scale (<= 1), for the flat field's weight."""
        cap = OUTLIER_FACTOR * (ts * s_f + tg * g_f + math.sqrt(2.0 * dof))
        scale = 1.0
        if excess > cap:
            scale = cap / excess
            excess_i = excess_i * scale
        self.floor.add(rows, excess_i, dof)
        return scale

    def cramer_rao(self, strain: np.ndarray, model: str, params: np.ndarray) -> dict[str, float | None]:
        """1-sigma Cramer-Rao bounds (user units) at the parameter vector ``params`` of
        ``model``, for the window this fitter would choose on ``strain`` (e.g. at the truth of
        a simulated frame: what an efficient estimator could achieve)."""
        prob = self._problem(strain, get_model(model), None)
        if isinstance(prob, FitResult):
            return dict.fromkeys(VALUE_KEYS)
        residual, peak = prob[0], prob[2]
        _, jac = residual(np.asarray(params, dtype=float))
        return self._uncertainty(get_model(model), np.asarray(params, dtype=float), jac * peak, {})[1]

    def line_cramer_rao(self, strain: np.ndarray, contact: LineContact,
                        window: int | None = None) -> dict[str, float | None]:
        """1-sigma Cramer-Rao bounds of a line contact (a cylinder on a flat array) at the
        truth ``contact``, for the window this fitter would choose on ``strain`` (with
        ``window``: a square window of that side on the ridge,
        :func:`tactiled.fit.linewindow.square_window`): ``r1_mm``, ``angle_deg``, ``x_mm``,
        ``y_mm``, ``load_n_per_mm`` and ``offset_mm``."""
        fr = line_frame(self, self.flattened(strain), None, window)
        keys = ("x_mm", "y_mm", "r1_mm", "angle_deg", "load_n_per_mm", "offset_mm")
        if isinstance(fr, FitResult):
            return dict.fromkeys(keys)
        prob = self._line_problem(fr)
        psi = contact.psi
        c = -math.sin(psi) * (contact.x0 - prob.ref[0]) + math.cos(psi) * (contact.y0 - prob.ref[1])
        p = np.array([math.log(contact.r1), psi, math.log(contact.load), c])
        _, jac = prob.residual_and_jacobian(p)
        cov, _ = _covariance(jac * fr.peak, self.sigma)
        _, std, line = prob.report(p, cov)
        return {**{k: std[k] for k in keys[:4]}, "load_n_per_mm": line["load_n_per_mm_std"],
                "offset_mm": line["offset_mm_std"]}

    def _line_frame(self, strain: np.ndarray, mask: np.ndarray | None) -> _Frame | FitResult:
        """The line model's window: the tactels that see the line, along its whole length
        (:func:`tactiled.fit.linewindow.line_frame`)."""
        return line_frame(self, strain, mask)

    def _line_problem(self, fr: _Frame) -> LineProblem:
        return LineProblem(self.sensor, fr.xs, fr.ys, fr.ex, fr.ey, fr.target, fr.valid,
                           fr.inv_scale, self.options.tol)

    def _unobservable(self, values: dict, std: dict, reasons: dict[str, str]) -> None:
        """Withhold what the data cannot pin down rather than report confident nonsense.

        A radius or force whose Cramer-Rao sigma exceeds ``POOR_RELATIVE_SIGMA`` of it is
        flagged; beyond ``UNOBSERVABLE_RELATIVE_SIGMA`` (or beyond the options' withholding
        threshold, for a radius), or an orientation uncertain by more than ``MAX_ANGLE_SIGMA``,
        it becomes None with the reason.  (A vanishing radius can look "certain" in absolute
        terms: its sigma shrinks with it; relative sigma is the honest test.)
        """
        g = self.sensor.geometry
        x, y = values.get("x_mm"), values.get("y_mm")
        inside = (
            x is not None and y is not None
            and -g.dx <= x <= g.span_x + g.dx and -g.dy <= y <= g.span_y + g.dy
        )
        if not inside:
            reasons["model"] = "contact centre outside the array: only the tail of the response is seen"
        withhold = self.options.withhold_relative_sigma
        for k in ("r1_mm", "r2_mm", "force_n"):
            v, sd = values.get(k), std.get(k)
            if v is None:
                continue
            rel = (sd / v) if (sd is not None and v > 0) else math.inf
            is_radius = k != "force_n"
            what = "radius" if is_radius else "force"
            # beyond 100 times the value the figure is noise of a degenerate solve (it differed
            # in its leading digits between CPUs): say so, not the digits
            pct = ("unbounded" if math.isinf(rel) else "over 10000 %" if rel > 100.0
                   else f"{100 * rel:.0f} %")
            cause = TOO_LIGHT if inside and is_radius else "not observable from this window"
            degenerate = rel > UNOBSERVABLE_RELATIVE_SIGMA or (
                is_radius and not RADIUS_LIMITS[0] <= v <= RADIUS_LIMITS[1])
            if degenerate or (is_radius and withhold is not None and rel > withhold):
                values[k] = None
                std[k] = None
                reasons[k] = f"{cause}: the Cramer-Rao sigma of the {what} is {pct} of it"
            elif rel > POOR_RELATIVE_SIGMA:
                reasons[k] = f"poorly determined ({cause}): the Cramer-Rao sigma is {pct} of it"
        a, sa = values.get("angle_deg"), std.get("angle_deg")
        if a is not None and (sa is None or sa > MAX_ANGLE_SIGMA):
            values["angle_deg"] = None
            std["angle_deg"] = None
            reasons["angle_deg"] = "orientation not observable: Cramer-Rao sigma above 45 deg"

    def _line_contact(self, ell, values: dict, std: dict, reasons: dict[str, str]) -> bool:
        """The paper's stated failure case (secs. 5, 8.2): an indentor nearly parallel to the
        finger axis (or nearly flat) makes a Hertz ellipse longer than the finger.  The planar model assumes the
        contact lies on an infinite plane; the real finger ends, and in the window the contact
        is a ridge of constant section, so its radius, its total force and its centre along the
        ridge are not measurable.  Those become None with the reason; the ridge's direction
        and its position across the finger stay.  Returns True for such a line contact.

        Any other contact longer than the array is kept but flagged (``reasons["model"]``).
        """
        g = self.sensor.geometry
        c, s = abs(math.cos(ell.theta)), abs(math.sin(ell.theta))
        extent = c * g.span_x + s * g.span_y  # the array's length along the major axis
        if 2.0 * ell.a <= extent:
            return False
        along_finger = c >= math.cos(math.radians(LINE_CONTACT_ANGLE))
        if not (along_finger and 2.0 * ell.a > LINE_CONTACT_LENGTH * extent):
            reasons["model"] = (
                f"contact ellipse {2 * ell.a:.1f} mm long exceeds the array ({extent:.1f} mm along "
                "it): outside the planar model"
            )
            return False
        why = (f"line contact along the finger axis (an indentor nearly parallel to it, or nearly "
               f"flat): the Hertz ellipse ({2 * ell.a:.1f} mm) runs off the array ({extent:.1f} mm), "
               "where the planar model does not hold (paper secs. 5, 8.2)")
        reasons["model"] = why
        for k, what in (("r1_mm", "radius not observable"), ("r2_mm", "radius not observable"),
                        ("force_n", "part of the contact lies beyond the array"),
                        ("x_mm", "the centre along the line is not defined")):
            if values.get(k) is not None or k == "r1_mm":
                values[k] = None
                std[k] = None
                reasons[k] = f"{what}: {why}"
        return True

    def _label(self, values: dict[str, float | None], model_name: str) -> str:
        """Paper Table 2 vocabulary: 'edge' (R1 < 1 mm), 'plane' (both radii beyond the
        array's span), else the model name."""
        r1, r2 = values.get("r1_mm"), values.get("r2_mm")
        if r1 is not None and r1 < 1.0:
            return "edge"
        if r1 is not None and r1 > self._span and (r2 is None or r2 > self._span):
            return "plane"
        return model_name

    def _solve_line(self, strain: np.ndarray, scout: FitResult, mask: np.ndarray | None) -> FitResult:
        """The line fully solved from where its scout stopped, counting the scout's
        iterations and evaluations."""
        full = self._fit_line(strain, np.asarray(scout.params), mask, start_chi2=scout.chi2)
        full.iterations += scout.iterations
        full.evaluations += scout.evaluations
        return full

    def _criteria(self, fits: list[FitResult], cyl: FitResult, strain: np.ndarray,
                  mask: np.ndarray | None) -> dict[str, float]:
        """Each fit's BIC with known noise, ``chi^2 + k ln n`` (Schwarz), by model.  On a flat
        array the point models' chi^2 is taken on the line's band, so that models are compared
        on the same tactels."""
        flat = self.sensor.geometry.flat
        crit = {}
        for r in fits:
            k = len(r.params) if r.params is not None else get_model(r.model).size
            chi2, n = r.chi2, r.n_points
            if flat and r is not cyl and cyl.window != r.window:  # compared on the line's band
                chi2, n = chi2_on_band(self, strain, mask, r.model, r.params)
            crit[r.model] = (chi2 if chi2 is not None else math.inf) + k * math.log(max(n, 2))
        return crit

    def _cut_short(self, cyl: FitResult, fits: list[FitResult]) -> FitResult:
        """Auto's answer when its budget ran out while it scouted the other models: the
        cylinder, fully solved, with every search's iterations and evaluations; the scouts,
        unfinished, cannot be ranked.  ``fit`` says the choice stopped short."""
        cyl.iterations = sum(r.iterations for r in fits)
        cyl.evaluations = sum(r.evaluations for r in fits)
        return cyl

    # ------------------------------------------------------------------------------------
    def _fit_auto(self, strain: np.ndarray, mask: np.ndarray | None,
                  warm: tuple[str, tuple[float, ...]] | None = None) -> FitResult:
        """Fit all three models and keep the lowest BIC with known noise,
        ``chi^2 + k ln n`` (Schwarz): a parameter must buy more than ``ln n`` of chi^2.

        With ``warm`` (the previous frame's model and parameters) only that model is fitted,
        from there, and kept if its chi^2 is consistent with the noise."""
        if warm is not None and warm[0] in ("cylinder", "sphere", "general") and warm[1]:
            p_warm = np.asarray(warm[1], dtype=float)
            kept = (self._fit_cylinder(strain, p_warm, mask) if warm[0] == "cylinder"
                    else self._fit_model(strain, get_model(warm[0]), p_warm, mask))
            # (an ellipse running off a flat array is the line: chosen afresh, as a cold fit would)
            if kept.contact and kept.chi2 is not None and kept.peak and self._consistent(kept) \
                    and not self._runs_off(kept):
                kept.message = f"model {warm[0]} kept from the previous frame; {kept.message}"
                return kept
        held = self._budget.hold(0.5) if self._budget is not None else None
        flat = self.sensor.geometry.flat
        cyl = self._fit_line(strain, None, mask, scout_first=True) if flat \
            else self._fit_cylinder(strain, None, mask)
        scouted = flat and self._line_scouted and cyl.params is not None
        if held is not None:
            self._budget.release(held)
        if not cyl.contact or cyl.chi2 is None or cyl.params is None or self._out_of_time():
            return cyl
        if self._line_explains(cyl):
            cyl.message = f"the line explains the window to the noise: no other model tried; {cyl.message}"
            return cyl
        fits = [cyl]
        ln_r, psi, ln_f, x0, y0 = self._cylinder_as_point(cyl)
        sph = self._fit_model(strain, get_model("sphere"), np.array([ln_r, ln_f, x0, y0]), mask,
                              scouting=True)
        fits.append(sph)
        if self._out_of_time():
            return self._cut_short(cyl, fits)
        gen_model = get_model("general")
        gen_starts: list[tuple[np.ndarray, float | None]] = [
            (np.array([ln_r, 0.2, psi, ln_f, x0, y0]), None)]
        if sph.params is not None:
            s_ln_r, s_ln_f, sx, sy = sph.params
            # nearly the sphere's own contact: about the sphere's chi^2 (Budget.grant_cost)
            gen_starts.append((np.array([s_ln_r, 0.95, 0.5 * math.pi, s_ln_f, sx, sy]), sph.chi2))
        gens = [self._fit_model(strain, gen_model, p0, mask, scouting=True, start_chi2=c0)
                for p0, c0 in gen_starts]
        fits.append(min(gens, key=lambda r: r.chi2 if r.chi2 is not None else math.inf))
        if self._out_of_time():
            return self._cut_short(cyl, [cyl, sph, *gens])
        crit = self._criteria(fits, cyl, strain, mask)
        best = min(fits, key=lambda r: crit[r.model])
        if best.model == "general" and best.params is not None and not self._out_of_time():
            # The general's two extra parameters must buy their ln n each against the sphere
            # at its best, not against a scout that stopped in another valley (started from
            # the cylinder's point it can end far above the noise on a weak ball: chi^2 190
            # where the sphere from the general's own point reaches 30). The sphere from there.
            ln_ra, _, _, g_ln_f, gx, gy = best.params
            again = self._fit_model(strain, get_model("sphere"),
                                    np.array([ln_ra, g_ln_f, gx, gy]), mask, scouting=True)
            if again.chi2 is not None and (sph.chi2 is None or again.chi2 < sph.chi2):
                again.iterations += sph.iterations
                again.evaluations += sph.evaluations
                fits[1] = sph = again
                crit = self._criteria(fits, cyl, strain, mask)
                best = min(fits, key=lambda r: crit[r.model])
        if best is not cyl and self._runs_off(best):
            best = cyl  # an ellipse longer than the array is the line the cylinder model fits
        iterations = sum(r.iterations for r in fits)
        evaluations = sum(r.evaluations for r in fits)
        resolved = best is not cyl and best.params is not None
        if best is cyl and scouted and not self._out_of_time():  # the line, scouted: solve it
            best = self._solve_line(strain, cyl, mask)
            iterations += best.iterations - cyl.iterations
            evaluations += best.evaluations - cyl.evaluations
        if resolved:  # scouted: now solve it fully
            best = self._fit_model(strain, get_model(best.model), np.asarray(best.params), mask,
                                   start_chi2=best.chi2)
            iterations += best.iterations
            if self._runs_off(best):
                best, resolved = cyl, False
        best.criterion = {k: float(v) for k, v in crit.items() if math.isfinite(v)}
        best.iterations = iterations
        best.evaluations = evaluations + (best.evaluations if resolved else 0)
        return best

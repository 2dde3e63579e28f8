"""The curvature fitter: a strain frame in, a FitResult out (paper secs. 6-7).

``Fitter`` holds one sensor's state (its forward model, window frames, the fit's budget, the
learned model-error floor and flat field) and hands each model to its strategy: a
:class:`~tactiled.fit.point.PointFit` per point-contact model, the
:class:`~tactiled.fit.linefit.LineFit` on a flat array, the
:class:`~tactiled.fit.auto.ModelSelector` for ``auto``; every result then passes the one rule
(:func:`tactiled.fit.verdict.judge_values`).  No I/O here, and nothing raises on bad data:
every outcome is a FitResult.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from tactiled.sensors.model import SensorModel
from tactiled.fit import budget as fit_budget
from tactiled.fit import flatfield, search, uncertainty
from tactiled.fit.auto import ModelSelector
from tactiled.fit.budget import EXHAUSTED, Budget
from tactiled.fit.flatfield import FlatField
from tactiled.fit.floor import FloorLearner
from tactiled.fit.line import LineProblem
from tactiled.fit.linefit import LineFit
from tactiled.fit.models import MODELS, VALUE_KEYS, Model, get_model
from tactiled.fit.point import PointFit
from tactiled.fit.result import FitResult
from tactiled.fit.search import bounds_of, forward_difference, steps_of
from tactiled.fit.solver import SolveResult, levenberg_marquardt
from tactiled.fit.start import StartTable, force_constants, start_table
from tactiled.fit.verdict import ArrayLimits, judge_values
from tactiled.fit.window import choose_window, plain_frame, plain_window
from tactiled.physics.contact import Contact, LineContact
from tactiled.physics.quadrature_rules import warm_rules
from tactiled.physics.strain import StrainModel

#: A peak below this is no contact at all (far below any sensor's noise).
MIN_PEAK = 1e-9
#: Strain magnitudes above this are broken readings, not contact (1000 % compression).
MAX_STRAIN = 10.0
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


class Fitter:
    """Fits contact models to strain frames of one sensor."""

    def __init__(
        self, sensor: SensorModel | None = None, options: FitOptions | None = None, warm: bool = True
    ) -> None:
        self.sensor = sensor or SensorModel()
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
        #: a frozen fit's profile tests wait for :meth:`finish` (:meth:`deferring`)
        self._deferring = False
        #: :meth:`deferring` takes effect (off: every fit's tests run at once)
        self.defer_tests = True
        self._tails: list[tuple[FitResult, Callable[[], None]]] = []
        self._deferred: dict[int, tuple[FitResult, Callable[[], None]]] = {}
        self._frame_memo: tuple[tuple[int, int], _Frame | FitResult] | None = None
        #: a window set for the next fits (:meth:`on_window`), else None: the options' square
        self._window_at: tuple[int, int, int, int] | None = None
        self._starts: StartTable | None = None  # start_table(sensor), once it is needed
        self._force_constants = force_constants(self.sensor)
        #: what the sensor's recent fits say of its departure from the model (tactiled.fit.uncertainty.mismatch)
        self.floor = FloorLearner()
        #: each tactel's gain and position as this finger's fits show them (tactiled.fit.uncertainty.mismatch)
        self.flat = (FlatField(g.rows, g.cols)
                     if self.options.learn_floor and g.rows * g.cols <= flatfield.MAX_TACTELS else None)
        #: use what was learned, learn no more (:meth:`adopt`)
        self.frozen = False
        #: the strategies: one per point-contact model, the line (a flat array's cylinder)
        #: and the model selector
        self.points = {name: PointFit(self, spec) for name, spec in MODELS.items()}
        self.line = LineFit(self)
        self.selector = ModelSelector(self)
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
            self.line.fit(frame, None, None)
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
                levenberg_marquardt(self._residual(fr, model), p0, max_step=steps_of(model),
                                    max_iter=2, bounds=bounds_of(model), verdict_tol=1e-12)
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
        self._budget = self._new_budget()
        self._in_fit = True
        if frames != 1:
            if not (isinstance(frames, int) and frames >= 1):
                raise ValueError(f"frames must be a positive whole number, got {frames!r}")
            self.sigma = self._sigma1 / math.sqrt(frames)
        strain = self.flattened(strain)
        try:
            if model == "auto":
                res = self.selector.fit(strain, mask, warm)
            else:
                get_model(model)  # ValueError naming the choices
                if start is None and warm is not None and warm[0] == model and warm[1]:
                    start = np.asarray(warm[1], dtype=float)
                res = (self._fit_cylinder(strain, start, mask) if model == "cylinder"
                       else self._fit_model(strain, get_model(model), start, mask))
            tail = next((t for r, t in self._tails if r is res), None)
            if tail is not None:
                self._deferred[id(res)] = (res, self._finisher(res, tail, self._budget, self._deadline))
                res.fit_ms = (time.perf_counter() - t0) * 1e3
                return res
            self._exhausted(res)
        finally:
            self._deadline = None
            self.spent = (self._budget.used_iterations, self._budget.used_work)
            self._budget = None
            self._in_fit = False
            self._tails = []
            self.sigma = self._sigma1
            self._frame_memo = None  # the memo must not outlive the frame (ids are reused)
        self._judged(res)
        res.fit_ms = (time.perf_counter() - t0) * 1e3
        return res

    def _new_budget(self) -> Budget:
        """A fit's budget: the options', its work scaled to the window :meth:`on_window` set
        (an evaluation's work is its nodes times the window's tactels, so a window ``k`` times
        the options' square costs ``k`` times as much for the same search)."""
        work, reserve = self.options.budget_work, self.allowance
        if self._window_at is not None and work is not None:
            side = self.options.window
            scale = max(self._window_at[2] * self._window_at[3] / float(side * side), 1.0)
            work, reserve = int(work * scale), reserve * scale
        return Budget(self.budget_limits[0], work, reserve)

    @contextmanager
    def on_window(self, win: tuple[int, int, int, int] | None) -> Iterator[None]:
        """While open, point fits take the window ``win`` (``(row0, col0, rows, cols)``)
        instead of the options' square round the peak, their work budget scaled to it (None:
        the options' square): a contact wider than the window is fitted on all the tactels
        it presses (:func:`tactiled.fit.multi.fit_contacts`)."""
        before = self._window_at
        self._window_at = win
        self._frame_memo = None
        try:
            yield
        finally:
            self._window_at = before
            self._frame_memo = None

    def _exhausted(self, res: FitResult) -> None:
        if self._budget.exhausted and res.converged:
            # a converged search, but the fit's other starts or models were cut short
            res.converged = False
            res.reasons["fit"] = (f"{EXHAUSTED} before the fit ended: the {res.model} fit "
                                  "kept converged, the other starts or models were not tried out")

    def _judged(self, res: FitResult) -> None:
        if res.contact:
            # the one rule before anything leaves the fitter (tactiled.fit.verdict)
            judge_values(res.values, res.std, res.reasons, self.limits, label=res.label,
                         withhold_relative_sigma=self.options.withhold_relative_sigma)
            if "ellipse" in res.reasons:
                res.ellipse = None

    @contextmanager
    def deferring(self, on: bool = True) -> Iterator[None]:
        """While open (``on``) on a fitter that learns nothing (frozen, or ``learn_floor``
        off), a point fit's profile tests, and the one rule after them, wait until
        :meth:`finish` is called on its result: a frame of several contacts refits most of
        the ones it seeks and publishes those refits, so the tests run only on what is
        published.  With nothing learned between a fit and its tests, they see what they
        would have seen at once, within the fit's own budget: the answers are the same."""
        before = self._deferring
        self._deferring = on and self.defer_tests and (self.frozen or not self.options.learn_floor)
        try:
            yield
        finally:
            self._deferring = before
            if not before:
                self._deferred.clear()  # the results never published: their tests never run

    def finish(self, res: FitResult) -> FitResult:
        """``res`` complete: its deferred tests run (:meth:`deferring`), once; any other result
        as it is."""
        entry = self._deferred.pop(id(res), None)
        if entry is not None and entry[0] is res:
            entry[1]()
        return res

    def _finisher(self, res: FitResult, tests: Callable[[], None], budget: Budget,
                  deadline: float | None) -> Callable[[], None]:
        """The rest of :meth:`fit` on ``res``, its tests within its own fit's budget."""
        def run() -> None:
            self._budget, self._deadline, self._in_fit = budget, deadline, True
            try:
                tests()
                self._exhausted(res)
            finally:
                self._budget, self._deadline, self._in_fit = None, None, False
                self._frame_memo = None
            self._judged(res)
        return run

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
        kept = self.line.frames  # a frame of several contacts: each strain and mask prepared once
        last = kept.prepared if kept.frames is not None else None
        if last is not None and last[0] is strain and last[1] is mask:
            return last[2]
        s = np.asarray(strain, dtype=float)
        total = float(np.abs(s).max()) if s.size else 0.0
        if mask is None and total <= MAX_STRAIN:  # the common case (NaN fails the test too)
            return s, self._all_ok if s.shape == self._all_ok.shape else np.ones(s.shape, bool)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(s) & (np.abs(s) <= MAX_STRAIN)
        if mask is not None:
            ok &= np.asarray(mask, dtype=bool)
        out = np.where(ok, s, 0.0), ok
        if kept.frames is not None:
            kept.prepared = (strain, mask, out)
        return out

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
            residual = forward_difference(residual)
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
        kept = self.line.frames  # a frame of several contacts: its windows made once
        held = kept.frames is not None and self._window_at is None
        if held:
            kept_key = kept.key(self, strain, mask)
            out = kept.get(kept_key, point=True)
            if out is not None:
                if self._deadline is not None or self._in_fit:
                    self._frame_memo = (key, out)
                return out
        out = self._plain_frame(strain) if mask is None and self._window_at is None else None
        if out is None:
            out = self._general_frame(strain, mask)
        if self._deadline is not None or self._in_fit:
            self._frame_memo = (key, out)
        if held and isinstance(out, _Frame):  # (a FitResult is an answer: never shared)
            kept.put(kept_key, out, point=True)
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
                out = self._window_arrays(clean, ok, peak_idx, peak, self._window_at
                                          or choose_window(clean, peak_idx, self.options.window))
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

    def cramer_rao(self, strain: np.ndarray, model: str, params: np.ndarray) -> dict[str, float | None]:
        """1-sigma Cramer-Rao bounds (user units) at the parameter vector ``params`` of
        ``model``, for the window this fitter would choose on ``strain`` (e.g. at the truth of
        a simulated frame: what an efficient estimator could achieve)."""
        prob = self._problem(strain, get_model(model), None)
        if isinstance(prob, FitResult):
            return dict.fromkeys(VALUE_KEYS)
        residual, peak = prob[0], prob[2]
        _, jac = residual(np.asarray(params, dtype=float))
        return uncertainty.bounds(self, get_model(model), np.asarray(params, dtype=float), jac * peak,
                                  {})[1]

    def line_cramer_rao(self, strain: np.ndarray, contact: LineContact,
                        window: int | None = None) -> dict[str, float | None]:
        """1-sigma Cramer-Rao bounds of a line contact at the truth ``contact``
        (:meth:`tactiled.fit.linefit.LineFit.cramer_rao`)."""
        return self.line.cramer_rao(strain, contact, window)

    # the strategies, by the names the fit's helpers and tests call them ----------------------
    def _fit_model(self, strain: np.ndarray, model: Model, start: np.ndarray | None,
                   mask: np.ndarray | None, scouting: bool = False,
                   start_chi2: float | None = None) -> FitResult:
        """One point-contact model's fit (:meth:`tactiled.fit.point.PointFit.fit`)."""
        return self.points[model.name].fit(strain, start, mask, scouting, start_chi2)

    def _fit_cylinder(self, strain: np.ndarray, start: np.ndarray | None,
                      mask: np.ndarray | None) -> FitResult:
        """The cylinder model: on a curved finger the Hertz ellipse's; on a flat array a line
        contact's (:mod:`tactiled.fit.linefit`), reported as model 'cylinder', label 'line'."""
        if self.sensor.geometry.flat:
            return self.line.fit(strain, start, mask)
        return self._fit_model(strain, get_model("cylinder"), start, mask)

    def _search(self, fr: _Frame, kind: int, starts: list[np.ndarray], steps: np.ndarray,
                bounds: tuple[np.ndarray, np.ndarray], cap: int, stop_chi2: float,
                python_residual, start_chi2: float | None = None) -> tuple[SolveResult, int]:
        """:func:`tactiled.fit.search.search` on this fitter."""
        return search.search(self, fr, kind, starts, steps, bounds, cap, stop_chi2,
                             python_residual, start_chi2)

    def _consistent(self, res: FitResult) -> bool:
        """:func:`tactiled.fit.search.consistent`: chi^2 within what a right model gives."""
        return search.consistent(self, res)

    def _runs_off(self, res: FitResult) -> bool:
        """:meth:`tactiled.fit.auto.ModelSelector.runs_off`."""
        return self.selector.runs_off(res)

    def _line_frame(self, strain: np.ndarray, mask: np.ndarray | None) -> _Frame | FitResult:
        return self.line.frame(strain, mask)

    def _line_problem(self, fr: _Frame) -> LineProblem:
        return self.line.problem(fr)

    @property
    def _line_scouted(self) -> bool:
        """Auto's line stayed a scout in the last fit (:attr:`LineFit.scouted`)."""
        return self.line.scouted

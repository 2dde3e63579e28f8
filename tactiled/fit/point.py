"""A point contact's fit (paper secs. 6-7): a Hertz ellipse, one object per model.

Residuals are taken over a window around the peak (4x4 by default), normalised by the peak
strain; the search (:mod:`tactiled.fit.search`) works on the model's unconstrained parameters
with the forward model's exact Jacobian.  The cylinder on a curved finger, the sphere and the
general ellipse are each a :class:`PointFit`; a flat array's cylinder is the line
(:mod:`tactiled.fit.linefit`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from tactiled.fit import compiled, search, uncertainty
from tactiled.fit.budget import BudgetExhausted
from tactiled.fit.models import Model, get_model
from tactiled.fit.profile import (PROFILE_SIGMAS, TEST_RELATIVE_SIGMA, WIDENED_BY_RADIUS,
                                  angle_profile, flat_below, place_sigma, r2_profile,
                                  radius_points, round_test, widen_by_points, withhold_flat)
from tactiled.fit.result import FitResult
from tactiled.fit.search import SCOUT_ITERATIONS, STOP_CHI2, bounds_of, steps_of
from tactiled.fit.solver import SolveResult
from tactiled.fit.start import start_point, start_table
from tactiled.physics.hertz import Ellipse

if TYPE_CHECKING:
    from tactiled.fit.fitter import Fitter, _Frame


#: The general model's cold starts: the start table's radius as r1 and this many times less
#: curvature across it (r2 twice r1: the middle of the ellipsoids 1.5-4 times apart that
#: ``tactiled bench --suite sensors`` presses).  A near-cylinder start (r2 25 times r1) made
#: the Hertz ellipse of a hard press (10-25 N on the 12x32 mat under its 1.5 mm cover) many
#: rubber depths long, and its first evaluations spent the fit's base work before the search
#: came near: 25 % of those ellipsoids' fits were stopped by the budget, 10 % from these.
GENERAL_START_BETA2 = 0.5
#: A ball's or an ellipsoid's first cold start on a flat array has this many times the
#: array's width (its smaller extent, edge to edge) for its radius (:meth:`PointFit.cold_starts`):
#: a curvature the array resolves.  On the 6x4 pad of 4 mm pitch under 2 mm (16 mm wide) a
#: light 3 x 11 mm ellipsoid's searches from 6-24 mm all reached the least-squares minimum
#: (80 noise draws each), from 3 mm 3 of 80 stopped on the plateau of a point.
START_RADIUS_SPAN = 1.0
#: Gauss-Newton steps in the log force alone that scale a cold start to its window
#: (:meth:`PointFit.scaled`), each at most ``SCALE_STEP_LN`` (a factor of e^2).
SCALE_STEPS = 2
SCALE_STEP_LN = 2.0
#: What :meth:`PointFit.result` finds beyond where the search ended (:meth:`PointFit.complete`).
WHOLE_FIELDS = ("label", "values", "std", "condition", "reasons", "ellipse")


class PointFit:
    """The fit of one point-contact model (``spec``: cylinder, sphere or general)."""

    def __init__(self, fitter: Fitter, spec: Model) -> None:
        self.fitter = fitter
        self.spec = spec

    def fit(
        self,
        strain: np.ndarray,
        start: np.ndarray | None,
        mask: np.ndarray | None,
        scouting: bool = False,
        start_chi2: float | None = None,
    ) -> FitResult:
        """Fit one model.  ``scouting`` (auto's candidate models) stops at a chi^2 decrease
        below 0.01 and after ``SCOUT_ITERATIONS``: enough to rank models by an information
        criterion, whose differences that matter are units of chi^2; the chosen one is then
        solved fully.  ``start_chi2``: the chi^2 at ``start``, where a scout left it."""
        f, model = self.fitter, self.spec
        fr = f._window(strain, model, mask)
        if isinstance(fr, FitResult):
            return fr
        peak, win, n_points = fr.peak, fr.win, fr.n_points
        starts = [start] if start is not None else self.cold_starts(fr.clean, fr.peak_idx, model, fr)
        cap = SCOUT_ITERATIONS if scouting else f.options.max_iter
        # stop once the next step would lower chi^2 by less than STOP_CHI2 (0.01 scouting): a
        # parameter then moves by under 0.01 of its sigma, and a warm fit saves an evaluation
        best, tried = search.search(f, fr, compiled.KINDS[model.name], starts, steps_of(model),
                                   bounds_of(model), cap, 1e-2 if scouting else STOP_CHI2,
                                   lambda: f._residual(fr, model), start_chi2)
        if scouting:  # only ranked by chi^2, then solved again in full if chosen: no report
            return FitResult(contact=True, model=model.name, chi2=best.cost * peak * peak / f.sigma**2,
                             iterations=best.iterations, evaluations=best.evaluations,
                             converged=best.converged, peak=peak, n_points=n_points, window=win,
                             starts=tried, message=best.message,
                             params=tuple(best.p.tolist()))
        if f._deferring:  # among several: made whole if the result is published (Fitter.finish)
            res = self.searched(model, best, peak, win, n_points, tried)
            f._tails.append((res, lambda: self.complete(fr, model, best, res)))
            return res
        res = self.result(model, best, peak, win, n_points, tried, fr.zdata, fr.valid)
        self.tests(fr, model, best, res)
        return res

    def searched(self, model: Model, sol: SolveResult, peak: float, win, n_points: int,
                 starts: int) -> FitResult:
        """The full solve ``sol`` as a result that says where it ended (its parameters,
        chi^2, window, whether it converged) and nothing more: what a frame of several
        contacts reads of a fit it may refit (its strain, its information criterion, a
        refit's start).  :meth:`complete` makes it whole: the values, sigmas and reasons of
        :meth:`result`, and the profile tests."""
        f = self.fitter
        return FitResult(contact=True, model=model.name, chi2=sol.cost * peak * peak / f.sigma**2,
                         rms=math.sqrt(sol.cost / max(n_points, 1)), iterations=sol.iterations,
                         evaluations=sol.evaluations, converged=sol.converged, peak=peak,
                         n_points=n_points, window=win, starts=starts, message=sol.message,
                         params=tuple(sol.p.tolist()))

    def complete(self, fr, model: Model, sol: SolveResult, res: FitResult) -> None:
        """:meth:`searched`'s ``res`` made whole, in place, as :meth:`fit` makes a result at
        once: :meth:`result`'s values, sigmas, reasons, label and ellipse (what a model
        selector wrote on it since, its message, counts and criterion, stays), then
        :meth:`tests`."""
        whole = self.result(model, sol, res.peak, res.window, res.n_points, res.starts,
                            fr.zdata, fr.valid)
        for name in WHOLE_FIELDS:
            setattr(res, name, getattr(whole, name))
        self.tests(fr, model, sol, res)

    def tests(self, fr, model: Model, best: SolveResult, res: FitResult) -> None:
        """The profile-likelihood tests of the full solve ``best`` on the window ``fr``: each
        value they find flat withheld or its sigma widened in ``res``, in place."""
        f = self.fitter
        r1 = res.values.get("r1_mm")
        if best.converged and r1 is not None and abs(math.log(r1) - best.p[0]) < 1e-9:
            # every model's first parameter is a log radius: r1's, or the general's r_a
            sd_r1 = res.std.get("r1_mm")
            below: list = []
            withhold_flat(res.values, res.std, res.reasons, flat_below(
                f, fr, compiled.KINDS[model.name], best.p, steps_of(model), bounds_of(model),
                lambda: f._residual(fr, model), res.chi2, r1, sd_r1, seen=below))
            if model.name in ("sphere", "general"):
                # a ball fitted too small or too large: its radius's likelihood flat on one
                # side, the place and force that trade with it widened by the profile's points
                # (an ellipsoid's smaller radius alike: on the 6x4 pad of 4 mm pitch under
                # 2 mm the light ones' linearised sigmas of the place covered 76-84 % in two)
                up = radius_points(f, fr, compiled.KINDS[model.name], best.p, steps_of(model),
                                   bounds_of(model), lambda: f._residual(fr, model), res.chi2,
                                   r1, sd_r1)
                widen_by_points(res.values, res.std, res.reasons,
                                [(rise, model.report(q)[0]) for rise, q in below + up],
                                ("r1_mm", "x_mm", "y_mm", "force_n"), WIDENED_BY_RADIUS)
        sd_angle = res.std.get("angle_deg")
        if (best.converged and model.name == "general" and sd_angle is not None
                and PROFILE_SIGMAS * sd_angle < 45.0):
            # an ellipse's orientation on its profile likelihood, as a line's (its third
            # parameter), at the two near points only: turned 90 deg an ellipse with its
            # radii swapped is the same one, so the scan round the half-turn means nothing here
            withhold_flat(res.values, res.std, res.reasons, angle_profile(
                f, fr, compiled.KINDS[model.name], best.p, steps_of(model), bounds_of(model),
                lambda: f._residual(fr, model), res.chi2, 2, sd_angle, scan=(), bounded=True),
                key="angle_deg")
        if best.converged and model.name == "general":
            # a test the budget cuts short is not used, and does not make the fit a stopped one
            budget = f._budget
            spent = budget is None or budget.exhausted
            if res.values.get("angle_deg") is not None:
                # an ellipse not told from a circle has no orientation
                withhold_flat(res.values, res.std, res.reasons, round_test(
                    f, fr, best.p, steps_of(model), bounds_of(model),
                    lambda: f._residual(fr, model), lambda: f._residual(fr, get_model("sphere")),
                    res.chi2, res.values, res.std), key="angle_deg")
            # the larger radius on its profile, both sides (a light ellipsoid's valley where
            # both radii shrink together: tactiled.fit.profile.r2_profile)
            withhold_flat(res.values, res.std, res.reasons, r2_profile(
                f, fr, compiled.KINDS[model.name], best.p, steps_of(model), bounds_of(model),
                lambda: f._residual(fr, model), res.chi2, res.values.get("r2_mm"),
                res.std.get("r2_mm")), key="r2_mm")
            r1, sd_r1 = res.values.get("r1_mm"), res.std.get("r1_mm")
            if f.sensor.geometry.flat and (r1 is None or sd_r1 is None
                                           or sd_r1 > TEST_RELATIVE_SIGMA * r1) \
                    and not f._runs_off(res):
                # an ellipsoid on a flat array whose smaller radius is not resolved to 10 %:
                # its place on its profile likelihood too (tactiled.fit.profile.place_sigma;
                # under the paper's finger's 4.3-6 mm cover a light contact's place does not
                # sharpen with its radius, and its place covers 94-98 % as it is; an ellipse
                # running off the array at both ends is a line there, its place no point's)
                for key, name in (("x_mm", "x0"), ("y_mm", "y0")):
                    withhold_flat(res.values, res.std, res.reasons, place_sigma(
                        f, fr, compiled.KINDS[model.name], best.p, steps_of(model),
                        bounds_of(model), lambda: f._residual(fr, model), res.chi2,
                        model.params.index(name), res.std.get(key)), key=key)
            if not spent:
                budget.exhausted = False

    def cold_starts(self, strain: np.ndarray, peak_idx: tuple[int, int], model: Model,
                    fr: _Frame | None = None) -> list[np.ndarray]:
        """Up to ``max_starts`` starts from the start table's nearest shapes at the peak (a
        ball's or an ellipsoid's on a flat array after one of a curvature the array resolves,
        its force scaled to the window ``fr`` where given: :meth:`scaled`)."""
        f = self.fitter
        # interpolated_peak, force_estimate and features in one compiled call
        x0, y0, f0, feat = start_point(strain, peak_idx[0], peak_idx[1], float(strain.sum()),
                                       *f._force_constants)
        if f._starts is None:
            f._starts = start_table(f.sensor)
        cands = f._starts.candidates(feat, count=f.options.max_starts)
        out = []
        if f.sensor.geometry.flat and model.name in ("sphere", "general") and cands:
            # a flat array's table holds lines (its cylinder), whose radius and the point
            # load's force say little of a ball or an ellipsoid: a 3 x 11 mm ellipsoid at
            # 1.4 N on a 6x4 pad of 4 mm pitch under 2 mm started at a 0.3 mm line and 0.5 N,
            # where the likelihood is flat in the radius (a point to the tactels), and its
            # search stopped there at chi^2 60-170 (the truth's 12-38); a 21 x 82 mm one at
            # 9.5 N started at 85 x 170 mm and 42 N, whose first evaluation spent the fit's
            # base work.  So first a curvature the array resolves (START_RADIUS_SPAN: radius
            # the array's width), the table's best orientation, the force scaled to the
            # window (:meth:`scaled`); from there the search descends to a small contact
            # where the frame has one, and the likelihood's plateau of a point lies above it
            g = f.sensor.geometry
            r0 = START_RADIUS_SPAN * min(g.span_x + g.dx, g.span_y + g.dy)
            first = model.from_values(r0, r0 / GENERAL_START_BETA2 if model.name == "general"
                                      else r0, cands[0].psi_deg, f0, x0, y0)
            out.append(first if fr is None else self.scaled(fr, model, first))
            cands = cands[:max(f.options.max_starts - 1, 1)]
        for c in cands:
            if model.name == "general":
                out.append(model.from_values(c.radius, c.radius / GENERAL_START_BETA2, c.psi_deg,
                                             f0, x0, y0))
            else:
                out.append(model.from_values(c.radius, math.inf, c.psi_deg, f0, x0, y0))
            if model.name == "sphere":
                break  # orientation plays no part
        return out

    def scaled(self, fr: _Frame, model: Model, p: np.ndarray) -> np.ndarray:
        """``p`` with its force scaled to the window ``fr`` (``SCALE_STEPS`` Gauss-Newton steps
        in the log force alone, the rest held): the point-load force estimate a cold start
        takes is the strain summed over the tactels over the kernel summed at the peak, which
        a pitch twice the cover's depth samples so coarsely that it reads 0.5-5 times the
        force (a 3 x 11 mm ellipsoid at 1.4 N on the 6x4 pad of 4 mm pitch under 2 mm:
        0.5 N), and a search started that light crawled into a point contact.  Each step is
        one evaluation, charged to the fit's budget; ``p`` as it is where the budget cannot
        pay for them."""
        q = np.array(p, dtype=float)
        i = model.params.index("ln_f")
        try:
            residual = self.fitter._residual(fr, model)
            for _ in range(SCALE_STEPS):
                r, jac = residual(q)
                j = jac[:, i]
                jj = float(j @ j)
                if not (jj > 0.0 and math.isfinite(jj)):
                    break
                q[i] -= max(-SCALE_STEP_LN, min(SCALE_STEP_LN, float(j @ r) / jj))
        except BudgetExhausted:
            return np.array(p, dtype=float)
        return q if np.all(np.isfinite(q)) else np.array(p, dtype=float)

    def result(self, model: Model, sol: SolveResult, peak: float, win, n_points: int, starts: int,
               zdata: np.ndarray, valid: np.ndarray) -> FitResult:
        """The FitResult of the search ``sol``: values, their sigmas (widened where the frame
        says so), and what is withheld (:mod:`tactiled.fit.uncertainty`)."""
        f = self.fitter
        reasons: dict[str, str] = {}
        values, std, condition = uncertainty.bounds(f, model, sol.p, sol.jacobian * peak, reasons)
        chi2 = sol.cost * peak * peak / f.sigma**2
        stopped = search.stopped(sol)
        if condition is not None and std.get("x_mm") is not None:
            uncertainty.mismatch(f, model, sol, peak, zdata, chi2, std, reasons, win, valid, learn=not stopped)
        if stopped:
            uncertainty.unsettled(f, sol, peak, values, std, reasons)
        tied = uncertainty.tied_force(f, model, sol, values, std)  # before the radius may be withheld
        uncertainty.unobservable(f, values, std, reasons)
        if model.name == "cylinder":
            reasons.setdefault("r2_mm", "infinite: cylinder model")
        if model.name == "sphere":
            reasons.setdefault("angle_deg", "undefined: sphere model")
        if model.name == "general" and values.get("r2_mm") is None:
            reasons.setdefault("r2_mm", "infinite: fitted as a cylinder")
        ell = Ellipse(*compiled.ellipse_at(compiled.KINDS[model.name], sol.p, f.model._rf,
                                           f.model._k))
        line = ell.a >= 0.0 and uncertainty.line_contact(f, ell, values, std, reasons)
        if tied is not None and values.get("force_n") is not None:  # else withheld for another reason
            # kept, flagged: its sigma at this solution covers the trade (the bound at the
            # truth resolves such a force; least squares lands down the valley, several
            # bounds off, within that sigma: docs/concepts/uncertainty.md)
            reasons["force_n"] = f"poorly determined ({tied})"
        if not sol.converged:
            reasons.setdefault("fit", sol.message)
        rms = math.sqrt(sol.cost / max(n_points, 1))
        return FitResult(
            contact=True,
            model=model.name,
            label="line" if line else uncertainty.label(f, values, model.name),
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

"""A line contact's fit: a cylinder on a flat array, over the tactels that see the line.

The line's window follows it across the array (:mod:`tactiled.fit.linewindow`); the model is
:mod:`tactiled.fit.line`'s (radius, angle, load per length, offset), searched by the one
Levenberg-Marquardt (:mod:`tactiled.fit.search`), reported as model 'cylinder', label 'line'.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from tactiled.fit import budget as fit_budget
from tactiled.fit import compiled, search, uncertainty
from tactiled.fit.line import FORCE_REASON as LINE_FORCE_REASON
from tactiled.fit.line import PARAMS as LINE_PARAMS
from tactiled.fit.line import STEPS as LINE_STEPS
from tactiled.fit.line import LineProblem
from tactiled.fit.linewindow import KeptFrames, line_frame
from tactiled.fit.models import VALUE_KEYS
from tactiled.fit.profile import (ANGLE_SCAN_DEG, LINE_NEAR_STEPS, LINE_TEST_SIGMA,
                                  FLAT_CHI2, PROFILE_ITERATIONS, REACH_CHI2,
                                  AngleProfile, angle_scan, flat_below, widen_by_points,
                                  withhold_flat)
from tactiled.fit.result import FitResult
from tactiled.fit.search import LINE_BOUNDS, SCOUT_ITERATIONS, STOP_CHI2
from tactiled.fit.solver import SolveResult
from tactiled.physics.contact import LineContact

if TYPE_CHECKING:
    from tactiled.fit.fitter import Fitter, _Frame

#: The starts across the half-turn of a cold line search that stopped far above the noise
#: (:meth:`LineFit._around`), in degrees from its angle.
ANGLE_STARTS_DEG = (30.0, 60.0, 90.0, 120.0, 150.0)


class LineFit:
    """The line model's fit on one fitter's frames."""

    def __init__(self, fitter: Fitter) -> None:
        self.fitter = fitter
        #: set by :meth:`fit`: auto's line stayed a scout (:meth:`ruled_out`)
        self.scouted = False
        #: set by :meth:`fit`: where the line passes and its load ``(x, y, load)``, even where
        #: its values are withheld (auto's other models start there)
        self.point: tuple[float, float, float] | None = None
        #: the line windows one frame's fit makes, kept while ``frames.kept()`` is open
        self.frames = KeptFrames()
        #: set by :meth:`fit`: a ruled-out scout's result, unreported until :meth:`tested`
        #: ``(result, frame, problem, solution, starts tried)``
        self.untested: tuple | None = None

    def fit(self, strain: np.ndarray, start: np.ndarray | None,
                  mask: np.ndarray | None, scout_first: bool = False,
                  start_chi2: float | None = None) -> FitResult:
        """A cylinder on a flat array: the line model on this frame's window.

        ``scout_first`` (auto, cold): the first cold start is searched with a scout's iteration
        cap and tolerance (:meth:`tactiled.fit.point.PointFit.fit`); where that rules the line out
        (:meth:`ruled_out`) the scout is the answer and ``scouted`` is set,
        else the search goes on from where it stopped, as a full fit."""
        f = self.fitter
        self.scouted = False
        self.point = None
        self.untested = None
        fr = self.frame(strain, mask)
        if isinstance(fr, FitResult):
            fr.model = "cylinder"
            return fr
        peak = fr.peak
        prob = self.problem(fr)
        if start is not None and np.shape(start) != (len(LINE_PARAMS),):
            start = None  # a start of another model (a curved finger's cylinder): start cold
        starts = ([np.asarray(start, dtype=float)] if start is not None
                  else prob.starts(fr.clean, f.model.xs_full, f.model.ys_full, peak))
        scout = None
        if scout_first:
            scout, _ = search.search(f, fr, compiled.LINE, starts[:1], LINE_STEPS, LINE_BOUNDS,
                                    SCOUT_ITERATIONS, 1e-2, lambda: prob.residual_and_jacobian)
            start_chi2 = scout.cost * peak * peak / f.sigma**2
            # (a scout denied the flat allowance is over GRANT_CHI2_FACTOR >= 2 times a right
            # model's chi^2: as far from a line as a converged scout the test rules out)
            self.scouted = self.ruled_out(scout.converged, start_chi2, fr.n_points) \
                or scout.message == fit_budget.DENIED
            starts = [scout.p, *starts[1:]]
        if self.scouted:
            best, tried = scout, 1
        else:
            best, tried = search.search(f, fr, compiled.LINE, starts, LINE_STEPS, LINE_BOUNDS,
                                       f.options.max_iter, STOP_CHI2,
                                       lambda: prob.residual_and_jacobian,
                                       start_chi2)
            if scout is not None:
                if best.jacobian.size == 0 and scout.jacobian.size:
                    # the budget refused the search's first evaluation: the scout's point stands
                    best = SolveResult(scout.p, scout.residual, scout.jacobian, scout.cost, 0, 0,
                                       False, best.message)
                best.iterations += scout.iterations
                best.evaluations += scout.evaluations
        other = None
        if start is None and not self.scouted:
            if not scout_first:  # (auto's other models answer a frame no line explains)
                best, tried = self._around(fr, prob, best, tried, starts[0])
            best, tried, other = self._mirror(fr, prob, best, tried)
        if self.scouted:  # ranked by chi^2, its report made only if it is the answer (tested)
            values, std, line = prob.report(best.p, None)
            self.point = (values["x_mm"], values["y_mm"], line["load_n_per_mm"])
            res = FitResult(
                contact=True, model="cylinder", values=values, std=std,
                rms=math.sqrt(best.cost / max(fr.n_points, 1)),
                chi2=best.cost * peak * peak / f.sigma**2,
                iterations=best.iterations, evaluations=best.evaluations, converged=best.converged,
                peak=peak, n_points=fr.n_points, window=fr.win, starts=tried,
                message=best.message, params=tuple(best.p.tolist()), line=line)
            self.untested = (res, fr, prob, best, tried)
            return res
        return self._finish(fr, prob, best, tried, valley=other)

    def _around(self, fr: _Frame, prob: LineProblem, best: SolveResult, tried: int,
                cold: np.ndarray) -> tuple[SolveResult, int]:
        """A cold search ``best`` that stopped far above what the noise allows
        (:func:`tactiled.fit.search.good_enough`) searched again from starts across the
        half-turn, ``ANGLE_STARTS_DEG`` from its angle, the cheapest first, each at its radius and at the cold
        start ``cold``'s (a search lost far from a line can stop at the smallest radius the
        solver allows) and placed across the window where it explains it best (:meth:`_across`):
        the line's angle is one periodic parameter,
        and a cold direction from a ridge whose half-peak tactels are one or two (a thin
        line crossing a coarse pad between rows) can lie in no valley of a line at all
        (chi^2 5500-6000 over 24 tactels on a 6x4 pad).  ``(the best search, starts tried)``.
        Not under auto, whose sphere and ellipse answer a frame the line does not explain
        (a ball's: on the 4x4 XELA pad those starts put auto's p99 up by a fifth)."""
        f = self.fitter
        if search.good_enough(f, best, fr.peak, fr.n_points, len(LINE_PARAMS)) \
                or f._out_of_time():
            return best, tried
        place = self._across(fr, prob)
        starts = []
        for turn in ANGLE_STARTS_DEG:
            for r in (best.p, cold):
                q = np.array(r, dtype=float)
                q[1] = best.p[1] + math.radians(turn)
                starts += place(q)
        costs = sorted((self._cost(prob, q), i) for i, q in enumerate(starts))
        starts = [starts[i] for _, i in costs]  # the cheap scan: the lowest first
        # (its chi^2 lets the first search draw on the flat allowance the lost search spent
        # its base work to, where it is within a right model's reach: Budget.grant_cost)
        sol, more = f._search(fr, compiled.LINE, starts, LINE_STEPS, LINE_BOUNDS,
                              f.options.max_iter, STOP_CHI2, lambda: prob.residual_and_jacobian,
                              costs[0][0] * fr.peak * fr.peak / f.sigma**2)
        if not sol.cost < best.cost:
            best.iterations += sol.iterations
            best.evaluations += sol.evaluations
            return best, tried + more
        sol.iterations += best.iterations
        sol.evaluations += best.evaluations
        return sol, tried + more

    @staticmethod
    def _cost(prob: LineProblem, q: np.ndarray) -> float:
        """The line ``q``'s cost on ``prob``'s window (inf for a line too wide to integrate)."""
        try:
            r, _ = prob.residual_and_jacobian(q)
        except ValueError:
            return math.inf
        return float(r @ r)

    def _mirror(self, fr: _Frame, prob: LineProblem, best: SolveResult, tried: int
                ) -> tuple[SolveResult, int, tuple[float, np.ndarray] | None]:
        """A cold search ``best`` whose pressed tactels lie on one lattice line, searched
        again from its mirror image about that line (:meth:`LineProblem.mirrored`): the
        deeper of the two valleys is the answer, ``(best, starts tried, the other valley's
        (chi^2, solution) or None)``.  Both are searched whatever their chi^2: the two
        mirror images both explain the frame to the noise (chi^2 31-50 and 16-32 over 24
        tactels), so only their depths tell them apart; a line that does not explain the frame
        (a ball's blob on one or two tactels, under auto) has no mirror worth a search."""
        f = self.fitter
        q = prob.mirrored(best.p) if best.converged else None
        if q is None or f._out_of_time() \
                or not search.good_enough(f, best, fr.peak, fr.n_points, len(LINE_PARAMS)):
            return best, tried, None
        sol, _ = f._search(fr, compiled.LINE, [q], LINE_STEPS, LINE_BOUNDS, f.options.max_iter,
                           STOP_CHI2, lambda: prob.residual_and_jacobian)
        if not sol.converged:
            return best, tried + 1, None
        sol.iterations += best.iterations
        sol.evaluations += best.evaluations
        win, lose = (sol, best) if sol.cost < best.cost else (best, sol)
        win.iterations, win.evaluations = sol.iterations, sol.evaluations
        unit = fr.peak * fr.peak / f.sigma**2
        return win, tried + 1, (lose.cost * unit, lose.p)

    def _finish(self, fr: _Frame, prob: LineProblem, best: SolveResult, tried: int,
                known: list[tuple[float, np.ndarray]] | None = None,
                valley: tuple[float, np.ndarray] | None = None) -> FitResult:
        """The FitResult of the line's search ``best`` on ``fr``: its values, their sigmas
        (widened where the frame says so, tested on their profile likelihood where it
        converged) and what is withheld.  Where the angle's profile finds a deeper valley
        than the search's, the line is searched again from there and that search is the
        answer, its profile the points already searched (``known``, ``(chi^2, solution)``)
        and its two near points."""
        f = self.fitter
        peak = fr.peak
        reasons: dict[str, str] = {}
        jraw = best.jacobian * peak
        cov, condition = uncertainty.covariance(jraw, f.sigma)
        if cov is None:
            reasons.update(dict.fromkeys(("x_mm", "y_mm", "r1_mm", "angle_deg"),
                                         "Jacobian singular: parameter not identifiable from this window"))
        elif condition > uncertainty.ILL_CONDITION:
            reasons["condition"] = f"ill-conditioned fit (condition number {condition:.3g})"
        if cov is not None and not search.stopped(best):
            cov = uncertainty.birge(cov, best.cost * peak * peak / f.sigma**2,
                                    fr.n_points - len(LINE_PARAMS), reasons)
        values, std, line = prob.report(best.p, cov)
        # where the line passes and its load, even if withheld below (auto's other starts)
        self.point = (values["x_mm"], values["y_mm"], line["load_n_per_mm"])
        reasons["force_n"] = LINE_FORCE_REASON
        reasons["r2_mm"] = "infinite: cylinder model"
        if search.stopped(best):
            uncertainty.unsettled(f, best, peak, values, std, reasons)
            if all(values.get(k) is None for k in VALUE_KEYS):
                line = None  # the load and offset of a search stopped short are no measurement
        uncertainty.unobservable(f, values, std, reasons)
        if not best.converged:
            reasons.setdefault("fit", best.message)
        else:
            scan = self._profiles(fr, prob, best, values, std, reasons, line, known)
            if valley is not None:  # (after the profile tests: they test the curvature's sigma)
                self._valleys(fr, prob, best, valley, values, std, reasons, line)
            if scan.deeper is not None and known is None:
                # the angle's profile found a valley deeper than the search's: search from
                # there; where that does not reach it, the angle stays withheld (flat)
                sol, _ = f._search(fr, compiled.LINE, [scan.deeper], LINE_STEPS, LINE_BOUNDS,
                                   f.options.max_iter, STOP_CHI2, lambda: prob.residual_and_jacobian)
                if sol.converged and sol.cost < best.cost:
                    sol.iterations += best.iterations
                    sol.evaluations += best.evaluations
                    chi2 = best.cost * peak * peak / f.sigma**2
                    seen = [(chi2 + rise, q) for rise, q in scan.points]
                    return self._finish(fr, prob, sol, tried + 1, [(chi2, best.p), *seen])
        return FitResult(
            contact=True, model="cylinder", label=self._label(values, line),
            values=values, std=std,
            rms=math.sqrt(best.cost / max(fr.n_points, 1)),
            chi2=best.cost * peak * peak / f.sigma**2,
            iterations=best.iterations, evaluations=best.evaluations, converged=best.converged,
            condition=condition, peak=peak, n_points=fr.n_points, window=fr.win, starts=tried,
            message=best.message, reasons=reasons, params=tuple(best.p.tolist()), line=line,
        )

    def _valleys(self, fr: _Frame, prob: LineProblem, best: SolveResult,
                 valley: tuple[float, np.ndarray], values: dict, std: dict,
                 reasons: dict[str, str], line: dict | None) -> None:
        """The angle's sigma (and the place's, offset's and load's that trade with it) widened
        so that the other valley ``valley`` (``(chi^2, solution)``, :meth:`_mirror`) lies
        ``sqrt(rise)`` sigmas away, where it rises by under ``REACH_CHI2`` (a rise under
        ``FLAT_CHI2`` puts it one sigma away): two valleys that explain the frame alike are
        one answer with the sigma that covers both, never a confident pick of one."""
        chi2 = best.cost * fr.peak * fr.peak / self.fitter.sigma**2
        rise = valley[0] - chi2
        if not rise < REACH_CHI2 or values.get("angle_deg") is None:
            return
        at_v, _, at_l = prob.report(valley[1], None)
        at = [(rise, {**at_v, **at_l})]
        why = ("poorly determined: its sigma widened to cover the mirror-image valley of its "
               f"likelihood (chi^2 {max(rise, 0.0):.2g} above)")
        turn = abs(at_v["angle_deg"] - values["angle_deg"]) % 180.0  # (the half-turn round)
        wide = min(turn, 180.0 - turn) / math.sqrt(max(rise, FLAT_CHI2))
        if std.get("angle_deg") is not None and wide > std["angle_deg"]:
            std["angle_deg"] = wide
            reasons.setdefault("angle_deg", why)
        widen_by_points(values, std, reasons, at, ("x_mm", "y_mm"), why)
        _widen_line(line, at)

    def _profiles(self, fr: _Frame, prob: LineProblem, best: SolveResult, values: dict,
                  std: dict, reasons: dict[str, str], line: dict | None,
                  known: list[tuple[float, np.ndarray]] | None = None) -> AngleProfile:
        """The radius's and the angle's profile tests (:mod:`tactiled.fit.profile`) at the
        converged solution ``best``: up to seven more searches (each angle point's from two
        starts), so a scout the line was ruled out by (a ball's window) is tested only if it
        is the answer (:meth:`tested`).  The angle's profile points widen the sigmas of the
        place and of the line's offset and load that trade with it.  ``known``: the points a
        scan from another valley searched (then only the two near points are searched).
        Returns the angle's profile (its ``deeper``: a valley deeper than the search's, where
        the angle is withheld as flat across it)."""
        f = self.fitter
        chi2 = best.cost * fr.peak * fr.peak / f.sigma**2
        withhold_flat(values, std, reasons, flat_below(
            f, fr, compiled.LINE, best.p, LINE_STEPS, LINE_BOUNDS,
            lambda: prob.residual_and_jacobian, chi2, values.get("r1_mm"), std.get("r1_mm")))
        scan = angle_scan(f, fr, compiled.LINE, best.p, LINE_STEPS, LINE_BOUNDS,
                          lambda: prob.residual_and_jacobian, chi2, LINE_PARAMS.index("psi"),
                          std.get("angle_deg"), scan=ANGLE_SCAN_DEG if known is None else (),
                          starts_at=self._across(fr, prob), known=known or [],
                          test_sigma=LINE_TEST_SIGMA, near_steps=LINE_NEAR_STEPS,
                          cap=PROFILE_ITERATIONS)
        withhold_flat(values, std, reasons, scan.why, "angle_deg")
        if scan.points:
            at = []
            for rise, q in scan.points:
                v, _, ln = prob.report(q, None)
                at.append((rise, {**v, **ln}))
            widen_by_points(values, std, reasons, at, ("x_mm", "y_mm"))
            _widen_line(line, at)
        return scan

    def _across(self, fr: _Frame, prob: LineProblem):
        """For an angle profile point's search: its start, the line at the held angle placed
        across the window where it explains the window best (its offset on a grid a tactel
        apart across the window's tactels, or the solution's own; its load scaled to the
        strains there: the least-squares scale, the strain being nearly proportional to the
        load).  Turned about
        the window's centre, a line can cross the band of tactels that see it anywhere along
        it, and a search from there stops in the nearest of several valleys of the offset."""
        g = self.fitter.sensor.geometry
        step = min(g.dx, g.dy)
        valid = fr.valid
        px, py = prob.px[valid] - prob.ref[0], prob.py[valid] - prob.ref[1]
        w2 = prob.inv_scale[valid] ** 2
        target = prob.target[valid]

        def starts(start: np.ndarray) -> list[np.ndarray]:
            nx, ny = -math.sin(start[1]), math.cos(start[1])
            across = px * nx + py * ny
            best, out = math.inf, None
            grid = np.arange(across.min(), across.max() + 0.5 * step, step)
            for c in (start[3], *grid):
                q = start.copy()
                q[3] = c
                m = prob.strains(q)[valid]
                mm = float((w2 * m * m).sum())
                if not mm > 0.0:
                    continue
                mt = float((w2 * m * target).sum())
                if mt <= 0.0:
                    continue
                cost = -mt * mt / mm  # chi^2 less the target's own, at the best scale
                if cost < best:
                    best, out = cost, q
                    out[2] = q[2] + math.log(mt / mm)
            return [start] if out is None else [out]

        return starts

    def _label(self, values: dict, line: dict | None) -> str | None:
        """The line's label: 'edge' for a radius under 1 mm, else 'line'; None for a line
        whose load and offset are withheld (a search its budget stopped far from any line)."""
        if line is None:
            return None
        label = uncertainty.label(self.fitter, values, "line")
        return "line" if label == "plane" else label

    def tested(self, res: FitResult) -> FitResult:
        """``res`` made whole (its sigmas, what is withheld, its profile tests), when it is
        the scout :meth:`fit` left unreported (auto's answer is the line it ruled out: a
        budget cut the choice short); else as it is.  What auto wrote on it (the iterations
        and evaluations of every model, its message, the criterion) stays."""
        pending, self.untested = self.untested, None
        if pending is None or pending[0] is not res:
            return res
        _, fr, prob, best, tried = pending
        whole = self._finish(fr, prob, best, tried)
        for name in ("label", "values", "std", "rms", "chi2", "converged", "condition", "peak",
                     "n_points", "window", "starts", "reasons", "params", "line", "ellipse"):
            setattr(res, name, getattr(whole, name))
        return res

    def as_point(self, cyl: FitResult) -> tuple[float, float, float, float, float]:
        """A cylinder fit as ``(ln R, psi, ln F, x0, y0)``, a start for the other models: on a
        flat array the line's point nearest the window's peak, with the load over one cover
        depth's length (the part of the line a sphere's start should explain)."""
        f = self.fitter
        p = cyl.params
        if not f.sensor.geometry.flat:
            return tuple(p)  # type: ignore[return-value]
        x, y = cyl.values.get("x_mm"), cyl.values.get("y_mm")
        load = (cyl.line or {}).get("load_n_per_mm") or 0.1
        if (x is None or y is None) and self.point is not None:
            x, y, load = self.point  # a line stopped short: its values withheld, not its place
        if x is None or y is None:
            g = f.sensor.geometry
            x, y = 0.5 * g.span_x, 0.5 * g.span_y
        if cyl.window is not None:  # slide along the line to the window's centre
            r0, c0, nr, nc = cyl.window
            g = f.sensor.geometry
            wx, wy = (r0 + 0.5 * (nr - 1)) * g.dx, (c0 + 0.5 * (nc - 1)) * g.dy
            c, s = math.cos(p[1]), math.sin(p[1])
            t = (wx - x) * c + (wy - y) * s
            x, y = x + t * c, y + t * s
        depth = min(f.sensor.impulse.depth_x, f.sensor.impulse.depth_y)
        return p[0], p[1], math.log(load * 4.0 * depth), x, y

    def explains(self, cyl: FitResult) -> bool:
        """On a flat array: the line fit converged with chi^2 consistent with the noise (the
        test a warm fit's model is kept by).  Auto then keeps it without scouting the sphere
        and the general ellipse: where the window shows a line, those can only follow it
        into ever larger contacts (a circle, an ellipse running off the array), the costliest
        searches a flat array's fit has, to land on what :meth:`tactiled.fit.auto.ModelSelector.runs_off` turns back into
        the line."""
        f = self.fitter
        return f.sensor.geometry.flat and cyl.converged and search.consistent(f, cyl)

    def ruled_out(self, converged: bool, chi2: float, n_points: int) -> bool:
        """The line's scout converged (the next step would lower chi^2 by under its
        tolerance: it sits at a minimum) with chi^2 over twice the most a right model reaches
        (:func:`tactiled.fit.search.consistent`): solving on cannot bring it to the noise, so the window shows
        no line (a ball's blob: tens to hundreds of times its degrees of freedom) and the
        line stays a scout, ranked with the others and solved fully only if chosen."""
        dof = max(n_points - len(LINE_PARAMS), 1)
        return converged and chi2 > 2.0 * (dof + 3.0 * math.sqrt(2.0 * dof))

    def frame(self, strain: np.ndarray, mask: np.ndarray | None) -> _Frame | FitResult:
        """The line model's window: the tactels that see the line, along its whole length
        (:func:`tactiled.fit.linewindow.line_frame`)."""
        f = self.fitter
        return line_frame(f, strain, mask)

    def problem(self, fr: _Frame) -> LineProblem:
        f = self.fitter
        return LineProblem(f.sensor, fr.xs, fr.ys, fr.ex, fr.ey, fr.target, fr.valid,
                           fr.inv_scale, f.options.tol)

    def cramer_rao(self, strain: np.ndarray, contact: LineContact,
                        window: int | None = None) -> dict[str, float | None]:
        """1-sigma Cramer-Rao bounds of a line contact (a cylinder on a flat array) at the
        truth ``contact``, for the window this fitter would choose on ``strain`` (with
        ``window``: a square window of that side on the ridge,
        :func:`tactiled.fit.linewindow.square_window`): ``r1_mm``, ``angle_deg``, ``x_mm``,
        ``y_mm``, ``load_n_per_mm`` and ``offset_mm``."""
        f = self.fitter
        fr = line_frame(f, f.flattened(strain), None, window)
        keys = ("x_mm", "y_mm", "r1_mm", "angle_deg", "load_n_per_mm", "offset_mm")
        if isinstance(fr, FitResult):
            return dict.fromkeys(keys)
        prob = self.problem(fr)
        psi = contact.psi
        c = -math.sin(psi) * (contact.x0 - prob.ref[0]) + math.cos(psi) * (contact.y0 - prob.ref[1])
        p = np.array([math.log(contact.r1), psi, math.log(contact.load), c])
        _, jac = prob.residual_and_jacobian(p)
        cov, _ = uncertainty.covariance(jac * fr.peak, f.sigma)
        _, std, line = prob.report(p, cov)
        return {**{k: std[k] for k in keys[:4]}, "load_n_per_mm": line["load_n_per_mm_std"],
                "offset_mm": line["offset_mm_std"]}

    def solve(self, strain: np.ndarray, scout: FitResult, mask: np.ndarray | None) -> FitResult:
        """The line fully solved from where its scout stopped, counting the scout's
        iterations and evaluations."""
        full = self.fit(strain, np.asarray(scout.params), mask, start_chi2=scout.chi2)
        full.iterations += scout.iterations
        full.evaluations += scout.evaluations
        return full


def _widen_line(line: dict | None, at: list[tuple[float, dict]]) -> None:
    """The line's load and offset sigmas widened by the profile points ``at``
    (:func:`tactiled.fit.profile.widen_by_points`)."""
    if line is None:
        return
    sd = {k: line.get(k + "_std") for k in ("load_n_per_mm", "offset_mm")}
    widen_by_points(line, sd, {}, at, ("load_n_per_mm", "offset_mm"))
    line.update({k + "_std": v for k, v in sd.items()})

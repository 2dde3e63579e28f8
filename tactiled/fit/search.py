"""The search of one model on one window: from each start in turn, the one Levenberg-Marquardt.

The compiled search (:func:`tactiled.fit.compiled.solve`) runs each start; the Python solver
(:func:`tactiled.fit.solver.levenberg_marquardt`) where that hands back.  Here also what every
model's search shares: the step caps and box of its parameters, its stopping tolerances, and
the tests of a fit against the noise (:func:`good_enough`, :func:`consistent`).
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import gammaincinv

from tactiled.fit import compiled
from tactiled.fit.budget import EXHAUSTED
from tactiled.fit.line import PARAMS as LINE_PARAMS
from tactiled.fit.models import Model, get_model
from tactiled.fit.params import RADIUS_LIMITS
from tactiled.fit.result import FitResult
from tactiled.fit.solver import BUDGET_MESSAGE, TIME_BUDGET_EXCEEDED, SolveResult, levenberg_marquardt

if TYPE_CHECKING:
    from tactiled.fit.fitter import Fitter, _Frame

#: A full fit stops once the next step would lower chi^2 by less than this (units of the
#: noise: 1e-4 moves no parameter by more than 0.01 of its sigma; measured on warm fits, 1e-6
#: took 4 evaluations at the median, 1e-4 takes 3).
STOP_CHI2 = 1e-4
#: Iteration cap of auto's candidate fits (see PointFit.fit's ``scouting``).
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

#: chi^2 above its quantile of this level flags a fit whose residuals exceed the noise.
MISMATCH_LEVEL = 0.99


#: A search whose chi^2 is above this quantile of a right model's (and ``MODEL_SLACK``) stopped
#: far above what the noise allows: the search's other starts are tried (:func:`good_enough`).
NOISE_LEVEL = 0.999
#: The model error a fit is allowed before other starts are tried: this share of the peak
#: strain's square per tactel (a residual of 1 % of the peak at every tactel), so a sensor
#: whose model is off by that much does not send every fit through all its starts.
MODEL_SLACK = 1e-4


@lru_cache(maxsize=None)
def _chi2_limit(dof: int, level: float = MISMATCH_LEVEL) -> float:
    """The ``level`` quantile of chi^2 with ``dof`` degrees of freedom: scipy.stats'
    ``chi2.ppf``, bit for bit, from scipy.special (scipy.stats costs a second to import)."""
    return float(2.0 * gammaincinv(dof / 2.0, level))


_STEP = {"ln_r": 1.0, "ln_ra": 1.0, "beta": 0.5, "psi": 0.5, "ln_f": 0.7, "x0": 2.0, "y0": 2.0}


def forward_difference(residual):
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


@lru_cache(maxsize=None)
def steps_of(model: Model) -> np.ndarray:
    """The step caps of ``model``'s parameters (read-only, shared)."""
    out = np.array([_STEP[name] for name in model.params])
    out.setflags(write=False)
    return out


@lru_cache(maxsize=None)
def bounds_of(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """The solver's box on ``model``'s parameters: its log radii within ``_LN_R_BOUNDS``."""
    radius = np.array([name in _LOG_RADII for name in model.params])
    lo = np.where(radius, _LN_R_BOUNDS[0], -np.inf)
    hi = np.where(radius, _LN_R_BOUNDS[1], np.inf)
    for arr in (lo, hi):
        arr.setflags(write=False)
    return lo, hi


#: The line model (a cylinder on a flat array) as the window check sees it.
LINE_MODEL = Model("line", LINE_PARAMS)
LINE_BOUNDS = (np.array([_LN_R_BOUNDS[0], -np.inf, -np.inf, -np.inf]),
                np.array([_LN_R_BOUNDS[1], np.inf, np.inf, np.inf]))


def search(fitter: Fitter, fr: _Frame, kind: int, starts: list[np.ndarray], steps: np.ndarray,
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
    widened by that excess: :func:`tactiled.fit.uncertainty.mismatch`).  Fits the model explains are untouched.

    On a flat array a search that has spent the fit's base work goes on into the flat
    allowance only while its chi^2 is within ``GRANT_CHI2_FACTOR`` times a right model's
    (``Budget.grant_cost``); ``start_chi2``, the first start's chi^2 where a scout left
    it, lets its first evaluation draw on the allowance when it is within that."""
    peak = fr.peak
    budget = fitter._budget
    unit = (fitter.sigma / peak) ** 2  # the cost of chi^2 = 1
    atol = stop_chi2 * unit
    verdict_tol = CONVERGED_CHI2 * unit
    dof = max(fr.n_points - len(starts[0]), 1)
    noise_cost = _chi2_limit(dof) * unit
    exact = kind == compiled.LINE or fitter.options.jacobian == "exact"
    window = (fr.xs, fr.ys, fr.target, fr.valid, fr.inv_scale, fr.ex, fr.ey)
    residual = None  # the Python solver's residual function, built only if it is needed
    best: SolveResult | None = None
    tried = 0
    for p0 in starts:
        max_iter = iterations_for(fitter, cap)
        if tried and (max_iter == 0 or fitter._out_of_time()):
            break
        tried += 1
        sol = None
        if exact:  # the whole search compiled (falls back on huge contacts)
            grant = -1.0 if budget is None else budget.grant_cost(dof, unit)
            sol = compiled.solve(kind, p0, steps, max_iter, atol, fitter._model_args, window,
                                 fitter.options.tol, bounds=bounds, verdict_tol=verdict_tol,
                                 budget=budget, noise_cost=noise_cost, grant_cost=grant,
                                 start_ok=tried == 1 and start_chi2 is not None
                                 and start_chi2 * unit <= grant)
        if sol is None:
            if residual is None:
                residual = python_residual()
            sol = levenberg_marquardt(residual, p0, max_step=steps, max_iter=max_iter, atol=atol,
                                      deadline=fitter._deadline, verdict_tol=verdict_tol,
                                      bounds=bounds, noise_cost=noise_cost)
            if budget is not None:
                budget.charge(sol.iterations, 0.0)
        ran_out(fitter, sol, max_iter, cap)
        if best is None or sol.cost < best.cost:
            best = sol
        if good_enough(fitter, best, peak, fr.n_points, len(p0)) or fitter._out_of_time():
            break
    assert best is not None
    return best, tried


def iterations_for(fitter: Fitter, cap: int) -> int:
    """The iteration cap of the next search: ``cap``, or what the fit's budget has left."""
    return cap if fitter._budget is None else fitter._budget.iterations_for(cap)


def ran_out(fitter: Fitter, sol: SolveResult, max_iter: int, cap: int) -> None:
    """Mark a search the fit's iterations stopped (not its own cap) as the budget's."""
    if fitter._budget is not None and max_iter < cap and sol.iterations >= max_iter \
            and not sol.converged:
        fitter._budget.exhausted = True
        sol.message = f"{EXHAUSTED} ({fitter.options.budget_iterations} iterations)"


def stopped(sol: SolveResult) -> bool:
    """The fit's budget (iterations, work or wall time) stopped this search."""
    return sol.message is BUDGET_MESSAGE or sol.message is TIME_BUDGET_EXCEEDED or (
        sol.message.startswith(EXHAUSTED))


def good_enough(fitter: Fitter, sol: SolveResult, peak: float, n_points: int,
                params: int = 0) -> bool:
    """The search's chi^2 within what the noise allows a right model with ``params``
    parameters (its ``NOISE_LEVEL`` quantile) and ``MODEL_SLACK`` of model error, so further
    starts cannot be expected to help.  (A bound of 4 per tactel let a line on a 6x4 pad
    stop in its wrong valley at chi^2 60 over 24 tactels, where the noise allows 45.)"""
    if not math.isfinite(sol.cost):
        return False
    chi2 = sol.cost * peak * peak / (fitter.sigma * fitter.sigma)
    dof = max(n_points - params, 1)
    return chi2 <= _chi2_limit(dof, NOISE_LEVEL) + MODEL_SLACK * n_points * (peak / fitter.sigma) ** 2


def consistent(fitter: Fitter, res: FitResult) -> bool:
    """chi^2 within 3 standard deviations of its expectation for a correct model (its
    own parameters: a flat array's line contact, reported as a cylinder, has four)."""
    k = len(res.params) if res.params is not None else get_model(res.model).size
    n = res.n_points
    dof = max(n - k, 1)
    return res.chi2 <= dof + 3.0 * math.sqrt(2.0 * dof)

"""The one damped least-squares search (Levenberg-Marquardt) of every fit, for small dense problems.

``(J^T J + lam diag(J^T J)) dp = -J^T r`` on a few parameters, the damping raised on a rejected
step and lowered on an accepted one, a per-parameter step cap (a trust region) so a poor start
cannot throw the contact off the array in one step, and an optional box.
"""

# :func:`descend` is the loop; :func:`levenberg_marquardt` runs it on a Python residual function
# (finite-difference Jacobians, contacts past the compiled rules, the several-contacts joint
# fit), and ``tactiled.fit.compiled.search`` runs it on the compiled evaluation, the reference of
# the core's own search (core/search.cpp), which the fitter calls.

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tactiled.fit.budget import EXHAUSTED, BudgetExhausted
from tactiled.physics.kernels import damped_step, finite_cost, normal_equations

ResidualFn = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
#: ``evaluate(trial, cost of the point stepped from) -> (r, J, cost)``; cost inf: an invalid
#: point (the step is rejected); raising :class:`Stop` ends the search where it stands.
EvaluateFn = Callable[[np.ndarray, float], tuple[np.ndarray, np.ndarray, float]]
TIME_BUDGET_EXCEEDED = "time budget exceeded"
#: The message of a search the fit's budget stopped (tactiled.fit.budget): not converged.
BUDGET_MESSAGE = f"{EXHAUSTED} (the work of the next model evaluation)"
#: Added to the message of a search that ended without its stopping rule firing (the
#: iteration cap) but within ``verdict_tol`` of the minimum: converged.
WITHIN_TOLERANCE = "within tolerance of the least-squares minimum"
#: The message of a search whose stopping rule fired short of that: not converged.
STALLED = "stalled short of the least-squares minimum (steps too small to get there)"
#: How the loop ends, in the order of the compiled search's message codes.
MAX_ITERATIONS = "maximum iterations reached"
STEP_BELOW_XTOL = "step below xtol"
DECREASE_BELOW_FTOL = "predicted decrease below ftol"
DAMPING_EXHAUSTED = "no step reduces the cost (damping exhausted)"


class Stop(Exception):
    """Raised by an evaluation to end the search at the current point; ``message`` says why."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


@dataclass
class SolveResult:
    p: np.ndarray
    residual: np.ndarray
    jacobian: np.ndarray
    cost: float  # sum of squared residuals
    iterations: int
    evaluations: int
    converged: bool
    message: str


def descend(evaluate: EvaluateFn, p: np.ndarray, r: np.ndarray, jac: np.ndarray, cost: float,
            scale: np.ndarray, max_iter: int, xtol: float, ftol: float, lam0: float, atol: float,
            noise_cost: float, bounds: tuple[np.ndarray, np.ndarray] | None):
    """The Marquardt loop from ``p`` (its residuals ``r``, Jacobian ``jac`` and finite
    ``cost``): ``(p, r, J, cost, iterations, evaluations, converged, message)``, the
    evaluations not counting the start's.  The stopping rules: every component of the next
    step below ``xtol`` of its ``scale``, or a predicted decrease below ``ftol * cost + atol``
    (``atol`` growing with ``cost / noise_cost`` beyond 1); a parameter on a ``bounds`` face
    that the descent pushes outwards is held there (:func:`_pin`)."""
    lam, nu = lam0, 2.0
    evals = 0
    message = MAX_ITERATIONS
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        jtj, g, diag = normal_equations(jac, r)
        if bounds is not None:
            jtj, g = _pin(p, jtj, g, *bounds)
        accepted = stopped = False
        while lam < 1e12:
            try:
                step, over, predicted = damped_step(jtj, g, diag, lam, scale)
            except np.linalg.LinAlgError:  # pragma: no cover - damping makes A definite
                lam *= 10.0
                continue
            if over < xtol:
                converged, message = True, STEP_BELOW_XTOL
                break
            if predicted <= ftol * cost + atol * max(1.0, cost / noise_cost):
                converged, message = True, DECREASE_BELOW_FTOL
                break
            trial = p + step if bounds is None else np.clip(p + step, *bounds)
            try:
                r_new, jac_new, cost_new = evaluate(trial, cost)
            except Stop as stop:
                message, stopped = stop.message, True
                break
            evals += 1
            if cost_new < math.inf and cost_new < cost:
                rho = (cost - cost_new) / predicted
                lam = max(lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 1e-12)
                nu = 2.0
                accepted = True
                break
            lam *= nu
            nu *= 2.0
        if converged or stopped:
            break
        if not accepted:
            message = DAMPING_EXHAUSTED
            break
        p, r, jac, cost = trial, r_new, jac_new, cost_new
    return p, r, jac, cost, it, evals, converged, message


def verdict(converged: bool, message: str, remaining: float, cost: float, verdict_tol: float,
            noise_cost: float) -> tuple[bool, str]:
    """``(converged, message)`` decided on where the search ended, not on which stopping rule
    fired: converged when one more Gauss-Newton step within the caps could lower the cost by
    at most ``verdict_tol`` (``remaining``, :func:`remaining_decrease`; the tolerance growing
    with ``cost / noise_cost`` beyond 1)."""
    close = remaining <= verdict_tol * max(1.0, cost / noise_cost)
    if close and not converged:
        message = f"{message}, {WITHIN_TOLERANCE}"
    elif converged and not close:
        message = STALLED
    return close, message


def levenberg_marquardt(
    fun: ResidualFn,
    p0: np.ndarray,
    max_step: np.ndarray | None = None,
    max_iter: int = 60,
    xtol: float = 1e-9,
    ftol: float = 1e-10,
    lam0: float = 1e-3,
    atol: float = 0.0,
    deadline: float | None = None,
    verdict_tol: float | None = None,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
    noise_cost: float = math.inf,
) -> SolveResult:
    """Minimise ``sum(r(p)^2)`` from ``p0`` by :func:`descend` on the Python residual ``fun``
    (residuals and Jacobian from one call).

    ``max_step`` caps each component of a step (same units as p).  A residual function that
    raises ``ValueError`` or returns non-finite values rejects the trial step (an infinite
    cost).  ``deadline`` (``time.perf_counter()`` seconds) stops the search before the next
    evaluation once passed: not converged, "time budget exceeded".  A residual function that
    raises :class:`~tactiled.fit.budget.BudgetExhausted` (the fit's budget cannot pay for that
    evaluation) stops it the same way: not converged, ``BUDGET_MESSAGE``.

    ``verdict_tol`` (cost units): the verdict of :func:`verdict`; without it the stopping
    rule is the verdict.  ``bounds`` (lower, upper arrays; +-inf for none) keep the parameters
    in a box.  ``noise_cost`` (cost units): the cost of a fit whose residuals are the noise
    (its degrees of freedom); beyond it ``atol`` and ``verdict_tol`` grow with
    ``cost / noise_cost``: a fit its model does not explain has errors that many times larger
    than the noise's.  Default: never.
    """
    p = np.array(p0, dtype=float)
    if bounds is not None:
        p = np.clip(p, *bounds)
    try:
        r, jac = fun(p)
    except BudgetExhausted:
        return SolveResult(p, np.zeros(0), np.zeros((0, p.size)), float("inf"), 0, 0, False,
                           BUDGET_MESSAGE)
    except (ValueError, OverflowError) as err:
        return SolveResult(p, np.zeros(0), np.zeros((0, p.size)), float("inf"), 0, 1, False,
                           f"invalid start: {err}")
    cost = finite_cost(r, jac)
    if not math.isfinite(cost):
        return SolveResult(p, r, jac, float("inf"), 0, 1, False, "non-finite residual at start")

    def evaluate(trial: np.ndarray, _from: float) -> tuple[np.ndarray, np.ndarray, float]:
        if deadline is not None and time.perf_counter() > deadline:
            raise Stop(TIME_BUDGET_EXCEEDED)
        try:
            r_new, jac_new = fun(trial)
            return r_new, jac_new, finite_cost(r_new, jac_new)
        except BudgetExhausted:
            raise Stop(BUDGET_MESSAGE) from None
        except (ValueError, OverflowError):  # an invalid trial point: reject the step
            return r, jac, math.inf

    scale = np.ones_like(p) if max_step is None else np.asarray(max_step, dtype=float)
    p, r, jac, cost, it, evals, converged, message = descend(
        evaluate, p, r, jac, cost, scale, max_iter, xtol, ftol, lam0, atol, noise_cost, bounds)
    if verdict_tol is not None and message not in (TIME_BUDGET_EXCEEDED, BUDGET_MESSAGE):
        converged, message = verdict(converged, message, remaining_decrease(jac, r, scale, p, bounds),
                                     cost, verdict_tol, noise_cost)
    return SolveResult(p, r, jac, cost, it, evals + 1, converged, message)


def _pin(p: np.ndarray, jtj: np.ndarray, g: np.ndarray, lo: np.ndarray,
         hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Take the parameters that sit on a bound with the descent pushing them out of the
    step (their rows and columns of ``J^T J`` and their gradient set to 0): the step then
    moves the others only, as if those were constants."""
    pinned = ((p <= lo) & (g > 0.0)) | ((p >= hi) & (g < 0.0))
    if not pinned.any():
        return jtj, g
    jtj, g = jtj.copy(), g.copy()
    jtj[pinned, :] = 0.0
    jtj[:, pinned] = 0.0
    g[pinned] = 0.0
    return jtj, g


def remaining_decrease(jac: np.ndarray, r: np.ndarray, scale: np.ndarray, p: np.ndarray,
                       bounds: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """How much the cost could still drop in one step: the decrease the Gauss-Newton model of
    ``|r + J s|^2`` predicts for its minimising step, capped per parameter by ``scale`` (the
    solver's trust region) and barely damped (a flat direction stays finite), the parameters
    pinned on a bound held (``bounds``); cost units."""
    jtj, g, diag = normal_equations(jac, r)
    if bounds is not None:
        jtj, g = _pin(p, jtj, g, *bounds)
    try:
        _, _, predicted = damped_step(jtj, g, diag, 1e-9, scale)
    except np.linalg.LinAlgError:  # pragma: no cover - the damping makes it definite
        return math.inf
    return predicted if math.isfinite(predicted) else math.inf

"""Damped least squares (Levenberg-Marquardt) for small, dense problems.

scipy.optimize.least_squares costs ~1 ms of Python per call before any work, which is the whole
budget of a frame, so this is a plain Marquardt loop: ``(J^T J + lam diag(J^T J)) dp = -J^T r``
on a few parameters, the damping raised on a rejected step and lowered on an accepted one, and
a per-parameter step cap (a trust region) so a poor start cannot throw the contact off the
array in one step.  The residual function returns residuals and Jacobian together because the
forward model computes both in one pass.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tactiled.fit.budget import EXHAUSTED, BudgetExhausted
from tactiled.physics.kernels import damped_step, finite_cost, normal_equations

ResidualFn = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
TIME_BUDGET_EXCEEDED = "time budget exceeded"
#: The message of a search the fit's budget stopped (tactiled.fit.budget): not converged.
BUDGET_MESSAGE = f"{EXHAUSTED} (the work of the next model evaluation)"
#: Added to the message of a search that ended without its stopping rule firing (the
#: iteration cap) but within ``verdict_tol`` of the minimum: converged.
WITHIN_TOLERANCE = "within tolerance of the least-squares minimum"
#: The message of a search whose stopping rule fired short of that: not converged.
STALLED = "stalled short of the least-squares minimum (steps too small to get there)"


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
    """Minimise ``sum(r(p)^2)`` from ``p0``.

    ``max_step`` caps each component of a step (same units as p).  Convergence when every
    accepted step is below ``xtol`` (in units of ``max_step`` where given) or the relative
    decrease of the cost is below ``ftol``.  A residual function that raises ``ValueError`` or
    returns non-finite values rejects the trial step (treated as an infinite cost).
    ``deadline`` (``time.perf_counter()`` seconds) stops the search before the next
    evaluation once passed: not converged, "time budget exceeded".  A residual function that
    raises :class:`~tactiled.fit.budget.BudgetExhausted` (the fit's budget cannot pay for that
    evaluation) stops it the same way: not converged, ``BUDGET_MESSAGE``.

    ``verdict_tol`` (cost units) decides ``converged`` on where the search ended, not on which
    stopping rule fired: converged when the Gauss-Newton model at the final point puts the
    cheapest step within the caps less than ``verdict_tol`` of cost below it
    (:func:`remaining_decrease`), whatever ended the loop.  A tolerance far above rounding
    cannot be crossed by last-bit differences; whether the iteration cap or a stopping rule
    comes first can.  Without it the stopping rule is the verdict.

    ``bounds`` (lower, upper arrays; +-inf for none) keep the parameters in a box: a trial
    point is clipped into it, and a parameter on a bound that the descent pushes outwards is
    held there while the others move (see :func:`_pin`).

    ``noise_cost`` (cost units): the cost of a fit whose residuals are the noise (its degrees
    of freedom).  Beyond it ``atol`` and ``verdict_tol`` grow with ``cost / noise_cost``: a
    fit its model does not explain has errors that many times larger than the noise's, and a
    step small against the noise's sigmas is smaller still against those.  Default: never.
    """
    p = np.array(p0, dtype=float)
    if bounds is not None:
        lo, hi = bounds
        p = np.clip(p, lo, hi)
    try:
        r, jac = fun(p)
    except BudgetExhausted:
        return SolveResult(p, np.zeros(0), np.zeros((0, p.size)), float("inf"), 0, 0, False,
                           BUDGET_MESSAGE)
    except (ValueError, OverflowError) as err:
        return SolveResult(p, np.zeros(0), np.zeros((0, p.size)), float("inf"), 0, 1, False,
                           f"invalid start: {err}")
    if not math.isfinite(finite_cost(r, jac)):
        return SolveResult(p, r, jac, float("inf"), 0, 1, False, "non-finite residual at start")
    cost = finite_cost(r, jac)
    lam, nu = lam0, 2.0
    evals = 1
    scale = np.ones_like(p) if max_step is None else np.asarray(max_step, dtype=float)
    message = "maximum iterations reached"
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        jtj, g, diag = normal_equations(jac, r)
        if bounds is not None:
            jtj, g = _pin(p, jtj, g, lo, hi)
        accepted = False
        while lam < 1e12:
            try:
                step, over, predicted = damped_step(jtj, g, diag, lam, scale)
            except np.linalg.LinAlgError:  # pragma: no cover - damping makes A definite
                lam *= 10.0
                continue
            if over < xtol:
                converged, message = True, "step below xtol"
                break
            if predicted <= ftol * cost + atol * max(1.0, cost / noise_cost):
                converged, message = True, "predicted decrease below ftol"
                break
            if deadline is not None and time.perf_counter() > deadline:
                message = TIME_BUDGET_EXCEEDED
                break
            trial = p + step if bounds is None else np.clip(p + step, lo, hi)
            try:
                r_new, jac_new = fun(trial)
                cost_new = finite_cost(r_new, jac_new)
            except BudgetExhausted:
                message = BUDGET_MESSAGE
                break
            except (ValueError, OverflowError):  # an invalid trial point: reject the step
                cost_new = math.inf
            evals += 1
            if cost_new < math.inf:
                if cost_new < cost:
                    rho = (cost - cost_new) / predicted
                    lam = max(lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 1e-12)
                    nu = 2.0
                    accepted = True
                    break
            lam *= nu
            nu *= 2.0
        if converged or message is TIME_BUDGET_EXCEEDED or message is BUDGET_MESSAGE:
            break
        if not accepted:
            message = "no step reduces the cost (damping exhausted)"
            break
        p, r, jac, cost = trial, r_new, jac_new, cost_new
    if verdict_tol is not None and message not in (TIME_BUDGET_EXCEEDED, BUDGET_MESSAGE):
        close = remaining_decrease(jac, r, scale, p, bounds) <= verdict_tol * max(1.0, cost / noise_cost)
        if close and not converged:
            message = f"{message}, {WITHIN_TOLERANCE}"
        elif converged and not close:
            message = STALLED
        converged = close
    return SolveResult(p, r, jac, cost, it, evals, converged, message)


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

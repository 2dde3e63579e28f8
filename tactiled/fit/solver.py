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

from tactiled.physics.kernels import damped_step, finite_cost, normal_equations

ResidualFn = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
TIME_BUDGET_EXCEEDED = "time budget exceeded"


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
) -> SolveResult:
    """Minimise ``sum(r(p)^2)`` from ``p0``.

    ``max_step`` caps each component of a step (same units as p).  Convergence when every
    accepted step is below ``xtol`` (in units of ``max_step`` where given) or the relative
    decrease of the cost is below ``ftol``.  A residual function that raises ``ValueError`` or
    returns non-finite values rejects the trial step (treated as an infinite cost).
    ``deadline`` (``time.perf_counter()`` seconds) stops the search before the next
    evaluation once passed: not converged, "time budget exceeded".
    """
    p = np.array(p0, dtype=float)
    try:
        r, jac = fun(p)
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
            if predicted <= ftol * cost + atol:
                converged, message = True, "predicted decrease below ftol"
                break
            if deadline is not None and time.perf_counter() > deadline:
                message = TIME_BUDGET_EXCEEDED
                break
            trial = p + step
            try:
                r_new, jac_new = fun(trial)
                cost_new = finite_cost(r_new, jac_new)
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
        if converged or message is TIME_BUDGET_EXCEEDED:
            break
        if not accepted:
            message = "no step reduces the cost (damping exhausted)"
            break
        p, r, jac, cost = trial, r_new, jac_new, cost_new
    return SolveResult(p, r, jac, cost, it, evals, converged, message)

"""A model's window evaluation and the whole search of one start, compiled (core/search.cpp).

The Python bodies here are the core's reference: :func:`_evaluate` (the model's parameter
map, the Hertz solve, the quadrature rule's size, the window residual) and :func:`search`,
which runs the one Levenberg-Marquardt loop (:func:`tactiled.fit.solver.descend`) on it; the
core runs the same steps in one call, operation for operation (tests/native).
"""

# With a work budget (:mod:`tactiled.fit.budget`) every evaluation runs here: the budget refuses
# any it cannot pay for.  Without one, a contact needing more than :data:`MAX_COMPILED_NODES`
# nodes per axis returns :data:`FALLBACK`, and the caller runs
# :func:`tactiled.fit.solver.levenberg_marquardt`, which checks the wall clock between
# evaluations.

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from tactiled import native

from tactiled.fit.budget import DENIED, LINE_CHARGED_TACTELS, Budget, evaluation_work, line_work
from tactiled.fit.models import physical_map
from tactiled.fit.solver import (BUDGET_MESSAGE, DAMPING_EXHAUSTED, DECREASE_BELOW_FTOL,
                                 MAX_ITERATIONS, STEP_BELOW_XTOL, SolveResult, Stop, descend,
                                 remaining_decrease, verdict)
from tactiled.physics.hertz import ellipse_core
from tactiled.physics.kernels import finite_cost, window_residual
from tactiled.physics.line import line_points, line_residual
from tactiled.physics.quadrature_rules import _LADDER, MAX_NODES, MIN_NODES, _rule_s, _rule_u

#: Largest rule (nodes per axis) the compiled search uses without a work budget; beyond it,
#: the Python solver.
MAX_COMPILED_NODES = 64
#: Model kinds (the order of ``tactiled.fit.models``' parameter maps below).
KINDS = {"cylinder": 0, "sphere": 1, "general": 2}
#: The line model's kind (a cylinder on a flat array, ``tactiled.fit.line``): its own
#: evaluation, the same search.
LINE = 3

# status codes of an evaluation and of a search
_OK, _INVALID_LINE, _INVALID_LONG, FALLBACK, _BUDGET = 0, 1, 2, 3, 4
#: messages, by code, as the Python solver words them
MESSAGES = (MAX_ITERATIONS, STEP_BELOW_XTOL, DECREASE_BELOW_FTOL, DAMPING_EXHAUSTED, BUDGET_MESSAGE)
_FALLBACK_MESSAGE = "a rule past the compiled limit"


@lru_cache(maxsize=1)
def rule_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(ladder, offsets, u, wu, s, ws)``: every ladder size and its
    Gauss-Jacobi(1, 1) (u) and Gauss-Chebyshev-U (s) rules, packed (from the same cached rules
    the Python path uses, so the nodes are the same numbers)."""
    ladder = np.array(_LADDER, dtype=np.int64)
    sizes = list(_LADDER)
    offsets = np.zeros(len(sizes) + 1, dtype=np.int64)
    us, wus, ss, wss = [], [], [], []
    for i, n in enumerate(sizes):
        u, wu = _rule_u(n)
        s, ws = _rule_s(n)
        us.append(u)
        wus.append(wu)
        ss.append(s)
        wss.append(ws)
        offsets[i + 1] = offsets[i] + n
    return (ladder, offsets, np.concatenate(us), np.concatenate(wus), np.concatenate(ss),
            np.concatenate(wss))


def _nodes(extent: float, depth: float, tol: float, ladder: np.ndarray) -> int:
    """``quadrature_rules.nodes_for``: the ladder size, or -1 beyond MAX_NODES (too long to integrate)."""
    r = depth / max(extent, 1e-12)
    log_rho = math.asinh(r)
    n = math.ceil(0.5 * math.log(1.0 / tol) / log_rho) if log_rho > 0 else MAX_NODES + 1
    if n > MAX_NODES:
        return -1
    return ladder[np.searchsorted(ladder, max(n, MIN_NODES))]


def _rule_index(n: int, ladder: np.ndarray) -> int:
    return np.searchsorted(ladder, n)


_work = evaluation_work
_line_work = line_work


def _evaluate_line(p, comp, scale, dmin, tol, imp, xs, ys, target, valid, inv_scale, ex, ey,
                   ladder, offsets, rs, rws, work_left, max_nodes):
    """:func:`_evaluate` for the line model (``tactiled.fit.line``): the rule across the line
    its half-width needs (``_INVALID_LONG`` beyond ``MAX_NODES``), its work
    (``tactiled.fit.budget.line_work``), then :func:`tactiled.physics.line.line_residual`.
    The cover's modulus comes back from ``scale = 3/(2 pi E)``."""
    empty_r = np.zeros(1)
    empty_j = np.zeros((1, 4))
    b = math.sqrt(4.0 * math.exp(p[2]) * math.exp(p[0]) * comp / math.pi)
    n = _nodes(b, dmin, tol, ladder)
    if n < 0:
        empty_r[0] = b
        return _INVALID_LONG, empty_r, empty_j, 0.0
    work = _line_work(n, min(int(valid.sum()), LINE_CHARGED_TACTELS))  # a band: its valid tactels
    if work > work_left:
        return _BUDGET, empty_r, empty_j, 0.0
    if n > max_nodes:
        return FALLBACK, empty_r, empty_j, 0.0
    o = offsets[_rule_index(n, ladder)]
    px, py, ref_x, ref_y = line_points(xs, ys, ex, ey)
    r, jac = line_residual(p, px, py, ref_x, ref_y, imp, 3.0 / (2.0 * math.pi * scale), comp,
                           rs[o:o + n], rws[o:o + n], target, valid, inv_scale)
    return _OK, r, jac, float(work)


def _evaluate(kind, p, k, rf, comp, scale, dmin, tol, imp, xs, ys, target, valid, inv_scale, ex, ey,
              ladder, offsets, ru, rwu, rs, rws, work_left, max_nodes):
    """One evaluation of the residual closure: ``(status, r, J, work)``; status ``_OK``, an
    invalid point (``_INVALID_LINE``: infinite line contact; ``_INVALID_LONG``: too long to
    integrate, with the semi-axis in ``r[0]``), ``FALLBACK`` (a rule past the compiled limit)
    or ``_BUDGET`` (its work, ``tactiled.fit.budget.evaluation_work``, exceeds ``work_left``:
    not evaluated); ``FALLBACK`` beyond ``max_nodes`` per axis.  ``work`` is what the evaluation cost (0 when none was made).
    ``kind`` :data:`LINE`: the line model (:func:`_evaluate_line`)."""
    if kind == LINE:
        return _evaluate_line(p, comp, scale, dmin, tol, imp, xs, ys, target, valid, inv_scale, ex,
                              ey, ladder, offsets, rs, rws, work_left, max_nodes)
    d = np.zeros((6, k))
    ka, kb, psi, force, x0, y0 = physical_map(kind, p, d)
    hj = np.empty((3, 4))
    a, b, theta, _ = ellipse_core(ka, kb, psi, force, rf, comp, hj)
    empty_r = np.zeros(1)
    empty_j = np.zeros((1, k))
    if a < 0.0:
        return _INVALID_LINE, empty_r, empty_j, 0.0
    nu = _nodes(a, dmin, tol, ladder)
    if nu < 0:
        empty_r[0] = a
        return _INVALID_LONG, empty_r, empty_j, 0.0
    ns = _nodes(b, dmin, tol, ladder)
    if ns < 0:
        empty_r[0] = b
        return _INVALID_LONG, empty_r, empty_j, 0.0
    work = _work(nu, ns, target.shape[0])
    if work > work_left:
        return _BUDGET, empty_r, empty_j, 0.0
    if nu > max_nodes or ns > max_nodes:
        return FALLBACK, empty_r, empty_j, 0.0
    iu, is_ = _rule_index(nu, ladder), _rule_index(ns, ladder)
    ou, os_ = offsets[iu], offsets[is_]
    nq = nu * ns
    u = np.empty(nq)
    v = np.empty(nq)
    w = np.empty(nq)
    for i in range(nu):
        ui, wui = ru[ou + i], rwu[ou + i]
        root = math.sqrt(1.0 - ui * ui)
        for j in range(ns):
            q = i * ns + j
            u[q] = ui
            v[q] = root * rs[os_ + j]
            w[q] = wui * rws[os_ + j]
    geo = np.empty(7)
    geo[0], geo[1], geo[2], geo[3], geo[4], geo[5], geo[6] = x0, y0, a, b, theta, force, scale
    r, jac = window_residual(geo, hj, d, u, v, w, xs, ys, imp, target, valid, inv_scale, ex, ey)
    return _OK, r, jac, float(work)


def ellipse_at(kind: int, p: np.ndarray, rf: float, comp: float) -> tuple[float, float, float, float]:
    """The Hertz ellipse ``(a, b, theta, m)`` of the model ``kind`` at ``p`` (``a < 0``: an
    infinite line), by the same map and solve as an evaluation, in one call."""
    d = np.zeros((6, p.shape[0]))
    ka, kb, psi, force, _, _ = physical_map(kind, p, d)
    return ellipse_core(ka, kb, psi, force, rf, comp, np.empty((0, 0)))


def search(kind, p0, max_step, max_iter, xtol, ftol, lam0, atol, lo, hi, rf, comp, scale, dmin, tol,
           imp, xs, ys, target, valid, inv_scale, ex, ey, ladder, offsets, ru, rwu, rs, rws,
           work_left, max_nodes, noise_cost, reserve, grant_cost, start_ok):
    """:func:`tactiled.fit.solver.descend` on :func:`_evaluate` for one model and start (the box ``lo``,
    ``hi`` as its ``bounds``; the verdict is the caller's).  Returns ``(status, p, r, J, cost,
    iterations, evaluations, converged, message code, remaining, work)``; status ``_OK``,
    ``_INVALID_LINE`` / ``_INVALID_LONG`` (invalid start; semi-axis in ``cost``), ``_BUDGET``
    (the start's evaluation exceeds ``work_left``) or ``FALLBACK``; ``atol`` grows with the
    cost beyond ``noise_cost`` (``solver.levenberg_marquardt``'s); ``remaining`` is
    ``solver.remaining_decrease`` at the end point (for the caller's verdict; inf where there
    is none); ``work`` the evaluations' work (``tactiled.fit.budget``).  A trial point whose
    evaluation the work left cannot pay for ends the search there (message code 4).

    ``reserve``: work beyond ``work_left`` that an evaluation may draw on when the cost of the
    point it steps from is at most ``grant_cost`` (``tactiled.fit.budget.Budget.grant_cost``),
    the start's evaluation when ``start_ok`` (a start whose cost is known to be within it).
    A search that drew on it has ``work`` over ``work_left``: the allowance is granted."""
    k = p0.shape[0]
    p = np.clip(p0, lo, hi)
    status, r, jac, work = _evaluate(kind, p, k, rf, comp, scale, dmin, tol, imp, xs, ys, target,
                                     valid, inv_scale, ex, ey, ladder, offsets, ru, rwu, rs, rws,
                                     work_left + (reserve if start_ok else 0.0), max_nodes)
    if status != _OK:
        extent = r[0] if status == _INVALID_LONG else 0.0
        return status, p, r, jac, extent, 0, 1, False, -1, math.inf, work
    cost = finite_cost(r, jac)
    if not math.isfinite(cost):  # non-finite residual at start
        return _OK, p, r, jac, math.inf, 0, 1, False, -2, math.inf, work
    spent = [work]

    def evaluate(trial: np.ndarray, cost_from: float) -> tuple[np.ndarray, np.ndarray, float]:
        work = spent[0]
        avail = work_left + (reserve if cost_from <= grant_cost or work > work_left else 0.0)
        st, r_new, jac_new, w = _evaluate(kind, trial, k, rf, comp, scale, dmin, tol, imp, xs, ys,
                                          target, valid, inv_scale, ex, ey, ladder, offsets, ru,
                                          rwu, rs, rws, avail - work, max_nodes)
        if st == FALLBACK:
            raise Stop(_FALLBACK_MESSAGE)
        if st == _BUDGET:
            raise Stop(BUDGET_MESSAGE)
        spent[0] = work + w
        return r_new, jac_new, finite_cost(r_new, jac_new) if st == _OK else math.inf

    p, r, jac, cost, it, evals, converged, message = descend(
        evaluate, p, r, jac, cost, max_step, max_iter, xtol, ftol, lam0, atol, noise_cost, (lo, hi))
    if message == _FALLBACK_MESSAGE:
        return FALLBACK, p, r, jac, cost, it, evals + 1, False, 0, math.inf, spent[0]
    return (_OK, p, r, jac, cost, it, evals + 1, converged, MESSAGES.index(message),
            remaining_decrease(jac, r, max_step, p, (lo, hi)), spent[0])


#: the Python bodies (the reference); the module's names run the compiled core's
#: (core/search.cpp) when it is loaded
REFERENCE = native.bind(globals(), {"_evaluate": "evaluate", "search": "search",
                                    "ellipse_at": "ellipse_at"})


def solve(kind: int, p0: np.ndarray, max_step: np.ndarray, max_iter: int, atol: float, model_args: tuple,
          window_args: tuple, tol: float, xtol: float = 1e-9, ftol: float = 1e-10,
          lam0: float = 1e-3, bounds: tuple[np.ndarray, np.ndarray] | None = None,
          verdict_tol: float | None = None, budget: Budget | None = None,
          noise_cost: float = math.inf, grant_cost: float = -1.0,
          start_ok: bool = False) -> SolveResult | None:
    """Run :func:`search`; a :class:`SolveResult` worded and judged as the Python solver
    words and judges it (``verdict_tol``, ``bounds``: see ``levenberg_marquardt``), or None
    when the search must fall back to the Python solver.  ``budget``: the fit's
    (:mod:`tactiled.fit.budget`), charged with the search's iterations and work (also those
    spent before a fallback); a search it stops is not converged, whatever the verdict.
    ``noise_cost``: see ``levenberg_marquardt``.  ``grant_cost``: the cost within which the
    search earns the budget's allowance (``Budget.grant_cost``; -1: none to grant);
    ``start_ok``: the start's cost is known to be within it (:func:`search`)."""
    rf, comp, scale, dmin, imp = model_args
    xs, ys, target, valid, inv_scale, ex, ey = window_args
    p0 = np.asarray(p0, dtype=float)
    lo, hi = bounds if bounds is not None else (np.full(p0.size, -np.inf), np.full(p0.size, np.inf))
    work_left = math.inf if budget is None else float(budget.work_left())
    reserve = 0.0 if budget is None or grant_cost < 0.0 else budget.reserve
    status, p, r, jac, cost, it, evals, converged, msg, remaining, work = search(
        kind, p0, max_step, max_iter, xtol, ftol, lam0, atol, lo, hi, rf, comp,
        scale, dmin, tol, imp, xs, ys, target, valid, inv_scale, ex, ey, *rule_tables(),
        work_left, MAX_NODES if math.isfinite(work_left) else MAX_COMPILED_NODES, noise_cost,
        reserve, grant_cost, start_ok and grant_cost >= 0.0)
    if budget is not None:
        if work > work_left:
            budget.grant()
        budget.charge(it, work)
    if status == FALLBACK:
        return None
    if status == _BUDGET or msg == 4:
        # stopped at the base work with the allowance there to grant: the fit did not earn it
        denied = reserve > 0.0 and budget is not None and not budget.granted and (
            (not start_ok if status == _BUDGET else cost > grant_cost))
        if budget is not None:
            if denied:  # this search stops; a later one may still earn the allowance
                budget.denied = True
            else:
                budget.exhausted = True
        if status == _BUDGET:
            return SolveResult(p, np.zeros(0), np.zeros((0, p.size)), math.inf, 0, 0, False,
                               DENIED if denied else BUDGET_MESSAGE)
        if denied:
            return SolveResult(p, r, jac, cost, it, evals, False, DENIED)
    if status == _INVALID_LINE:
        return SolveResult(p, np.zeros(0), np.zeros((0, p.size)), math.inf, 0, 1, False,
                           "invalid start: infinite line contact")
    if status == _INVALID_LONG:
        return SolveResult(p, np.zeros(0), np.zeros((0, p.size)), math.inf, 0, 1, False,
                           f"invalid start: contact ellipse semi-axis {cost:.4g} mm is too long for "
                           f"the planar model (over {MAX_NODES} quadrature nodes at tol {tol:g})")
    if msg == -2:
        return SolveResult(p, r, jac, math.inf, 0, 1, False, "non-finite residual at start")
    message = MESSAGES[msg]
    if msg == 4:
        return SolveResult(p, r, jac, cost, it, evals, False, message)
    if verdict_tol is not None:
        converged, message = verdict(bool(converged), message, remaining, cost, verdict_tol,
                                     noise_cost)
    return SolveResult(p, r, jac, cost, it, evals, bool(converged), message)


def evaluate(kind: int, p: np.ndarray, model_args: tuple, window_args: tuple,
             tol: float) -> tuple[str, np.ndarray, np.ndarray]:
    """One evaluation of the scaled window residual and its Jacobian at ``p`` (the search's
    own, compiled): ``("ok", r, J)``, ``("invalid", ...)`` at a point outside the model's
    domain, or ``("fallback", ...)`` past the compiled rule limit (use the Python residual)."""
    rf, comp, scale, dmin, imp = model_args
    status, r, jac, _ = _evaluate(kind, np.asarray(p, dtype=float), p.size, rf, comp, scale,
                                  dmin, tol, imp, *window_args, *rule_tables(), math.inf,
                                  MAX_COMPILED_NODES)
    if status == _OK:
        return "ok", r, jac
    return ("fallback" if status == FALLBACK else "invalid"), r, jac

"""Inner loop of the forward model: quadrature of the impulse response over the nodes.

The numpy expression of the same sum (``StrainModel.strain_and_jacobian_numpy``) costs ~200 us
for a 4x4 window because it is some fifty numpy calls on tiny arrays; these loops run in the
compiled core (core/quadrature.cpp, core/lsq.cpp, built by ``pip install``).  The Python bodies
here are the reference it is held to (tests/native), and run with ``TACTILED_CORE=python``.
"""

from __future__ import annotations

import math

import numpy as np

from tactiled import native

_INV_PI = 1.0 / math.pi


def strain_with_jacobian(
    geo: np.ndarray,
    hj: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    w: np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
    imp: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Strains and their Jacobian with respect to ``(kappa_a, kappa_b, psi, F, x0, y0)``.

    ``geo = [x0, y0, a, b, theta, F, scale]`` (mm, rad, N; ``scale = 3/(2 pi E)``), ``hj`` the
    3x4 Hertz Jacobian ``d(a, b, theta)/d(kappa_a, kappa_b, psi, F)``, ``(u, v, w)`` the unit-disk
    rule, ``imp = [d_x, nu_x, d_y, nu_y]``.  Returns ``(M, N)`` and ``(M, N, 6)`` arrays.

    The kernel is separable, so the per-axis responses at every node are tabulated first
    (``HX[i, q]``, ``HY[j, q]`` and their slopes) and each tactel's value and derivatives are then
    sums over the nodes, which vectorise.
    """
    x0, y0, a, b, theta, force, scale = (float(g) for g in geo[:7])
    dep_x, nu_x, dep_y, nu_y = (float(g) for g in imp[:4])
    c, s = math.cos(theta), math.sin(theta)
    cx = 2.0 * dep_x * _INV_PI
    cy = 2.0 * dep_y * _INV_PI
    dx2 = dep_x * dep_x
    dy2 = dep_y * dep_y
    # node offsets from the centre and their motion per unit (a, b): (u c, u s), (-v s, v c)
    au, bv = a * u, b * v
    ex = au * c - bv * s
    ey = au * s + bv * c
    uc, us, vs, vc = u * c, u * s, -v * s, v * c
    # the per-axis responses at every node, (tactels along the axis, nodes)
    t = xs[:, None] - x0 - ex[None, :]
    t2 = t * t
    sx = t2 + dx2
    inv = w / (sx * sx)
    hx = cx * (dx2 - nu_x * t2) * inv
    dhx = 2.0 * cx * t * (nu_x * t2 - (nu_x + 2.0) * dx2) * inv / sx
    t = ys[:, None] - y0 - ey[None, :]
    t2 = t * t
    sy = t2 + dy2
    inv = 1.0 / (sy * sy)
    hy = cy * (dy2 - nu_y * t2) * inv
    dhy = 2.0 * cy * t * (nu_y * t2 - (nu_y + 2.0) * dy2) * inv / sy
    # every tactel's sums over the nodes, (M, N, nodes), each summed node after node as the
    # core sums (a running difference from 0 is minus the running sum: rounding is symmetric)
    ax_ = dhx[:, None, :] * hy[None, :, :]  # d/d(node x) is minus this
    by_ = hx[:, None, :] * dhy[None, :, :]  # d/d(node y) is minus this
    sv = _node_sum(hx[:, None, :] * hy[None, :, :])
    d0 = -_node_sum(ax_)
    d1 = -_node_sum(by_)
    d2 = -_node_sum(ax_ * uc + by_ * us)
    d3 = -_node_sum(ax_ * vs + by_ * vc)
    d4 = _node_sum(ax_ * ey - by_ * ex)  # theta: node motion (-ey, ex)
    kf = scale * force
    jac = np.empty((xs.shape[0], ys.shape[0], 6))
    for k in range(4):
        jac[:, :, k] = kf * (d2 * hj[0, k] + d3 * hj[1, k] + d4 * hj[2, k])
    jac[:, :, 3] += scale * sv
    jac[:, :, 4] = kf * d0
    jac[:, :, 5] = kf * d1
    return kf * sv, jac


def _node_sum(terms: np.ndarray) -> np.ndarray:
    """``terms`` (..., nodes) summed over the last axis one node after another, from 0 (the
    core's order; ``np.sum`` sums pairwise, to other bits)."""
    if terms.shape[-1] == 0:
        return np.zeros(terms.shape[:-1])
    return 0.0 + np.cumsum(terms, axis=-1)[..., -1]


def quadrature(
    x0: float,
    y0: float,
    a: float,
    b: float,
    theta: float,
    u: np.ndarray,
    v: np.ndarray,
    w: np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
    dep_x: float,
    nu_x: float,
    dep_y: float,
    nu_y: float,
) -> np.ndarray:
    """``S[m, n]`` alone (see :func:`quadrature_with_derivatives`)."""
    c, s = math.cos(theta), math.sin(theta)
    cx = 2.0 * dep_x * _INV_PI
    cy = 2.0 * dep_y * _INV_PI
    dx2 = dep_x * dep_x
    dy2 = dep_y * dep_y
    au, bv = a * u, b * v
    xq = x0 + au * c - bv * s
    yq = y0 + au * s + bv * c
    t = xs[:, None] - xq[None, :]
    t2 = t * t
    sx = t2 + dx2
    hx = cx * (dx2 - nu_x * t2) / (sx * sx) * w
    t = ys[:, None] - yq[None, :]
    t2 = t * t
    sy = t2 + dy2
    hy = cy * (dy2 - nu_y * t2) / (sy * sy)
    return _node_sum(hx[:, None, :] * hy[None, :, :])


def quadrature_points(
    x0: float,
    y0: float,
    a: float,
    b: float,
    theta: float,
    u: np.ndarray,
    v: np.ndarray,
    w: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    imp: np.ndarray,
) -> np.ndarray:
    """The sum of :func:`quadrature` at arbitrary points ``(px[k], py[k])`` (mm): tactels off
    the grid, evaluated exactly (the simulator's truth for a finger with displaced tactels)."""
    dep_x, nu_x, dep_y, nu_y = imp[0], imp[1], imp[2], imp[3]
    npt, nq = px.shape[0], u.shape[0]
    val = np.zeros(npt)
    c, s = math.cos(theta), math.sin(theta)
    cx = 2.0 * dep_x * _INV_PI
    cy = 2.0 * dep_y * _INV_PI
    dx2 = dep_x * dep_x
    dy2 = dep_y * dep_y
    for q in range(nq):
        au = a * u[q]
        bv = b * v[q]
        xq = x0 + au * c - bv * s
        yq = y0 + au * s + bv * c
        for k in range(npt):
            tx = px[k] - xq
            tx2 = tx * tx  # a product, not ``** 2`` (libm's pow may differ in the last bit)
            sx = tx2 + dx2
            ty = py[k] - yq
            ty2 = ty * ty
            sy = ty2 + dy2
            val[k] += cx * (dx2 - nu_x * tx2) / (sx * sx) * cy * (dy2 - nu_y * ty2) / (sy * sy) * w[q]
    return val


def window_residual(
    geo: np.ndarray,
    hj: np.ndarray,
    dphys: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    w: np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
    imp: np.ndarray,
    target: np.ndarray,
    valid: np.ndarray,
    inv_scale: np.ndarray,
    ex: np.ndarray,
    ey: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Scaled residuals ``(model - target) * inv_scale`` over the valid tactels of a window
    and their Jacobian with respect to a model's own parameters.

    ``target``, ``valid``, ``inv_scale`` (1 / (peak strain x the tactel's relative standard
    deviation)), ``ex`` and ``ey`` (the tactels' displacements from the grid ``xs x ys``, mm)
    are per window tactel, flattened row-major; ``dphys`` is
    ``d(kappa_a, kappa_b, psi, F, x0, y0)/d(params)``, shape (6, k).

    A displaced tactel's strain is taken to first order, ``s(X + e) = s(X) - e . ds/d(x0, y0)``
    (the strain depends on ``X - x0`` only); the Jacobian keeps the grid's (the dropped term is
    ``e`` times a second derivative: for the 0.1 mm displacements of a real array, ~1/40 of a
    term that is itself small).  Zero displacements give the grid's values bit for bit.
    """
    val, jac6 = strain_with_jacobian(geo, hj, u, v, w, xs, ys, imp)
    ny = ys.shape[0]
    k = dphys.shape[1]
    n = 0
    for idx in range(valid.shape[0]):
        if valid[idx]:
            n += 1
    r = np.empty(n)
    jac = np.zeros((n, k))
    row = 0
    for idx in range(valid.shape[0]):
        if not valid[idx]:
            continue
        i, j = idx // ny, idx % ny
        scale = inv_scale[idx]
        r[row] = (val[i, j] - ex[idx] * jac6[i, j, 4] - ey[idx] * jac6[i, j, 5] - target[idx]) * scale
        for c in range(k):
            acc = 0.0
            for e in range(6):
                acc += jac6[i, j, e] * dphys[e, c]
            jac[row, c] = acc * scale
        row += 1
    return r, jac


def normal_equations(jac: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``J^T J``, ``J^T r`` and the Marquardt scaling ``diag(J^T J)`` (floored at 1e-12 of its
    largest entry so a dead parameter still gets damped), compiled: numpy's per-call overhead
    on 5x5 products dominates."""
    jtj = jac.T @ jac
    g = jac.T @ r
    k = jtj.shape[0]
    diag = np.empty(k)
    top = 0.0
    for i in range(k):
        top = max(top, jtj[i, i])
    floor = 1e-12 * max(top, 1e-300)
    for i in range(k):
        diag[i] = max(jtj[i, i], floor)
    return jtj, g, diag


def finite_cost(r: np.ndarray, jac: np.ndarray) -> float:
    """``sum(r^2)``, or inf if any residual or Jacobian entry is not finite."""
    if not np.isfinite(np.sum(jac)):
        return np.inf
    c = 0.0
    for x in r:
        c += x * x
    return c if np.isfinite(c) else np.inf


def damped_step(
    jtj: np.ndarray, g: np.ndarray, diag: np.ndarray, lam: float, scale: np.ndarray
) -> tuple[np.ndarray, float, float]:
    """Solve ``(J^T J + lam diag) step = -J^T r``, cap the step so no component exceeds its
    ``scale``, and return ``(step, max |step|/scale, predicted cost decrease)``; the cost model
    is ``|r + J s|^2 = cost + 2 g.s + s.JTJ.s``."""
    a = jtj.copy()
    n = a.shape[0]
    for i in range(n):
        a[i, i] += lam * diag[i]
    step = -np.linalg.solve(a, g)
    over = 0.0
    for i in range(n):
        over = max(over, abs(step[i]) / scale[i])
    if over > 1.0:
        step /= over
        over = 1.0
    predicted = -(2.0 * (g @ step) + step @ (jtj @ step))
    return step, over, predicted


def cramer_rao(jraw: np.ndarray, grad: np.ndarray, sigma: float) -> tuple[np.ndarray, float]:
    """1-sigma bounds of the quantities whose gradients are the rows of ``grad`` (NaN rows give
    NaN), from ``cov = sigma^2 (J^T J)^-1``; and the condition number of J (inf if singular).

    J's columns are scaled to unit norm first, so the condition number measures how nearly
    parameters trade off against each other, not their units.
    """
    k = jraw.shape[1]
    col = np.empty(k)
    for j in range(k):
        col[j] = math.sqrt(np.sum(jraw[:, j] ** 2))
    nq = grad.shape[0]
    std = np.full(nq, np.nan)
    if np.min(col) <= 0.0:
        return std, np.inf
    jn = jraw / col
    ev, vec = np.linalg.eigh(jn.T @ jn)
    if ev[0] <= 0.0:
        return std, np.inf
    cond = math.sqrt(ev[-1] / ev[0])
    cov = (vec / ev) @ vec.T
    for i in range(k):
        for j in range(k):
            cov[i, j] *= sigma * sigma / (col[i] * col[j])
    for q in range(nq):
        g = grad[q]
        var = g @ (cov @ g)
        if var >= 0.0:
            std[q] = math.sqrt(var)
    return std, cond


#: the Python bodies (the reference); the module's names run the compiled core's when it is loaded
REFERENCE = native.bind(globals(), ("strain_with_jacobian", "quadrature", "quadrature_points",
                                    "window_residual", "normal_equations", "finite_cost",
                                    "damped_step", "cramer_rao"))

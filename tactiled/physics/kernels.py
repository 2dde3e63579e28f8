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
    x0, y0, a, b, theta, force, scale = geo[0], geo[1], geo[2], geo[3], geo[4], geo[5], geo[6]
    dep_x, nu_x, dep_y, nu_y = imp[0], imp[1], imp[2], imp[3]
    mx, ny, nq = xs.shape[0], ys.shape[0], u.shape[0]
    c, s = math.cos(theta), math.sin(theta)
    cx = 2.0 * dep_x * _INV_PI
    cy = 2.0 * dep_y * _INV_PI
    dx2 = dep_x * dep_x
    dy2 = dep_y * dep_y
    # node offsets from the centre and their motion per unit (a, b): (u c, u s), (-v s, v c)
    ex = np.empty(nq)
    ey = np.empty(nq)
    uc = np.empty(nq)
    us = np.empty(nq)
    vs = np.empty(nq)
    vc = np.empty(nq)
    for q in range(nq):
        au = a * u[q]
        bv = b * v[q]
        ex[q] = au * c - bv * s
        ey[q] = au * s + bv * c
        uc[q] = u[q] * c
        us[q] = u[q] * s
        vs[q] = -v[q] * s
        vc[q] = v[q] * c
    hx = np.empty((mx, nq))
    dhx = np.empty((mx, nq))
    hy = np.empty((ny, nq))
    dhy = np.empty((ny, nq))
    for i in range(mx):
        for q in range(nq):
            t = xs[i] - x0 - ex[q]
            t2 = t * t
            sx = t2 + dx2
            inv = w[q] / (sx * sx)
            hx[i, q] = cx * (dx2 - nu_x * t2) * inv
            dhx[i, q] = 2.0 * cx * t * (nu_x * t2 - (nu_x + 2.0) * dx2) * inv / sx
    for j in range(ny):
        for q in range(nq):
            t = ys[j] - y0 - ey[q]
            t2 = t * t
            sy = t2 + dy2
            inv = 1.0 / (sy * sy)
            hy[j, q] = cy * (dy2 - nu_y * t2) * inv
            dhy[j, q] = 2.0 * cy * t * (nu_y * t2 - (nu_y + 2.0) * dy2) * inv / sy
    kf = scale * force
    val = np.empty((mx, ny))
    jac = np.empty((mx, ny, 6))
    for i in range(mx):
        for j in range(ny):
            sv = d0 = d1 = d2 = d3 = d4 = 0.0
            for q in range(nq):
                # the kernel's argument is X - x_q, hence the minus signs on node motion
                ax_ = dhx[i, q] * hy[j, q]  # d/d(node x) is minus this
                by_ = hx[i, q] * dhy[j, q]  # d/d(node y) is minus this
                sv += hx[i, q] * hy[j, q]
                d0 -= ax_
                d1 -= by_
                d2 -= ax_ * uc[q] + by_ * us[q]
                d3 -= ax_ * vs[q] + by_ * vc[q]
                d4 += ax_ * ey[q] - by_ * ex[q]  # theta: node motion (-ey, ex)
            for k in range(4):
                jac[i, j, k] = kf * (d2 * hj[0, k] + d3 * hj[1, k] + d4 * hj[2, k])
            jac[i, j, 3] += scale * sv
            jac[i, j, 4] = kf * d0
            jac[i, j, 5] = kf * d1
            val[i, j] = kf * sv
    return val, jac


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
    mx, ny, nq = xs.shape[0], ys.shape[0], u.shape[0]
    val = np.zeros((mx, ny))
    hx = np.empty(mx)
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
        for i in range(mx):
            t = xs[i] - xq
            t2 = t * t
            sx = t2 + dx2
            hx[i] = cx * (dx2 - nu_x * t2) / (sx * sx) * w[q]
        for j in range(ny):
            t = ys[j] - yq
            t2 = t * t
            sy = t2 + dy2
            hyj = cy * (dy2 - nu_y * t2) / (sy * sy)
            for i in range(mx):
                val[i, j] += hx[i] * hyj
    return val


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

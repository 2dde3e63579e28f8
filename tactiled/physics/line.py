"""Line contact on a flat array: a cylinder pressed on a flat cover (docs/concepts/model.md, "Other arrays")."""

# On a flat surface a cylinder's relative curvature along its axis is 0, the Hertz ellipse is
# unbounded and the contact is a line.  Across the line the pressure is the 2-D Hertz line
# contact's,
#
#     p(s) = 2 P / (pi b) sqrt(1 - s^2 / b^2),    b = sqrt(4 P R k / pi),   k = (1 - nu_f^2) / E,
#
# with ``P`` the load per unit length (N/mm) and ``R`` the cylinder's radius (``1/R* = 2 A' =
# 1/R``).  The line runs along ``psi`` (degrees from +x toward +y) through every point ``r`` with
# ``n . (r - ref) = c``, ``n = (-sin psi, cos psi)``.  A tactel at ``(X, Y)`` reads
#
#     strain = (1/E) integral p(s) ds integral h_x(X - x(s, t)) h_y(Y - y(s, t)) dt.
#
# The integral along the (infinite) line is exact: writing the impulse response as
# ``h(u) = Re g(u) / pi`` with ``g(u) = (1 + nu) d / (d - i u)^2 + (1 - nu) / (d - i u)`` (one
# double pole, in the lower half-plane), ``h_x h_y = Re[g_x g_y + g_x conj(g_y)] / (2 pi^2)`` and
# each product's integral over the real line is one residue.  Across the line a Gauss-Chebyshev
# (second kind) rule integrates the square-root pressure.  Compiled (core/line.cpp; these bodies
# are its reference); the total force and the position along the line do not exist for such a
# contact.

from __future__ import annotations

import math

import numpy as np

from tactiled import native

from tactiled.physics.quadrature_rules import _rule_s, nodes_for

#: Below this |cos psi| or |sin psi| the line lies along an axis and the residue's far pole
#: is at infinity: its limit, a principal value, is taken.  Near an axis the formula loses
#: digits to cancellation (2e-6 of the value at 1e-6 rad from it, none at 1e-4), far below any
#: sensor's noise.  The response has a kink at the axes (it grows as |angle| from them: a
#: kernel's 1/u^2 tail meeting the other's slow drift), so a Jacobian by differences takes
#: steps in the angle of 1e-4 rad (tactiled.fit.line).
_AXIS_EPS = 1e-12


def _g(a: float, b: float, d: float, sig: float, u: complex) -> complex:
    w = d - 1j * sig * u
    return a / (w * w) + b / w


def _dg(a: float, b: float, d: float, sig: float, u: complex) -> complex:
    w = d - 1j * sig * u
    return 1j * sig * (2.0 * a / (w * w * w) + b / (w * w))


def _pair(a1: float, b1: float, d1: float, s1: float, p1: float, q1: float,
          a2: float, b2: float, d2: float, s2: float, p2: float, q2: float) -> complex:
    """integral over real t of G1(p1 + q1 t) G2(p2 + q2 t), each
    ``G(u) = A/(D - i sig u)^2 + B/(D - i sig u)``: one residue, or a principal value when a
    factor does not vary along the line (``q = 0``)."""
    if abs(q1) < _AXIS_EPS:
        return _g(a1, b1, d1, s1, p1 + 0j) * math.pi * b2 / abs(q2)
    if abs(q2) < _AXIS_EPS:
        return _g(a2, b2, d2, s2, p2 + 0j) * math.pi * b1 / abs(q1)
    im1 = -s1 * d1 / q1  # imaginary parts of the poles in t
    im2 = -s2 * d2 / q2
    if (im1 > 0.0) == (im2 > 0.0):
        return 0.0 + 0j  # both poles on one side: close the contour on the other
    if im1 > 0.0:
        t = (-1j * s1 * d1 - p1) / q1
        u2 = p2 + q2 * t
        res = (a1 / (-q1 * q1)) * q2 * _dg(a2, b2, d2, s2, u2) + (b1 / (-1j * s1 * q1)) * _g(a2, b2, d2, s2, u2)
    else:
        t = (-1j * s2 * d2 - p2) / q2
        u1 = p1 + q1 * t
        res = (a2 / (-q2 * q2)) * q1 * _dg(a1, b1, d1, s1, u1) + (b2 / (-1j * s2 * q2)) * _g(a1, b1, d1, s1, u1)
    return 2j * math.pi * res


def along_line(px: float, py: float, c: float, s: float, imp: np.ndarray) -> float:
    """integral over the whole line of ``h_x(px - t c) h_y(py - t s)`` dt (1/mm): the response
    at offset ``(px, py)`` from a point of a line of unit direction ``(c, s)``."""
    return _along(px, py, c, s, imp)


def _along(px, py, c: float, s: float, imp: np.ndarray):
    """:func:`along_line`'s arithmetic, elementwise where ``px``, ``py`` are arrays (the
    reference's, whichever of it and the core ``along_line`` names)."""
    dx, nux, dy, nuy = imp[0], imp[1], imp[2], imp[3]
    ax, bx = (1.0 + nux) * dx, 1.0 - nux
    ay, by = (1.0 + nuy) * dy, 1.0 - nuy
    both = (_pair(ax, bx, dx, 1.0, px, -c, ay, by, dy, 1.0, py, -s)
            + _pair(ax, bx, dx, 1.0, px, -c, ay, by, dy, -1.0, py, -s))
    return both.real / (2.0 * math.pi * math.pi)


def _residue_line(a1: float, b1: float, d1: float, s1: float, q1: float,
                  a2: float, b2: float, d2: float, s2: float, q2: float):
    """One residue of :func:`_pair` off the axes (``q1``, ``q2`` nonzero) as a real function
    of the offset: with the pole the first factor's (the roles exchanged when it is the
    second's), ``w = w0 - i s2 e`` where ``e = p2 + mq21 p1`` (``p1``, ``p2`` exchanged with
    the roles) and the residue's real part is ``-2 pi [ca Re((2 a2 z + b2) z^2) + cb Re((a2 z
    + b2) z)]``, ``z = 1/w``: one real division a point (:func:`_residue_at`).  Returns
    ``(zero, swap, w0, a2, b2, ca, cb, mq21)``."""
    im1 = -s1 * d1 / q1
    im2 = -s2 * d2 / q2
    zero = (im1 > 0.0) == (im2 > 0.0)
    swap = not im1 > 0.0
    if swap:
        a1, b1, d1, s1, q1, a2, b2, d2, s2, q2 = a2, b2, d2, s2, q2, a1, b1, d1, s1, q1
    mq21 = -q2 / q1
    return (zero, swap, d2 + s2 * s1 * d1 * mq21, a2, b2, a1 / (-q1 * q1) * q2 * s2,
            b1 / (s1 * q1), mq21)


def _residue_at(r, p1, p2):
    """:func:`_residue_line`'s bracket at offsets ``(p1, p2)`` (elementwise on arrays)."""
    _, swap, w0, a2, b2, ca, cb, mq21 = r
    e = p1 + mq21 * p2 if swap else p2 + mq21 * p1
    inv = 1.0 / (w0 * w0 + e * e)
    x = w0 * inv
    y2 = (e * inv) * (e * inv)
    re2 = x * x - y2
    re3 = x * (x * x - 3.0 * y2)
    return ca * (2.0 * a2 * re3 + b2 * re2) + cb * (a2 * re2 + b2 * x)


def line_strain_points(load: float, half_width: float, psi: float, cx: float, cy: float,
                       px: np.ndarray, py: np.ndarray, imp: np.ndarray, modulus: float,
                       nodes: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Strains at points ``(px[k], py[k])`` (mm) of a line contact of load per length
    ``load`` (N/mm) and half-width ``half_width`` (mm) along ``psi`` (radians) through
    ``(cx, cy)``; ``nodes``/``weights`` a Gauss-Chebyshev (second kind) rule on [-1, 1]."""
    c, s = math.cos(psi), math.sin(psi)
    scale = 2.0 * load / (math.pi * modulus)
    # every point and node at once, each element as the core computes it; the nodes are
    # summed in their order, as the core sums them
    off = half_width * np.asarray(nodes, dtype=float)  # across the line, along n = (-s, c)
    qx = (np.asarray(px, dtype=float)[:, None] - cx) + off[None, :] * s
    qy = (np.asarray(py, dtype=float)[:, None] - cy) - off[None, :] * c
    if abs(c) < _AXIS_EPS or abs(s) < _AXIS_EPS:  # along an axis: the principal value
        vals = np.broadcast_to(_along(qx, qy, c, s, imp), qx.shape)
    else:
        # off the axes exactly one of along_line's two residues is nonzero (its poles
        # straddle the real line), and it is a real function of the offset (_residue_line)
        dx, nux, dy, nuy = imp[0], imp[1], imp[2], imp[3]
        ax, bx = (1.0 + nux) * dx, 1.0 - nux
        ay, by = (1.0 + nuy) * dy, 1.0 - nuy
        r = _residue_line(ax, bx, dx, 1.0, -c, ay, by, dy, 1.0, -s)
        if r[0]:
            r = _residue_line(ax, bx, dx, 1.0, -c, ay, by, dy, -1.0, -s)
        vals = (-1.0 / math.pi) * _residue_at(r, qx, qy)
    acc = np.zeros(qx.shape[0])
    for i in range(off.size):
        acc += weights[i] * vals[:, i]
    return scale * acc


def _pair_setup(a1: float, b1: float, d1: float, s1: float, q1: float,
                a2: float, b2: float, d2: float, s2: float, q2: float):
    """What :func:`_pair_partials` needs that depends on the line's angle only (``q1``,
    ``q2``, both nonzero) and not on the distance: which factor's pole the residue is taken
    at (the roles exchanged when it is the second's), whether the integral vanishes (both
    poles on one side), and the residue's coefficients."""
    im1 = -s1 * d1 / q1
    im2 = -s2 * d2 / q2
    zero = (im1 > 0.0) == (im2 > 0.0)
    swap = not im1 > 0.0
    if swap:
        a1, b1, d1, s1, q1, a2, b2, d2, s2, q2 = a2, b2, d2, s2, q2, a1, b1, d1, s1, q1
    alpha = a1 / (-q1 * q1)
    beta = b1 / (-1j * s1 * q1)
    return (zero, swap, a1, d1, s1, q1, a2, b2, d2, s2, q2, alpha, beta,
            2.0 * a1 / (q1 * q1 * q1), -q2 / q1)


def _pair_partials(st, p1: float, p2: float
                   ) -> tuple[complex, complex, complex, complex, complex]:
    """:func:`_pair` off the axes and its partials in ``(p1, q1, p2, q2)``: the one residue's
    closed form, differentiated; ``st`` is :func:`_pair_setup` of the angle."""
    zero, swap, a1, d1, s1, q1, a2, b2, d2, s2, q2, alpha, beta, a1q3, mq21 = st
    if zero:
        return 0j, 0j, 0j, 0j, 0j
    if swap:  # the pole is the second factor's: the same formula with the roles exchanged
        p1, p2 = p2, p1
    t = (-1j * s1 * d1 - p1) / q1
    u2 = p2 + q2 * t
    w = d2 - 1j * s2 * u2
    iw = 1.0 / w
    iw2 = iw * iw
    g2 = (a2 * iw + b2) * iw
    dg2 = 1j * s2 * (2.0 * a2 * iw + b2) * iw2
    ddg2 = -s2 * s2 * (6.0 * a2 * iw + 2.0 * b2) * iw2 * iw
    k = 2j * math.pi
    val = k * (alpha * q2 * dg2 + beta * g2)
    du = k * (alpha * q2 * ddg2 + beta * dg2)  # d value / d u2
    dp1 = du * mq21
    dq1 = k * (a1q3 * q2 * dg2 - beta / q1 * g2) + du * (-q2 * t / q1)
    dp2 = du
    dq2 = k * alpha * dg2 + du * t
    if swap:
        return val, dp2, dq2, dp1, dq1
    return val, dp1, dq1, dp2, dq2


#: Within this of an axis (|cos psi| or |sin psi|) the partials are taken a little off it (at
#: ``_AXIS_NUDGE`` rad): on the axis the response has a kink in the angle (see ``_AXIS_EPS``),
#: and this takes its one-sided slope, as a forward difference does.
_AXIS_NEAR = 1e-7
_AXIS_NUDGE = 1e-6


def _line_angle(psi: float, imp: np.ndarray):
    """What :func:`across_line` needs of the angle ``psi`` (radians), whatever the distance:
    its cosine and sine, whether it is within ``_AXIS_NEAR`` of an axis, the cosine and sine
    the partials are taken at (nudged off an axis) and the two residues' setups there."""
    c, s = math.cos(psi), math.sin(psi)
    near = abs(c) < _AXIS_NEAR or abs(s) < _AXIS_NEAR
    cj, sj = c, s
    if near:
        cj, sj = math.cos(psi + _AXIS_NUDGE), math.sin(psi + _AXIS_NUDGE)
    dx, nux, dy, nuy = imp[0], imp[1], imp[2], imp[3]
    ax, bx = (1.0 + nux) * dx, 1.0 - nux
    ay, by = (1.0 + nuy) * dy, 1.0 - nuy
    st1 = _pair_setup(ax, bx, dx, 1.0, -cj, ay, by, dy, 1.0, -sj)
    st2 = _pair_setup(ax, bx, dx, 1.0, -cj, ay, by, dy, -1.0, -sj)
    return c, s, near, cj, sj, st1, st2


def _across_at(dist: float, ang, imp: np.ndarray) -> tuple[float, float, float]:
    """:func:`across_line` with its partials, ``ang`` = :func:`_line_angle` of the angle."""
    c, s, near, cj, sj, st1, st2 = ang
    if near:
        val = along_line(-dist * s, dist * c, c, s, imp)
    v1, a1, b1, c1, d1 = _pair_partials(st1, -dist * sj, dist * cj)
    v2, a2, b2, c2, d2 = _pair_partials(st2, -dist * sj, dist * cj)
    norm = 1.0 / (2.0 * math.pi * math.pi)
    if not near:
        val = (v1 + v2).real * norm
    dp1, dq1, dp2, dq2 = (a1 + a2).real, (b1 + b2).real, (c1 + c2).real, (d1 + d2).real
    d_dist = (-sj * dp1 + cj * dp2) * norm
    # p1 = -d s, q1 = -c, p2 = d c, q2 = -s
    d_psi = (-dist * cj * dp1 + sj * dq1 - dist * sj * dp2 - cj * dq2) * norm
    return val, d_dist, d_psi


def across_line(dist: float, psi: float, imp: np.ndarray, want: bool) -> tuple[float, float, float]:
    """``L(d, psi)``: the response (1/mm) at signed distance ``dist`` (mm, along the normal
    ``(-sin psi, cos psi)``) from an infinite line along ``psi`` (:func:`along_line` at any
    point of that distance), and, when ``want``, its partials in ``dist`` and ``psi``."""
    if not want:
        c, s = math.cos(psi), math.sin(psi)
        return along_line(-dist * s, dist * c, c, s, imp), 0.0, 0.0
    return _across_at(dist, _line_angle(psi, imp), imp)


def line_residual(p: np.ndarray, px: np.ndarray, py: np.ndarray, ref_x: float, ref_y: float,
                  imp: np.ndarray, modulus: float, compliance: float, nodes: np.ndarray,
                  weights: np.ndarray, target: np.ndarray, valid: np.ndarray,
                  inv_scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scaled residuals ``(strain - target) * inv_scale`` of the line model (internal vector
    ``p = [ln R, psi, ln P, c]``, ``c`` the line's offset along its normal from
    ``(ref_x, ref_y)``) at the valid points ``(px, py)``, and their exact Jacobian in ``p``
    (0 rows of 4 where not valid).  ``nodes``, ``weights``: the rule across the line for the
    half-width at ``p``.  A tactel's normal distance from node ``u`` of the pressure is
    ``e - c - b u`` with ``e`` its own from the reference, so with ``L`` of
    :func:`across_line` the strain is ``2P/(pi E) sum w L(e - c - b u)``: its partials are
    ``L``'s, through ``b = sqrt(4 P R k / pi)`` (``db/d ln R = db/d ln P = b/2``).  What
    depends on the angle only is computed once (:func:`_line_angle`), not per node."""
    r_, psi, load, off = math.exp(p[0]), p[1], math.exp(p[2]), p[3]
    b = math.sqrt(4.0 * load * r_ * compliance / math.pi)
    c, s = math.cos(psi), math.sin(psi)
    ang = _line_angle(psi, imp)
    scale = 2.0 * load / (math.pi * modulus)
    n = px.shape[0]
    r = np.zeros(n)
    jac = np.zeros((n, 4))
    for k in range(n):
        if not valid[k]:
            continue
        ex, ey = px[k] - ref_x, py[k] - ref_y
        e = -ex * s + ey * c
        de = -ex * c - ey * s  # d e / d psi
        v = dd = du = dpsi = 0.0
        for i in range(nodes.shape[0]):
            val, l_d, l_psi = _across_at(e - off - b * nodes[i], ang, imp)
            wi = weights[i]
            v += wi * val
            dd += wi * l_d
            du += wi * l_d * nodes[i]
            dpsi += wi * (l_d * de + l_psi)
        w = inv_scale[k]
        r[k] = (scale * v - target[k]) * w
        jac[k, 0] = -scale * 0.5 * b * du * w
        jac[k, 1] = scale * dpsi * w
        jac[k, 2] = (scale * v - scale * 0.5 * b * du) * w
        jac[k, 3] = -scale * dd * w
    return r, jac


def line_points(xs: np.ndarray, ys: np.ndarray, ex: np.ndarray,
                ey: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """A window's tactel positions (mm, flattened row-major) from its grid ``xs x ys`` and
    each tactel's displacement ``(ex, ey)``, and their mean: the line's reference point."""
    nr, nc = xs.shape[0], ys.shape[0]
    px = np.empty(nr * nc)
    py = np.empty(nr * nc)
    sx = sy = 0.0
    for i in range(nr):
        for j in range(nc):
            k = i * nc + j
            px[k] = xs[i] + ex[k]
            py[k] = ys[j] + ey[k]
            sx += px[k]
            sy += py[k]
    return px, py, sx / (nr * nc), sy / (nr * nc)


#: the Python bodies (the reference); the module's names run the compiled core's when it is loaded
REFERENCE = native.bind(globals(), ("along_line", "line_strain_points", "across_line",
                                    "line_residual", "line_points"))


def half_width(load: float, radius: float, compliance: float) -> float:
    """Half-width ``b`` (mm) of the Hertz line contact: ``sqrt(4 P R k / pi)``, ``load`` in
    N/mm, ``radius`` in mm, ``compliance`` ``k`` in mm^2/N."""
    return math.sqrt(4.0 * load * radius * compliance / math.pi)


def across_rule(b: float, depth: float, tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """The Gauss-Chebyshev rule across a line of half-width ``b`` under a cover of ``depth``."""
    return _rule_s(nodes_for(b, depth, tol))


def line_strain(load: float, radius: float, psi_deg: float, cx: float, cy: float,
                px: np.ndarray, py: np.ndarray, imp: np.ndarray, modulus: float,
                compliance: float, tol: float = 1e-9) -> np.ndarray:
    """Strains at points ``(px, py)`` (mm, any equal shapes) of a cylinder of ``radius`` mm
    pressed with ``load`` N/mm along ``psi_deg`` through ``(cx, cy)`` on a flat cover
    (``imp`` = depth_x, nu_x, depth_y, nu_y)."""
    px = np.asarray(px, dtype=float)
    py = np.asarray(py, dtype=float)
    b = half_width(load, radius, compliance)
    u, w = across_rule(b, float(min(imp[0], imp[2])), tol)
    val = line_strain_points(load, b, math.radians(psi_deg), cx, cy,
                             np.ascontiguousarray(px.ravel()), np.ascontiguousarray(py.ravel()),
                             np.ascontiguousarray(imp, dtype=float), modulus, u, w)
    return val.reshape(px.shape)

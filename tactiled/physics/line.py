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
# each product's integral over the real line is one residue.  Off the axes one of the two
# vanishes (both poles on one side) and the other, as a function of the distance from the line,
# has a closed form in real arithmetic (``_coefficients``): the strain, the fit's residual and
# its partials use it; ``along_line`` keeps the residues (the reference the closed form is
# tested against, and the principal value on an axis).  Across the line a Gauss-Chebyshev
# (second kind) rule integrates the square-root pressure.  Compiled (core/line.cpp; these bodies
# are its reference); the total force and the position along the line do not exist for such a
# contact.

from __future__ import annotations

import math

import numpy as np

from tactiled import native

from tactiled.physics.quadrature_rules import _rule_s, nodes_for

#: Below this |cos psi| or |sin psi| the line lies along an axis and the residue's far pole
#: is at infinity: its limit, a principal value, is taken.  Near an axis the residue form loses
#: digits to cancellation (2e-6 of the value at 1e-6 rad from it, none at 1e-4; the closed form
#: of ``_coefficients`` loses none), far below any sensor's noise.  The response has a kink at
#: the axes (it grows as |angle| from them: a kernel's 1/u^2 tail meeting the other's slow
#: drift), so a Jacobian by differences takes steps in the angle of 1e-4 rad (tactiled.fit.line).
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


def line_strain_points(load: float, half_width: float, psi: float, cx: float, cy: float,
                       px: np.ndarray, py: np.ndarray, imp: np.ndarray, modulus: float,
                       nodes: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Strains at points ``(px[k], py[k])`` (mm) of a line contact of load per length
    ``load`` (N/mm) and half-width ``half_width`` (mm) along ``psi`` (radians) through
    ``(cx, cy)``; ``nodes``/``weights`` a Gauss-Chebyshev (second kind) rule on [-1, 1]."""
    c, s = math.cos(psi), math.sin(psi)
    scale = 2.0 * load / (math.pi * modulus)
    # every point and node at once (L of _across_value at each one's distance from the line),
    # each element as the core computes it; the nodes are summed in their order, as the core
    # sums them
    off = half_width * np.asarray(nodes, dtype=float)  # across the line, along n = (-s, c)
    qx = (np.asarray(px, dtype=float)[:, None] - cx) + off[None, :] * s
    qy = (np.asarray(py, dtype=float)[:, None] - cy) - off[None, :] * c
    vals = _across_value(-qx * s + qy * c, _coefficients(c, s, imp))
    acc = np.zeros(qx.shape[0])
    for i in range(off.size):
        acc += weights[i] * vals[:, i]
    return scale * acc


#: Within this of an axis (|cos psi| or |sin psi|) the partials are taken a little off it (at
#: ``_AXIS_NUDGE`` rad): on the axis the response has a kink in the angle (see ``_AXIS_EPS``),
#: and this takes its one-sided slope, as a forward difference does.
_AXIS_NEAR = 1e-7
_AXIS_NUDGE = 1e-6


def _coefficients(c: float, s: float, imp: np.ndarray):
    """The across-line closed form's coefficients at a line's direction ``(c, s)`` (cosine,
    sine) and their derivatives in its angle: ``(V, dV, A, dA, B, dB, C)``.

    Off the axes exactly one of :func:`along_line`'s two residues is nonzero (its poles
    straddle the real line), and at distance ``d`` from the line it is ``L = (A Re z^3 + B Re
    z^2 + C Re z) / pi`` with ``z = 1/(V + i d)``, ``V = depth_y |cos| + depth_x |sin|``, ``A
    = 2 a_x a_y |cos||sin|``, ``B = a_x b_y |sin| + a_y b_x |cos|``, ``C = b_x b_y`` (``a = (1
    + nu) depth``, ``b = 1 - nu``); on an axis it is the principal value's limit.  Real
    arithmetic, one division a point; symmetric in x and y, as it must be."""
    dx, nux, dy, nuy = imp[0], imp[1], imp[2], imp[3]
    ax, bx = (1.0 + nux) * dx, 1.0 - nux
    ay, by = (1.0 + nuy) * dy, 1.0 - nuy
    ac, as_ = abs(c), abs(s)
    dac = -s if c >= 0.0 else s  # d|cos|/d psi
    das = c if s >= 0.0 else -c  # d|sin|/d psi
    return (dy * ac + dx * as_, dy * dac + dx * das,
            2.0 * ax * ay * (ac * as_), 2.0 * ax * ay * (dac * as_ + ac * das),
            ax * by * as_ + ay * bx * ac, ax * by * das + ay * bx * dac, bx * by)


def _powers(v, dist):
    """``z = 1/(v + i dist)`` and the parts of ``z^2``, ``z^3``: ``(Re z, Im z, Re z^2, Im
    z^2, Re z^3)`` (elementwise on arrays)."""
    inv = 1.0 / (v * v + dist * dist)
    zr = v * inv
    zi = -dist * inv
    r2 = zr * zr - zi * zi
    i2 = 2.0 * zr * zi
    return zr, zi, r2, i2, r2 * zr - i2 * zi


def _across_value(dist, k):
    """``L(dist)`` (1/mm) of :func:`_coefficients` ``k`` (elementwise on arrays)."""
    v, _, a, _, bb, _, cc = k
    zr, _, r2, _, r3 = _powers(v, dist)
    return (a * r3 + bb * r2 + cc * zr) / math.pi


def _line_angle(psi: float, imp: np.ndarray):
    """What :func:`across_line` needs of the angle ``psi`` (radians), whatever the distance:
    its cosine and sine, whether it is within ``_AXIS_NEAR`` of an axis, and
    :func:`_coefficients` at the angle (the value's) and at the angle nudged off an axis
    (the partials')."""
    c, s = math.cos(psi), math.sin(psi)
    near = abs(c) < _AXIS_NEAR or abs(s) < _AXIS_NEAR
    at = _coefficients(c, s, imp)
    kj = _coefficients(math.cos(psi + _AXIS_NUDGE), math.sin(psi + _AXIS_NUDGE), imp) if near else at
    return c, s, near, at, kj


def _across_at(dist: float, ang, imp: np.ndarray) -> tuple[float, float, float]:
    """:func:`across_line` with its partials, ``ang`` = :func:`_line_angle` of the angle:
    ``dz^n/dd = -i n z^(n+1)`` and ``dz^n/dV = -n z^(n+1)`` (:func:`_coefficients`)."""
    c, s, near, k0, kj = ang
    v, dv, a, da, bb, dbb, cc = kj
    zr, zi, r2, i2, r3 = _powers(v, dist)
    i3 = r2 * zi + i2 * zr
    r4 = r2 * r2 - i2 * i2
    i4 = 2.0 * r2 * i2
    val = _across_value(dist, k0) if near else (a * r3 + bb * r2 + cc * zr) / math.pi
    d_dist = (3.0 * a * i4 + 2.0 * bb * i3 + cc * i2) / math.pi
    d_psi = (da * r3 + dbb * r2 - dv * (3.0 * a * r4 + 2.0 * bb * r3 + cc * r2)) / math.pi
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

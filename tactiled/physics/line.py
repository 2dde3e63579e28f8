"""Line contact on a flat array: a cylinder pressed on a flat cover (docs/concepts/model.md, "Other arrays").

On a flat surface a cylinder's relative curvature along its axis is 0, the Hertz ellipse is
unbounded and the contact is a line.  Across the line the pressure is the 2-D Hertz line
contact's,

    p(s) = 2 P / (pi b) sqrt(1 - s^2 / b^2),    b = sqrt(4 P R k / pi),   k = (1 - nu_f^2) / E,

with ``P`` the load per unit length (N/mm) and ``R`` the cylinder's radius (``1/R* = 2 A' =
1/R``).  The line runs along ``psi`` (degrees from +x toward +y) through every point ``r`` with
``n . (r - ref) = c``, ``n = (-sin psi, cos psi)``.  A tactel at ``(X, Y)`` reads

    strain = (1/E) integral p(s) ds integral h_x(X - x(s, t)) h_y(Y - y(s, t)) dt.

The integral along the (infinite) line is exact: writing the impulse response as
``h(u) = Re g(u) / pi`` with ``g(u) = (1 + nu) d / (d - i u)^2 + (1 - nu) / (d - i u)`` (one
double pole, in the lower half-plane), ``h_x h_y = Re[g_x g_y + g_x conj(g_y)] / (2 pi^2)`` and
each product's integral over the real line is one residue.  Across the line a Gauss-Chebyshev
(second kind) rule integrates the square-root pressure.  Compiled (numba); the total force and
the position along the line do not exist for such a contact.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tactiled.physics.strain import _rule_s, nodes_for

#: Below this |cos psi| or |sin psi| the line lies along an axis and the residue's far pole
#: is at infinity: its limit, a principal value, is taken.  Near an axis the formula loses
#: digits to cancellation (2e-6 of the value at 1e-6 rad from it, none at 1e-4), far below any
#: sensor's noise.  The response has a kink at the axes (it grows as |angle| from them: a
#: kernel's 1/u^2 tail meeting the other's slow drift), so a Jacobian by differences takes
#: steps in the angle of 1e-4 rad (tactiled.fit.line).
_AXIS_EPS = 1e-12


@njit(cache=True, nogil=True)
def _g(a: float, b: float, d: float, sig: float, u: complex) -> complex:
    w = d - 1j * sig * u
    return a / (w * w) + b / w


@njit(cache=True, nogil=True)
def _dg(a: float, b: float, d: float, sig: float, u: complex) -> complex:
    w = d - 1j * sig * u
    return 1j * sig * (2.0 * a / (w * w * w) + b / (w * w))


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
def along_line(px: float, py: float, c: float, s: float, imp: np.ndarray) -> float:
    """integral over the whole line of ``h_x(px - t c) h_y(py - t s)`` dt (1/mm): the response
    at offset ``(px, py)`` from a point of a line of unit direction ``(c, s)``."""
    dx, nux, dy, nuy = imp[0], imp[1], imp[2], imp[3]
    ax, bx = (1.0 + nux) * dx, 1.0 - nux
    ay, by = (1.0 + nuy) * dy, 1.0 - nuy
    both = (_pair(ax, bx, dx, 1.0, px, -c, ay, by, dy, 1.0, py, -s)
            + _pair(ax, bx, dx, 1.0, px, -c, ay, by, dy, -1.0, py, -s))
    return both.real / (2.0 * math.pi * math.pi)


@njit(cache=True, nogil=True)
def line_strain_points(load: float, half_width: float, psi: float, cx: float, cy: float,
                       px: np.ndarray, py: np.ndarray, imp: np.ndarray, modulus: float,
                       nodes: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Strains at points ``(px[k], py[k])`` (mm) of a line contact of load per length
    ``load`` (N/mm) and half-width ``half_width`` (mm) along ``psi`` (radians) through
    ``(cx, cy)``; ``nodes``/``weights`` a Gauss-Chebyshev (second kind) rule on [-1, 1]."""
    c, s = math.cos(psi), math.sin(psi)
    out = np.zeros(px.size)
    scale = 2.0 * load / (math.pi * modulus)
    for k in range(px.size):
        acc = 0.0
        for i in range(nodes.size):
            off = half_width * nodes[i]  # across the line, along n = (-s, c)
            acc += weights[i] * along_line(px[k] - cx + off * s, py[k] - cy - off * c, c, s, imp)
        out[k] = scale * acc
    return out


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

"""Impulse response of the finger's rubber skin (paper eqs. 1-4, docs/concepts/model.md).

The 2-D response is separable, ``h(x, y) = h_x(x) * h_y(y)``, and each factor is the plane-stress
strain under a normal line load at depth ``d``:

    h(u) = 2 d (d^2 - nu u^2) / (pi (u^2 + d^2)^2)        [1/mm]

``u`` is the horizontal offset in mm between the load and the tactel.  Its integral over the
line is ``1 - nu`` (used by the force estimate of a cold start).
"""

from __future__ import annotations

import math

import numpy as np


def line_response(u: np.ndarray | float, depth: float, nu: float) -> np.ndarray:
    """``h(u)`` in 1/mm for offsets ``u`` in mm; ``depth`` in mm, ``nu`` dimensionless."""
    u2 = np.square(u)
    d2 = depth * depth
    s = u2 + d2
    return (2.0 * depth / math.pi) * (d2 - nu * u2) / (s * s)


def line_response_and_slope(
    u: np.ndarray, depth: float, nu: float
) -> tuple[np.ndarray, np.ndarray]:
    """``h(u)`` [1/mm] and ``dh/du`` [1/mm^2], sharing the common sub-expressions."""
    u2 = np.square(u)
    d2 = depth * depth
    s = u2 + d2
    inv_s2 = 1.0 / (s * s)
    c = 2.0 * depth / math.pi
    h = c * (d2 - nu * u2) * inv_s2
    # d/du [ (d^2 - nu u^2) / s^2 ] = 2u (nu u^2 - (nu + 2) d^2) / s^3
    dh = (2.0 * c) * u * (nu * u2 - (nu + 2.0) * d2) * inv_s2 / s
    return h, dh


def line_response_integral(nu: float) -> float:
    """``integral of h(u) du`` over the whole line: ``1 - nu`` (independent of depth)."""
    return 1.0 - nu

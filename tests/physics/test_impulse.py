"""Impulse response h(u) of MODEL.md: values, slope and integral, against independent checks."""

import math

import numpy as np
from scipy.integrate import quad

from tactiled.physics.impulse import line_response, line_response_and_slope, line_response_integral


def test_formula_at_known_points():
    d, nu = 4.3, 0.5
    # u = 0: 2 d d^2 / (pi d^4) = 2 / (pi d)
    assert math.isclose(float(line_response(0.0, d, nu)), 2.0 / (math.pi * d), rel_tol=1e-14)
    # zero crossing where d^2 = nu u^2
    assert abs(float(line_response(d / math.sqrt(nu), d, nu))) < 1e-15


def test_integral_is_one_minus_nu():
    for d, nu in ((4.3, 0.5), (6.0, 0.7), (2.0, 0.0)):
        val, _ = quad(lambda u: float(line_response(u, d, nu)), -np.inf, np.inf, limit=200)
        assert math.isclose(val, line_response_integral(nu), rel_tol=1e-8)


def test_slope_matches_central_differences():
    u = np.linspace(-20, 20, 81)
    h = 1e-5
    _, dh = line_response_and_slope(u, 6.0, 0.7)
    fd = (line_response(u + h, 6.0, 0.7) - line_response(u - h, 6.0, 0.7)) / (2 * h)
    assert np.max(np.abs(dh - fd)) < 1e-9


def test_even_in_offset():
    u = np.linspace(0, 15, 31)
    assert np.array_equal(line_response(u, 4.3, 0.5), line_response(-u, 4.3, 0.5))

"""The eccentricity solve against high-precision mpmath and scipy's elliptic integrals.

The issue's bar: relative error < 1e-6 over curvature ratios 1 .. 1e8, sphere limit and near-line
contacts included.  We check the solved m reproduces lambda (computed independently in 50-digit
arithmetic) to 1e-10, and that m itself matches an independent root of the same equation.
"""

import math

import mpmath as mp
import numpy as np
import pytest
from scipy.special import ellipe, ellipk, ellipkm1

from tactiled.physics.eccentricity import curvature_ratio, ellip_ke, solve_log, solve_log_scalar

mp.mp.dps = 50


def lam_minus_1(m1: mp.mpf) -> mp.mpf:
    m = 1 - m1
    k, e = mp.ellipk(m), mp.ellipe(m)
    return (e / m1 - k) / (k - e) - 1


LAMBDA_MINUS_1 = np.concatenate([np.logspace(-12, 8, 61), [1e-16, 0.5, 1.0, 99999999.0]])


@pytest.mark.parametrize("l1", LAMBDA_MINUS_1)
def test_solution_reproduces_lambda(l1):
    m, m1, *_ = solve_log_scalar(math.log(l1))
    ref = lam_minus_1(mp.mpf(m1)) if m > 0.5 else lam_minus_1(1 - mp.mpf(m))
    assert abs(float((ref - l1) / (1 + l1))) < 1e-10  # relative error of lambda
    assert abs(float((ref - l1) / l1)) < 1e-9  # and of lambda - 1 (the sphere limit)


@pytest.mark.parametrize("l1", [1e-9, 1e-3, 0.3, 3.0, 1e3, 1e6, 1e8])
def test_m_matches_independent_root(l1):
    m, m1, *_ = solve_log_scalar(math.log(l1))
    # independent root of lambda = 1 + l1 in y = logit(m), 50 digits, from a perturbed start
    y0 = mp.log(mp.mpf(m) / mp.mpf(m1)) + mp.mpf("0.01")
    root = mp.findroot(lambda y: mp.log(lam_minus_1(1 / (1 + mp.e**y))) - mp.log(l1), y0)
    m1_ref = 1 / (1 + mp.e**root)
    assert abs(float((m1_ref - m1) / m1_ref)) < 1e-9
    assert abs(float(((1 - m1_ref) - m) / (1 - m1_ref))) < 1e-9


def test_scalar_and_vector_paths_agree():
    x = np.linspace(-44.0, 38.0, 997)
    vec = solve_log(x)
    for i in range(0, x.size, 7):
        m, m1, log_f, dlogf, dlogm1 = solve_log_scalar(float(x[i]))
        assert math.isclose(m, vec.m[i], rel_tol=1e-10)
        assert math.isclose(m1, vec.m1[i], rel_tol=1e-10)
        assert math.isclose(log_f, vec.log_f[i], rel_tol=1e-10, abs_tol=1e-12)


def test_agm_integrals_match_scipy():
    m1 = np.concatenate([np.logspace(-18, 0, 200), np.linspace(0.01, 1.0, 50)])
    for v in m1:
        k, e = ellip_ke(1.0 - v, v)
        assert math.isclose(k, float(ellipkm1(v)), rel_tol=1e-13)
        assert math.isclose(e, float(ellipe(1.0 - v)), rel_tol=1e-13)


def test_curvature_ratio_reference_matches_scipy_formula():
    m = np.array([0.1, 0.5, 0.9])
    k, e = ellipk(m), ellipe(m)
    np.testing.assert_allclose(curvature_ratio(m), (e / (1 - m) - k) / (k - e), rtol=1e-15)


def test_derivatives_against_differences():
    for x in (-20.0, -3.0, 0.0, 2.0, 12.0):
        h = 1e-6
        _, m1, log_f, dlogf, dlogm1 = solve_log_scalar(x)
        _, m1p, log_fp, *_ = solve_log_scalar(x + h)
        _, m1m, log_fm, *_ = solve_log_scalar(x - h)
        assert math.isclose(dlogf, (log_fp - log_fm) / (2 * h), rel_tol=1e-5, abs_tol=1e-9)
        assert math.isclose(dlogm1, (math.log(m1p) - math.log(m1m)) / (2 * h), rel_tol=1e-5, abs_tol=1e-9)

"""Hertz contact ellipse: MODEL.md's reference example, limits, scaling, Jacobian."""

import math

import numpy as np
import pytest

from tactiled.physics.hertz import contact_ellipse, contact_ellipse_radii

K = (1 - 0.5**2) / 0.25  # mm^2/N
RF = 12.7


def test_paper_example_cylinder_r10_psi45():
    e = contact_ellipse_radii(10.0, math.inf, 45.0, 1.0)
    assert 2 * e.a == pytest.approx(11.38, abs=0.01)
    assert 2 * e.b == pytest.approx(3.52, abs=0.01)
    assert math.degrees(e.theta) == pytest.approx(26.0, abs=0.5)


def test_sphere_limit_formula():
    # A tiny sphere makes A' ~ C' (m -> 0): a^3 -> 3 F k / (8 C'), with C' = 1/(2R)
    r = 1e-7
    e = contact_ellipse_radii(r, r, 0.0, 1.0)
    c_prime = 0.5 / r
    assert e.a**3 == pytest.approx(3 * K / (8 * c_prime), rel=1e-6)
    assert e.m < 1e-5


def test_cylinder_across_the_finger_axes():
    # psi = 90: the cylinder's axis runs around the finger, curvature 1/R along x, 1/R_f along y.
    e = contact_ellipse_radii(7.0, math.inf, 90.0, 1.0)
    a_prime, c_prime = 0.5 / 7.0, 0.5 / RF
    assert a_prime > c_prime
    assert math.degrees(e.theta) == pytest.approx(90.0, abs=1e-9)  # major axis along y
    assert (e.b / e.a) ** 2 == pytest.approx(1 - e.m, rel=1e-12)


@pytest.mark.parametrize("r1,r2,psi", [(10, math.inf, 45), (3, 8, 120), (0.1, math.inf, 90), (1e4, 1e4, 10)])
def test_force_scaling_is_cube_root(r1, r2, psi):
    e1 = contact_ellipse_radii(r1, r2, psi, 1.0)
    e8 = contact_ellipse_radii(r1, r2, psi, 8.0)
    assert e8.a == pytest.approx(2 * e1.a, rel=1e-12)
    assert e8.b == pytest.approx(2 * e1.b, rel=1e-12)
    assert e8.theta == pytest.approx(e1.theta, abs=1e-12)


def test_mirror_symmetry_of_orientation():
    e1 = contact_ellipse_radii(10, math.inf, 45, 1.0)
    e2 = contact_ellipse_radii(10, math.inf, 135, 1.0)
    assert e2.a == pytest.approx(e1.a, rel=1e-12)
    assert math.degrees(e2.theta) == pytest.approx(180 - math.degrees(e1.theta), abs=1e-9)


@pytest.mark.parametrize("args", [(0.08, 0.01, 0.7, 1.3), (0.5, 1e-4, 1.9, 0.2), (0.02, 0.03, 0.3, 2.0)])
def test_jacobian_matches_central_differences(args):
    _, jac = contact_ellipse(*args, RF, K, jac=True)
    for i in range(4):
        h = 1e-6 * max(abs(args[i]), 1e-2)
        up, dn = list(args), list(args)
        up[i] += h
        dn[i] -= h
        ep, _ = contact_ellipse(*up, RF, K)
        em, _ = contact_ellipse(*dn, RF, K)
        fd = np.array([ep.a - em.a, ep.b - em.b, ep.theta - em.theta]) / (2 * h)
        np.testing.assert_allclose(jac[:, i], fd, rtol=2e-6, atol=1e-6 * np.abs(jac).max())


def test_line_contact_is_an_error_not_a_nan():
    with pytest.raises(ValueError, match="infinite line"):
        contact_ellipse(0.1, 0.0, 0.0, 1.0, RF, K)
    with pytest.raises(ValueError):
        contact_ellipse(float("nan"), 0.0, 1.0, 1.0, RF, K)

"""Predicted strains against MODEL.md's reference value and two independent integrations."""

import math

import numpy as np
import pytest

from tactiled.sensors.model import SensorModel
from tactiled.physics.contact import Contact
from tactiled.physics.hertz import contact_ellipse
from tactiled.physics.impulse import line_response
from tactiled.physics.reference import reference_strain
from tactiled.physics.quadrature_rules import disk_rule
from tactiled.physics.strain import StrainModel

SENSOR = SensorModel()
MODEL = StrainModel(SENSOR)


def gauss_grid_strain(c: Contact, n_alpha: int, n_beta: int) -> np.ndarray:
    """Independent integration written for this test: the unit disk mapped by
    ``u = sin(alpha)``, ``v = cos(alpha) sin(beta)`` (so the Hertz pressure
    ``sqrt(1 - u^2 - v^2) = cos(alpha) cos(beta)`` and the area element
    ``cos^2(alpha) cos(beta)`` are smooth), on a tensor grid of Gauss-Legendre nodes."""
    g, imp, mat = SENSOR.geometry, SENSOR.impulse, SENSOR.material
    ell, _ = contact_ellipse(c.kappa_a, c.kappa_b, c.psi, c.force, g.finger_radius, mat.compliance)
    ta, wa = np.polynomial.legendre.leggauss(n_alpha)
    tb, wb = np.polynomial.legendre.leggauss(n_beta)
    alpha, beta = ta * math.pi / 2, tb * math.pi / 2
    wa, wb = wa * math.pi / 2, wb * math.pi / 2
    A, B = np.meshgrid(alpha, beta, indexing="ij")
    W = np.outer(wa, wb) * np.cos(A) ** 3 * np.cos(B) ** 2
    u, v = np.sin(A), np.cos(A) * np.sin(B)
    xp, yp = ell.a * u, ell.b * v
    cs, sn = math.cos(ell.theta), math.sin(ell.theta)
    xq = (c.x0 + xp * cs - yp * sn).ravel()
    yq = (c.y0 + xp * sn + yp * cs).ravel()
    xs = np.arange(g.rows) * g.dx
    ys = np.arange(g.cols) * g.dy
    hx = line_response(xs[:, None] - xq, imp.depth_x, imp.nu_x)
    hy = line_response(ys[:, None] - yq, imp.depth_y, imp.nu_y)
    # p dA = 3F/(2 pi a b) sqrt(.) * a b du dv
    return 3 * c.force / (2 * math.pi * mat.modulus) * ((hx * W.ravel()) @ hy.T)


def test_model_reference_peak_strain():
    s = MODEL.predict(Contact(7.0, math.inf, 90.0, 1.0, 8.25, 11.7))
    assert s.max() == pytest.approx(0.037, abs=0.0005)
    assert np.unravel_index(np.argmax(s), s.shape) == (2, 3) or np.unravel_index(np.argmax(s), s.shape) == (3, 3)


def test_disk_rule_integrates_the_hertz_weight():
    for n_u, n_s in ((3, 3), (12, 7), (40, 20)):
        u, v, w = disk_rule(n_u, n_s)
        assert w.sum() == pytest.approx(2 * math.pi / 3, rel=1e-13)
        assert np.all(u**2 + v**2 < 1)
        # second moment of sqrt(1 - r^2) over the disk: int u^2 = 2 pi / 15
        assert (w * u * u).sum() == pytest.approx(2 * math.pi / 15, rel=1e-12)


CASES = [
    Contact(0.1, math.inf, 90, 1.0, 11.0, 13.0),  # knife edge
    Contact(0.1, math.inf, 30, 0.5, 9.0, 14.0),
    Contact(1.0, math.inf, 150, 2.0, 12.5, 12.0),
    Contact(10, math.inf, 45, 1.0, 11.55, 11.7),
    Contact(50, math.inf, 120, 0.5, 10.0, 15.0),
    Contact(3, 3, 0, 1.0, 11.0, 13.0),  # sphere
    Contact(5, 20, 60, 2.0, 8.0, 10.0),  # general
    Contact(1e4, math.inf, 90, 1.0, 11.0, 13.0),  # near plane (contact ~100 mm long)
    Contact(1e4, 1e4, 45, 1.0, 11.0, 13.0),
]


@pytest.mark.parametrize("c", CASES, ids=lambda c: f"R{c.r1}-{c.r2}-psi{c.psi_deg}-F{c.force}")
def test_agrees_with_independent_fine_grid_integration(c):
    s = MODEL.predict(c)
    ell, _ = MODEL.ellipse(c.kappa_a, c.kappa_b, c.psi, c.force)
    n = int(min(1600, max(200, 40 * ell.a)))
    ref = gauss_grid_strain(c, n, 120)
    ref2 = gauss_grid_strain(c, 2 * n, 240)
    peak = np.abs(ref2).max()
    assert np.abs(ref2 - ref).max() < 1e-6 * peak  # the reference itself has converged
    assert np.abs(s - ref2).max() < 1e-4 * peak  # the bar
    assert np.abs(s - ref2).max() < 1e-6 * peak  # what the quadrature actually achieves


@pytest.mark.parametrize("c", CASES[:6], ids=str)
def test_agrees_with_library_reference_integrator(c):
    s = MODEL.predict(c)
    ref = reference_strain(c)
    assert np.abs(s - ref).max() < 1e-6 * np.abs(ref).max()


def test_compiled_loop_matches_numpy_expression():
    xs = np.arange(1, 5) * 3.3
    ys = np.arange(2, 6) * 3.9
    for args in ((0.1, 0.0, 1.0, 1.0, 9.0, 12.0), (0.3, 0.05, 2.5, 0.4, 11.0, 8.0)):
        v1, j1, _ = MODEL.strain_and_jacobian(*args, xs, ys)
        v2, j2, _ = MODEL.strain_and_jacobian_numpy(*args, xs, ys)
        np.testing.assert_allclose(v1, v2, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(j1, j2, rtol=1e-10, atol=1e-12 * np.abs(j2).max())
        ell, _ = MODEL.ellipse(*args[:4])
        np.testing.assert_allclose(
            MODEL.strain_from_ellipse(ell, args[3], args[4], args[5], xs, ys),
            MODEL.strain_from_ellipse_numpy(ell, args[3], args[4], args[5], xs, ys), rtol=1e-12)


def test_jacobian_matches_central_differences():
    xs = np.arange(8) * 3.3
    ys = np.arange(8) * 3.9
    p = np.array([0.1, 0.02, 1.1, 1.2, 10.0, 13.0])
    _, jac, _ = MODEL.strain_and_jacobian(*p, xs, ys)
    for i in range(6):
        h = 1e-6 * max(abs(p[i]), 1e-2)
        up, dn = p.copy(), p.copy()
        up[i] += h
        dn[i] -= h
        fd = (MODEL.strain_and_jacobian(*up, xs, ys)[0] - MODEL.strain_and_jacobian(*dn, xs, ys)[0]) / (2 * h)
        assert np.abs(fd - jac[..., i]).max() < 1e-6 * np.abs(jac[..., i]).max() + 1e-12


def test_strain_scales_with_force_as_hertz_predicts():
    # strain ~ F * S(a, b): doubling F scales the contact by 2^(1/3); for a contact much
    # smaller than the rubber depth S barely changes, so strain ~ F.
    c1 = Contact(0.2, 0.2, 0, 0.01, 11.0, 13.0)
    c2 = Contact(0.2, 0.2, 0, 0.02, 11.0, 13.0)
    ratio = MODEL.predict(c2).max() / MODEL.predict(c1).max()
    assert ratio == pytest.approx(2.0, rel=2e-3)


def test_integral_of_strain_matches_kernel_integral():
    # Summed over a fine grid of "tactels", strain * cell area = (F/E) * int h_x * int h_y
    # (the pressure integrates to F).  The kernels' -nu/u^2 tails make the finite-grid
    # integrals differ from 1 - nu, so integrate them over the same span with quad.
    from scipy.integrate import quad

    c = Contact(10, math.inf, 60, 1.0, 0.0, 0.0)
    half = 300.5 * 0.5
    xs = np.arange(-300, 301) * 0.5
    s = MODEL.predict(c, xs, xs)
    total = s.sum() * 0.25
    imp = SENSOR.impulse
    ix = quad(lambda u: float(line_response(u, imp.depth_x, imp.nu_x)), -half, half, limit=200)[0]
    iy = quad(lambda u: float(line_response(u, imp.depth_y, imp.nu_y)), -half, half, limit=200)[0]
    assert total == pytest.approx(1.0 / 0.25 * ix * iy, rel=5e-3)


def test_scaled_to_peak_reaches_the_asked_peak():
    """Two passes of the load's scale put the noise-free peak within 1 % of the asked one
    (the peak is nearly linear in the load: 0.4 % off for this cylinder), for a sphere and a
    cylinder."""
    import math

    from tactiled.physics.contact import Contact
    from tactiled.physics.strain import scaled_to_peak

    model = StrainModel()
    for make in (lambda s: Contact(4.0, 4.0, 0.0, s, 11.0, 13.0),
                 lambda s: Contact(8.0, math.inf, 60.0, s, 11.0, 13.0)):
        c = scaled_to_peak(model, make, 2e-3)
        assert abs(float(model.predict(c).max()) / 2e-3 - 1.0) < 1e-2

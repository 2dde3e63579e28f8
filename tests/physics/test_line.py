"""The line contact (a cylinder on a flat array) against independent quadrature and its limits."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from tactiled.physics.contact import LineContact
from tactiled.physics.impulse import line_response
from tactiled.fit.line import LineProblem
from tactiled.physics.line import across_line, along_line, half_width, line_strain
from tactiled.physics.strain import StrainModel
from tactiled.sensors import load_description

IMP = np.array([2.0, 0.5, 3.0, 0.3])


def _h(u: float, d: float, nu: float) -> float:
    return float(line_response(np.array([u]), d, nu)[0])


def _along_quad(px: float, py: float, psi: float) -> float:
    c, s = math.cos(psi), math.sin(psi)
    return quad(lambda t: _h(px - t * c, IMP[0], IMP[1]) * _h(py - t * s, IMP[2], IMP[3]),
                -np.inf, np.inf, limit=400, epsabs=1e-13, epsrel=1e-11)[0]


@pytest.mark.parametrize("psi", [0.0, 1e-4, 0.3, 0.7, math.pi / 2, 2.0, 3.0])
@pytest.mark.parametrize("px, py", [(0.0, 0.0), (1.5, -2.0), (4.0, 3.0), (-7.0, 0.3)])
def test_the_residue_integral_along_the_line_is_the_quadrature(psi: float, px: float, py: float) -> None:
    got = along_line(px, py, math.cos(psi), math.sin(psi), IMP)
    assert got == pytest.approx(_along_quad(px, py, psi), rel=1e-8, abs=1e-12)


def test_a_line_along_an_axis_integrates_one_kernel_to_one_minus_nu() -> None:
    # integral of h over the real line is 1 - nu: along x the response is (1 - nu_x) h_y
    got = along_line(0.3, 1.2, 1.0, 0.0, IMP)
    assert got == pytest.approx((1.0 - IMP[1]) * _h(1.2, IMP[2], IMP[3]), rel=1e-12)


def test_the_strain_is_the_double_quadrature_of_the_hertz_line_pressure() -> None:
    load, radius, psi = 0.08, 6.0, 37.0
    modulus, k = 0.25, 0.75 / 0.25
    b = half_width(load, radius, k)
    x, y, cx, cy = 11.3, 9.7, 10.0, 12.0
    c, s = math.cos(math.radians(psi)), math.sin(math.radians(psi))

    def across(sv: float) -> float:
        p = 2 * load / (math.pi * b) * math.sqrt(max(0.0, 1 - (sv / b) ** 2))
        return p * quad(lambda t: _h(x - (cx + t * c - sv * s), IMP[0], IMP[1])
                        * _h(y - (cy + t * s + sv * c), IMP[2], IMP[3]),
                        -np.inf, np.inf, limit=400, epsabs=1e-14)[0]

    reference = quad(across, -b, b, epsabs=1e-14, limit=200)[0] / modulus
    got = line_strain(load, radius, psi, cx, cy, np.array([x]), np.array([y]), IMP, modulus, k)[0]
    assert got == pytest.approx(reference, rel=1e-9)


def test_symmetries_half_turn_and_sliding_along_the_line() -> None:
    model = StrainModel(load_description("flat16").sensor_model())
    a = model.predict(LineContact(5.0, 30.0, 0.1, 18.0, 19.0))
    b = model.predict(LineContact(5.0, 210.0, 0.1, 18.0, 19.0))  # the same line
    t = 7.0  # another point of the same line
    c = model.predict(LineContact(5.0, 30.0, 0.1, 18.0 + t * math.cos(math.radians(30)),
                                  19.0 + t * math.sin(math.radians(30))))
    assert np.allclose(a, b, rtol=1e-9, atol=1e-13) and np.allclose(a, c, rtol=1e-9, atol=1e-13)
    assert np.allclose(2 * a, model.predict(LineContact(5.0 / 2, 30.0, 0.2, 18.0, 19.0)),
                       rtol=1e-9)  # same half-width (P R fixed), twice the load: twice the strain


def test_a_cylinder_on_a_flat_array_must_be_given_as_a_line() -> None:
    from tactiled.physics.contact import Contact

    model = StrainModel(load_description("flat16").sensor_model())
    with pytest.raises(ValueError, match="line contact"):
        model.predict(Contact(5.0, math.inf, 30.0, 1.0, 10.0, 10.0))
    # a sphere is an ordinary Hertz ellipse on a flat array (1/R_f = 0)
    assert model.predict(Contact(5.0, 5.0, 0.0, 1.0, 10.0, 10.0)).max() > 0.0


@pytest.mark.parametrize("psi", [0.3, 1.2, 2.0, 3.0, -0.4])
@pytest.mark.parametrize("dist", [0.0, 0.7, -2.3, 5.0])
def test_the_partials_across_the_line_are_the_residues_differentiated(psi: float, dist: float) -> None:
    # against central differences of the value (its own residue formula, checked above
    # against quadrature); steps where the difference's truncation and rounding are ~1e-9
    val, d_dist, d_psi = across_line(dist, psi, IMP, True)
    c, s = math.cos(psi), math.sin(psi)
    assert val == pytest.approx(along_line(-dist * s + 3.0 * c, dist * c + 3.0 * s, c, s, IMP),
                                rel=1e-12, abs=1e-15)  # any point at that distance
    h = 1e-5
    fd_dist = (across_line(dist + h, psi, IMP, False)[0] - across_line(dist - h, psi, IMP, False)[0]) / (2 * h)
    fd_psi = (across_line(dist, psi + h, IMP, False)[0] - across_line(dist, psi - h, IMP, False)[0]) / (2 * h)
    scale = abs(val) + 1e-3  # the partials' natural size: the value's
    assert d_dist == pytest.approx(fd_dist, abs=1e-7 * scale)
    assert d_psi == pytest.approx(fd_psi, abs=1e-7 * scale)


@pytest.mark.parametrize("psi", [0.0, math.pi / 2, math.pi])
def test_on_an_axis_the_angle_partial_is_the_one_sided_slope(psi: float) -> None:
    # the response has a kink in the angle there: the partial is the slope towards +psi
    _, _, d_psi = across_line(0.7, psi, IMP, True)
    h = 1e-5
    fwd = (across_line(0.7, psi + h, IMP, False)[0] - across_line(0.7, psi, IMP, False)[0]) / h
    assert d_psi == pytest.approx(fwd, rel=1e-3)


@pytest.mark.parametrize("p", [(math.log(6.0), 0.4, math.log(0.05), 0.7),
                               (math.log(20.0), 2.5, math.log(0.2), -1.0),
                               (math.log(2.0), -1.1, math.log(0.01), 0.1)])
def test_the_line_residual_and_its_exact_jacobian(p: tuple[float, ...]) -> None:
    """The compiled residual against the strain of line_strain_points (its value path) and its
    Jacobian against central differences of that."""
    rng = np.random.default_rng(7)
    xs, ys = 10.0 + 2.5 * np.arange(4), 12.0 + 2.5 * np.arange(4)
    ex, ey = rng.normal(0, 0.05, 16), rng.normal(0, 0.05, 16)
    sensor = load_description("flat16").sensor_model()
    target = rng.normal(0, 1e-3, 16)
    valid = np.ones(16, bool)
    valid[5] = False
    inv = np.full(16, 40.0)
    prob = LineProblem(sensor, xs, ys, ex, ey, target, valid, inv)
    p = np.array(p)

    def residual(q: np.ndarray) -> np.ndarray:
        return np.where(valid, (prob.strains(q) - target) * inv, 0.0)

    r, jac = prob.residual_and_jacobian(p)
    assert np.allclose(r, residual(p), rtol=1e-12, atol=1e-14)
    h = 1e-6
    fd = np.stack([(residual(p + h * e) - residual(p - h * e)) / (2 * h) for e in np.eye(4)], axis=1)
    assert np.abs(jac - fd).max() <= 1e-6 * np.abs(fd).max()
    assert not jac[5].any()  # an unusable tactel adds nothing


@pytest.mark.parametrize("psi", [0.4, 2.5, -1.1, 0.0, math.pi / 2, 1e-8])
def test_the_residual_sums_the_per_node_response_and_partials(psi: float) -> None:
    """line_residual computes what depends on the angle once per evaluation; each row is the
    sum over the rule of across_line (which recomputes it at each node), on and off the axes."""
    from tactiled.physics.line import line_residual
    rng = np.random.default_rng(11)
    n, nodes = 12, 9
    px, py = rng.uniform(0.0, 10.0, n), rng.uniform(0.0, 10.0, n)
    u = np.cos(np.arange(1, nodes + 1) * math.pi / (nodes + 1))
    w = rng.uniform(0.1, 1.0, nodes)
    p = np.array([math.log(8.0), psi, math.log(0.05), 0.4])
    comp, modulus = 0.01, 1.0
    r, jac = line_residual(p, px, py, 5.0, 5.0, IMP, modulus, comp, u, w, np.zeros(n),
                           np.ones(n, bool), np.ones(n))
    b = math.sqrt(4.0 * 0.05 * 8.0 * comp / math.pi)
    scale = 2.0 * 0.05 / (math.pi * modulus)
    c, s = math.cos(psi), math.sin(psi)
    for k in range(n):
        ex, ey = px[k] - 5.0, py[k] - 5.0
        e, de = -ex * s + ey * c, -ex * c - ey * s
        parts = np.array([across_line(e - 0.4 - b * ui, psi, IMP, True) for ui in u])
        assert r[k] == pytest.approx(scale * (w @ parts[:, 0]), rel=1e-12, abs=1e-18)
        assert jac[k, 3] == pytest.approx(-scale * (w @ parts[:, 1]), rel=1e-12, abs=1e-18)
        assert jac[k, 1] == pytest.approx(scale * (w @ (parts[:, 1] * de + parts[:, 2])),
                                          rel=1e-12, abs=1e-18)

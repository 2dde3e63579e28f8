"""The line contact (a cylinder on a flat array) against independent quadrature and its limits."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from tactiled.physics.contact import LineContact
from tactiled.physics.impulse import line_response
from tactiled.physics.line import along_line, half_width, line_strain
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

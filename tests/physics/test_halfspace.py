"""The half-space Green's functions against the equations they must solve and Johnson's closed
forms, and the traction model against independent adaptive quadrature (scipy, mpmath)."""

import math

import mpmath
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate

from tactiled.physics.halfspace import green, shear_modulus
from tactiled.physics.hertz import Ellipse
from tactiled.physics.traction import DisplacementModel, Traction, stick_ratio

E, NU = 0.3, 0.3
G = shear_modulus(E, NU)


def _u(x: float, y: float, z: float, j: int, nu: float = NU) -> np.ndarray:
    return green(np.array(x), np.array(y), z, G, nu)[:, j]


def _grad(x, y, z, j, h=1e-4):
    """du_i/dx_k by central differences, (3, 3)."""
    out = np.empty((3, 3))
    p = np.array((x, y, z))
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        out[:, k] = (_u(*(p + e), j) - _u(*(p - e), j)) / (2 * h)
    return out


def _stress(x, y, z, j, nu=NU):
    grad = _grad(x, y, z, j)
    eps = 0.5 * (grad + grad.T)
    lam = 2 * G * nu / (1 - 2 * nu)
    return 2 * G * eps + lam * np.trace(eps) * np.eye(3)


@pytest.mark.parametrize("j", [0, 1, 2])
@pytest.mark.parametrize("point", [(1.3, -0.7, 0.9), (-2.0, 0.4, 1.7), (0.2, 0.3, 0.5)])
def test_green_solves_navier(j, point):
    """Equilibrium without body force: (1 - 2 nu) lap u + grad div u = 0 (second differences)."""
    h = 2e-3
    p = np.array(point)
    lap = np.zeros(3)
    hess_div = np.zeros(3)
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        lap += (_u(*(p + e), j) - 2 * _u(*p, j) + _u(*(p - e), j)) / h ** 2

    def div(q):
        return np.trace(_grad(*q, j, h=1e-4))

    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        hess_div[k] = (div(p + e) - div(p - e)) / (2 * h)
    residual = (1 - 2 * NU) * lap + hess_div
    scale = np.abs(_u(*p, j)).max() / float(np.dot(p, p))
    assert np.abs(residual).max() < 1e-4 * scale


@pytest.mark.parametrize("j", [0, 1, 2])
def test_green_surface_traction_free(j):
    """sigma_iz = 0 on the surface away from the load (evaluated just below it)."""
    z = 1e-6
    for x, y in [(1.0, 0.5), (-0.7, 1.9), (2.5, -1.2)]:
        s = _stress(x, y, z + 2e-4, j)  # differences need room above the surface
        scale = 1.0 / (4 * math.pi * math.hypot(x, y) ** 2)  # stress per newton ~ 1/r^2
        assert np.abs(s[:, 2]).max() < 1e-3 * scale


@pytest.mark.parametrize("j", [0, 2])
def test_green_carries_the_force(j):
    """The stress across a plane at depth z balances the applied force: the slab above it
    carries +1 N along axis j and the traction sigma_jz on its lower face (outward normal +z),
    so the integral is -1 N (scipy dblquad in polar coordinates, radius mapped to [0, 1))."""
    z = 1.0

    def integrand(t, phi, i):
        r = t / (1 - t)
        jac = r / (1 - t) ** 2
        return _stress(r * math.cos(phi), r * math.sin(phi), z, j)[i, 2] * jac

    total = integrate.dblquad(lambda t, phi: integrand(t, phi, j), 0, 2 * math.pi, 0, 0.999,
                              epsabs=1e-5)[0]
    assert total == pytest.approx(-1.0, abs=3e-3)


def _axial_hertz_uz(a: float, z: float, nu: float) -> float:
    """u_z on the axis at depth z under a Hertz pressure of unit force on a circle of radius a
    (mpmath, 1-D: the Green's function averaged over the angle)."""
    g = shear_modulus(E, nu)
    p0 = 3 / (2 * math.pi * a * a)

    def f(r):
        rho = mpmath.sqrt(r * r + z * z)
        return p0 * mpmath.sqrt(1 - (r / a) ** 2) * (z * z / rho ** 3 + 2 * (1 - nu) / rho) * 2 * mpmath.pi * r

    return float(mpmath.quad(f, [0, a]) / (4 * mpmath.pi * g))


def _axial_stick_ux(a: float, z: float, nu: float) -> float:
    """u_x on the axis at depth z under the full-stick traction of unit force on a circle."""
    g = shear_modulus(E, nu)

    def f(t):  # r = a sin t removes the edge singularity: r dr / sqrt(a^2 - r^2) = a sin t dt
        r = a * mpmath.sin(t)
        rho = mpmath.sqrt(r * r + z * z)
        mean = 1 / rho + r * r / (2 * rho ** 3) + (1 - 2 * nu) * (1 / (rho + z) - r * r / (2 * rho * (rho + z) ** 2))
        return mean * 2 * mpmath.pi * a * mpmath.sin(t) / (2 * mpmath.pi * a)

    return float(mpmath.quad(f, [0, mpmath.pi / 2]) / (4 * mpmath.pi * g))


@pytest.mark.parametrize("nu", [0.0, 0.3, 0.5])
def test_axial_limits_are_johnsons_surface_closed_forms(nu):
    """As z -> 0 the axial integrals reach Johnson's surface displacements: Hertz (eq. 3.41)
    u_z(0) = pi (1 - nu^2) p0 a / (2 E); full stick (sec. 7.1) u_x = (2 - nu) Q / (8 G a)."""
    a = 2.0
    p0 = 3 / (2 * math.pi * a * a)
    e_nu = 2 * shear_modulus(E, nu) * (1 + nu)
    assert _axial_hertz_uz(a, 1e-7, nu) == pytest.approx(math.pi * (1 - nu * nu) * p0 * a / (2 * e_nu), rel=1e-5)
    assert _axial_stick_ux(a, 1e-7, nu) == pytest.approx((2 - nu) / (8 * shear_modulus(E, nu) * a), rel=1e-5)


@pytest.mark.parametrize("a,depth", [(1.0, 2.0), (2.5, 1.5), (4.0, 3.0)])
def test_axial_displacement_matches_mpmath(a, depth):
    model = DisplacementModel(depth, E, NU)
    ell = Ellipse(a, a, 0.0, 0.0)
    u = model.displacement(ell, Traction(1.0), 0.0, 0.0, np.zeros(1), np.zeros(1))[0]
    assert u[2] == pytest.approx(_axial_hertz_uz(a, depth, NU), rel=1e-8)
    assert abs(u[0]) < 1e-12 and abs(u[1]) < 1e-12
    stick = model.displacement(ell, Traction(1.0, fx=1.0), 0.0, 0.0, np.zeros(1), np.zeros(1))[0] - u
    assert stick[0] == pytest.approx(_axial_stick_ux(a, depth, NU), rel=1e-8)


def _dblquad_displacement(ell: Ellipse, load: Traction, x0, y0, px, py, depth) -> np.ndarray:
    """Independent integration of the same tractions: scipy's adaptive dblquad in the ellipse's
    polar coordinates (rho = k sin t, so both the sqrt and the 1/sqrt edges are smooth)."""
    g = shear_modulus(E, NU)
    c, s = math.cos(ell.theta), math.sin(ell.theta)
    ab = ell.a * ell.b
    q = np.array((load.fx, load.fy))

    def point(rho, phi):
        xp, yp = ell.a * rho * math.cos(phi), ell.b * rho * math.sin(phi)
        ox, oy = xp * c - yp * s, xp * s + yp * c
        return ox, oy, green(np.array(px - x0 - ox), np.array(py - y0 - oy), depth, g, NU)

    def hertz_part(k, t, phi, axis_weights):
        # traction 3/(2 pi a' b') sqrt(1 - rho^2/k^2) on the ellipse scaled by k: unit force
        rho = k * math.sin(t)
        _, _, gr = point(rho, phi)
        dens = 3 / (2 * math.pi * ab * k * k) * math.cos(t)
        area = ab * rho * k * math.cos(t)  # ab rho d rho, d rho = k cos t dt
        return gr @ axis_weights * dens * area

    out = np.zeros(3)
    for comp in range(3):
        def f_normal(t, phi):
            return hertz_part(1.0, t, phi, np.array((0, 0, load.force)))[comp]
        out[comp] += integrate.dblquad(f_normal, 0, 2 * math.pi, 0, math.pi / 2, epsabs=1e-13, epsrel=1e-10)[0]
        if load.lam > 0:
            kap = stick_ratio(load.lam)
            w = np.array((*q, 0.0)) / load.lam

            def f_outer(t, phi):
                return hertz_part(1.0, t, phi, w)[comp]

            def f_inner(t, phi):
                return hertz_part(kap, t, phi, w)[comp] * kap ** 3

            out[comp] += integrate.dblquad(f_outer, 0, 2 * math.pi, 0, math.pi / 2, epsabs=1e-13, epsrel=1e-10)[0]
            if kap > 0:
                out[comp] -= integrate.dblquad(f_inner, 0, 2 * math.pi, 0, math.pi / 2, epsabs=1e-13, epsrel=1e-10)[0]
        if load.torque:
            k_t = 3 * load.torque / (2 * math.pi * ab * (ell.a ** 2 + ell.b ** 2))

            def f_tors(t, phi):
                rho = math.sin(t)
                ox, oy, gr = point(rho, phi)
                # q = K (-oy, ox) / sqrt(1 - rho^2); area ab rho d rho = ab rho cos t dt
                return (gr @ np.array((-oy, ox, 0.0)))[comp] * k_t * ab * rho

            out[comp] += integrate.dblquad(f_tors, 0, 2 * math.pi, 0, math.pi / 2, epsabs=1e-13, epsrel=1e-10)[0]
    return out


@pytest.mark.parametrize("load", [
    Traction(1.0, fx=0.3, fy=-0.2, lam=0.5),
    Traction(0.8, fx=-0.1, fy=0.25, lam=0.9),
    Traction(1.2, fx=0.4, lam=1.0),
    Traction(1.0, torque=0.7),
])
def test_off_axis_displacement_matches_dblquad(load):
    depth = 2.0
    ell = Ellipse(2.2, 1.4, 0.6, 1 - (1.4 / 2.2) ** 2)
    model = DisplacementModel(depth, E, NU)
    px, py = np.array((1.7, -0.4)), np.array((0.9, 2.3))
    got = model.displacement(ell, load, 0.3, -0.2, px, py)
    for i in range(2):
        want = _dblquad_displacement(ell, load, 0.3, -0.2, px[i], py[i], depth)
        assert got[i] == pytest.approx(want, rel=1e-6, abs=1e-9 * np.abs(want).max())


def test_partial_slip_tends_to_full_stick():
    """lam -> 0: the Mindlin traction's displacement tends to the full-stick one (the two are
    integrated by different rules)."""
    model = DisplacementModel(1.5, E, NU)
    ell = Ellipse(2.0, 2.0, 0.0, 0.0)
    px, py = np.linspace(-3, 3, 7), np.linspace(-1, 2, 7)
    stick = model.displacement(ell, Traction(1.0, fx=0.2, fy=0.1, lam=0.0), 0.0, 0.0, px, py)
    near = model.displacement(ell, Traction(1.0, fx=0.2, fy=0.1, lam=1e-3), 0.0, 0.0, px, py)
    far = model.displacement(ell, Traction(1.0, fx=0.2, fy=0.1, lam=0.5), 0.0, 0.0, px, py)
    gap = np.abs(far - stick).max()
    assert np.abs(near - stick).max() < 2e-3 * gap


def test_gross_slip_is_mu_times_the_hertz_pressure():
    """lam = 1: the tangential traction is mu p, so its displacement along x at the contact's
    centre is Q times the Cerruti response of the unit Hertz pressure."""
    model = DisplacementModel(2.0, E, NU)
    ell = Ellipse(1.5, 1.5, 0.0, 0.0)
    px, py = np.array((0.0, 1.0)), np.array((0.0, -2.0))
    slip = model.displacement(ell, Traction(1.0, fx=0.4, lam=1.0), 0.0, 0.0, px, py)
    unit = model.hertz_shaped(ell, 1.0, 0.0, 0.0, px, py)
    assert slip == pytest.approx((unit[:, 2] * 1.0 + unit[:, 0] * 0.4).T, rel=1e-12)


_load = st.tuples(st.floats(0.2, 2.0), st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(-1, 1),
                  st.floats(0.0, 1.0))


@settings(max_examples=40, deadline=None)
@given(_load, _load, st.floats(0.5, 3.0))
def test_linear_in_the_loads(l1, l2, a):
    """At one friction state the displacement is linear in (P, Q, T)."""
    model = DisplacementModel(1.8, E, NU, tol=1e-7)
    ell = Ellipse(a, 0.7 * a, 0.3, 1 - 0.49)
    lam = l1[4]
    px, py = np.linspace(-4, 4, 5), np.linspace(3, -3, 5)
    t1, t2 = Traction(*l1[:4], lam=lam), Traction(*l2[:4], lam=lam)
    both = Traction(l1[0] + l2[0], l1[1] + l2[1], l1[2] + l2[2], l1[3] + l2[3], lam=lam)
    u = model.displacement(ell, both, 0.5, 0.1, px, py)
    parts = model.displacement(ell, t1, 0.5, 0.1, px, py) + model.displacement(ell, t2, 0.5, 0.1, px, py)
    assert u == pytest.approx(parts, rel=1e-9, abs=1e-12)


@settings(max_examples=40, deadline=None)
@given(_load, st.floats(0.5, 3.0), st.floats(-3, 3), st.floats(-3, 3))
def test_mirror_symmetry(load, a, x, y):
    """Mirroring y -> -y on an x-aligned ellipse flips fy, the torsion and u_y."""
    model = DisplacementModel(1.8, E, NU, tol=1e-7)
    ell = Ellipse(a, 0.6 * a, 0.0, 1 - 0.36)
    p, fx, fy, t, lam = load
    u = model.displacement(ell, Traction(p, fx, fy, t, lam), 0.0, 0.0, np.array([x]), np.array([y]))[0]
    m = model.displacement(ell, Traction(p, fx, -fy, -t, lam), 0.0, 0.0, np.array([x]), np.array([-y]))[0]
    assert m == pytest.approx(u * np.array((1, -1, 1)), rel=1e-9, abs=1e-12)


@settings(max_examples=30, deadline=None)
@given(_load, st.floats(0.5, 3.0), st.floats(-3, 3), st.floats(-3, 3))
def test_quarter_turn_symmetry(load, a, x, y):
    """On a circle, turning the loads and the point a quarter turn turns the displacement (to
    the quadrature's accuracy: its tensor rule is not itself invariant under the turn)."""
    model = DisplacementModel(1.8, E, NU, tol=1e-7)
    ell = Ellipse(a, a, 0.0, 0.0)
    p, fx, fy, t, lam = load
    u = model.displacement(ell, Traction(p, fx, fy, t, lam), 0.0, 0.0, np.array([x]), np.array([y]))[0]
    r = model.displacement(ell, Traction(p, -fy, fx, t, lam), 0.0, 0.0, np.array([-y]), np.array([x]))[0]
    assert r == pytest.approx(np.array((-u[1], u[0], u[2])), rel=1e-6, abs=1e-6 * np.abs(u).max())


def test_compiled_sum_matches_the_numpy_green():
    from tactiled.physics.halfspace import green_weighted

    rng = np.random.default_rng(3)
    px, py = rng.uniform(-3, 3, 7), rng.uniform(-3, 3, 7)
    ox, oy = rng.uniform(-1, 1, 11), rng.uniform(-1, 1, 11)
    w = rng.normal(size=(2, 3, 11))
    got = green_weighted(px, py, ox, oy, w, 1.7, G, NU)
    gr = green(px[:, None] - ox[None, :], py[:, None] - oy[None, :], 1.7, G, NU)  # (3, 3, P, N)
    want = np.einsum("ijpn,kjn->kijp", gr, w)
    assert got == pytest.approx(want, rel=1e-12, abs=1e-15)

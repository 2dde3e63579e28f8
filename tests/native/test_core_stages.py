"""Each compiled stage of the physics and the fit agrees with its Python reference.

The Python bodies (each module's ``REFERENCE``) and the C++ stages (core/*.cpp) do the same
arithmetic in the same order, with the same libm, no fast-math and no fused multiply-add, so
they are held bit-equal.  The exceptions, with their tolerance and why:

- ``normal_equations``, ``damped_step``, ``cramer_rao``: the reference's products go through
  numpy's BLAS (blocked, vectorised sums) and LAPACK (``solve``, ``eigh``); the core sums in
  plain order and solves by LU with partial pivoting / Jacobi rotations.  Both are backward
  stable, so they agree to a few ulps of the inputs' scale times the condition number: rtol
  1e-12 on well-conditioned draws (condition < 1e3).
- the line contact's response alone (``tactiled.physics.line``'s ``along_line``, and
  ``across_line`` without partials; its strain, residual and partials are real arithmetic,
  bit-equal): the reference's complex arithmetic runs on numpy scalars (its inputs come from
  arrays), whose complex division is numpy's, not the CPython arithmetic the core repeats
  (core/pycomplex.hpp): a last-bit difference per division, rtol 1e-10 after the residue's
  cancellations (atol 1e-12 of the response's scale).
- the whole search (``compiled.search``): built on those products, it agrees to rtol 1e-9 in
  the fitted parameters and the cost (rounding differences of 1e-16 damped through a few
  iterations of a converging search), the same status and message.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from tactiled import native

pytestmark = pytest.mark.skipif(native.core is None, reason="TACTILED_CORE=python: no core to compare")

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
unit = st.floats(-1.0, 1.0, allow_nan=False)


def same(got, want) -> None:
    """Bit-equal, element by element and through tuples (NaN equal to NaN)."""
    if isinstance(want, tuple | list):
        assert len(got) == len(want)
        for g, w in zip(got, want):
            same(g, w)
        return
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want), strict=False)
    assert np.asarray(got).shape == np.asarray(want).shape


def close(got, want) -> None:
    """Equal to rtol 1e-10, atol 1e-12 of the largest magnitude (the line contact's tolerance)."""
    if isinstance(want, tuple | list):
        for g, w in zip(got, want, strict=True):
            close(g, w)
        return
    w = np.asarray(want, dtype=float)
    scale = float(np.abs(w).max()) if w.size else 0.0
    np.testing.assert_allclose(np.asarray(got, dtype=float), w, rtol=1e-10, atol=1e-12 * scale)


# --- eccentricity, Hertz, models --------------------------------------------------------------

@settings(max_examples=300, deadline=None)
@given(x=st.floats(-60.0, 50.0), steps=st.integers(0, 3))
def test_eccentricity_solve_equals_the_reference(x: float, steps: int) -> None:
    from tactiled.physics import eccentricity as e

    same(e.solve_log_scalar(x, steps), e.REFERENCE["solve_log_scalar"](x, steps))


@settings(max_examples=300, deadline=None)
@given(m=st.floats(1e-300, 1.0, exclude_max=True))
def test_elliptic_integrals_and_kernel_equal_the_reference(m: float) -> None:
    from tactiled.physics import eccentricity as e

    same(e.ellip_ke(m, 1.0 - m), e.REFERENCE["ellip_ke"](m, 1.0 - m))
    same(e.kernel_scalar(m, 1.0 - m), e.REFERENCE["kernel_scalar"](m, 1.0 - m))


@settings(max_examples=300, deadline=None)
@given(ka=st.floats(0.0, 5.0), kb=st.floats(0.0, 5.0), psi=st.floats(-7.0, 7.0),
       force=st.floats(1e-3, 50.0), rf=st.floats(2.0, 30.0), comp=st.floats(1e-3, 5.0))
def test_hertz_ellipse_equals_the_reference(ka, kb, psi, force, rf, comp) -> None:
    from tactiled.physics import hertz

    j_core, j_ref = np.full((3, 4), 7.0), np.full((3, 4), 7.0)
    got = hertz.ellipse_core(ka, kb, psi, force, rf, comp, j_core)
    want = hertz.REFERENCE["ellipse_core"](ka, kb, psi, force, rf, comp, j_ref)
    # math.hypot is CPython's own correctly rounded norm, std::hypot glibc's (also within an
    # ulp): they may differ in the last bit, which the solve carries to ~1e-15 relative
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-300)
    if want[0] > 0 and np.isfinite(j_ref).all():
        np.testing.assert_allclose(j_core, j_ref, rtol=1e-10, atol=1e-13 * np.abs(j_ref).max())


@settings(max_examples=200, deadline=None)
@given(kind=st.integers(0, 2), p=arrays(np.float64, 6, elements=st.floats(-5.0, 5.0)))
def test_model_maps_equal_the_reference(kind: int, p: np.ndarray) -> None:
    from tactiled.fit import models

    k = (5, 4, 6)[kind]
    d_core, d_ref = np.zeros((6, k)), np.zeros((6, k))
    same(models.physical_map(kind, p[:k], d_core), models.REFERENCE["physical_map"](kind, p[:k], d_ref))
    same(d_core, d_ref)


# --- quadrature --------------------------------------------------------------------------------

def _rule(nu: int, ns: int):
    from tactiled.physics.quadrature_rules import disk_rule

    return disk_rule(nu, ns)


@settings(max_examples=100, deadline=None)
@given(x0=st.floats(-2.0, 12.0), y0=st.floats(-2.0, 12.0), a=st.floats(0.05, 6.0),
       ratio=st.floats(0.05, 1.0), theta=st.floats(0.0, math.pi), force=st.floats(0.01, 20.0),
       nu=st.integers(3, 10), ns=st.integers(3, 10), rows=st.integers(1, 5), cols=st.integers(1, 5),
       nux=st.floats(0.0, 0.5), nuy=st.floats(0.0, 0.5), dep=st.floats(0.5, 4.0))
def test_quadrature_kernels_equal_the_reference(x0, y0, a, ratio, theta, force, nu, ns, rows,
                                                cols, nux, nuy, dep) -> None:
    from tactiled.physics import kernels

    u, v, w = _rule(nu, ns)
    xs, ys = np.arange(rows) * 2.5 + 0.3, np.arange(cols) * 2.0 - 0.1
    imp = np.array([dep, nux, 1.1 * dep, nuy])
    geo = np.array([x0, y0, a, a * ratio, theta, force, 0.02])
    hj = np.linspace(-1.0, 1.0, 12).reshape(3, 4)
    ref = kernels.REFERENCE
    same(kernels.strain_with_jacobian(geo, hj, u, v, w, xs, ys, imp),
         ref["strain_with_jacobian"](geo, hj, u, v, w, xs, ys, imp))
    same(kernels.quadrature(x0, y0, a, a * ratio, theta, u, v, w, xs, ys, *imp),
         ref["quadrature"](x0, y0, a, a * ratio, theta, u, v, w, xs, ys, *imp))
    px, py = np.repeat(xs, cols) + 0.07, np.tile(ys, rows) - 0.03
    same(kernels.quadrature_points(x0, y0, a, a * ratio, theta, u, v, w, px, py, imp),
         ref["quadrature_points"](x0, y0, a, a * ratio, theta, u, v, w, px, py, imp))
    rng = np.random.default_rng(rows * 7 + cols)
    n = rows * cols
    target, inv = rng.normal(size=n), rng.uniform(0.5, 2.0, n)
    valid = rng.uniform(size=n) < 0.8
    ex, ey = rng.normal(0, 0.1, n), rng.normal(0, 0.1, n)
    dphys = rng.normal(size=(6, 5))
    same(kernels.window_residual(geo, hj, dphys, u, v, w, xs, ys, imp, target, valid, inv, ex, ey),
         ref["window_residual"](geo, hj, dphys, u, v, w, xs, ys, imp, target, valid, inv, ex, ey))


# --- least squares -----------------------------------------------------------------------------

def _conditioned(rows: int, k: int, seed: int) -> np.ndarray:
    """A rows x k Jacobian of condition below 1e3 (columns of spread scale)."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(rows, k)))
    s = np.geomspace(1.0, 1e-2, k) * rng.uniform(0.5, 2.0)
    vt, _ = np.linalg.qr(rng.normal(size=(k, k)))
    return (q * s) @ vt * np.geomspace(1e-3, 1e3, k)


@settings(max_examples=200, deadline=None)
@given(rows=st.integers(6, 30), k=st.integers(1, 6), seed=st.integers(0, 2**32 - 1),
       lam=st.floats(1e-9, 1e3), sigma=st.floats(1e-3, 10.0))
def test_least_squares_pieces_agree_with_the_reference(rows, k, seed, lam, sigma) -> None:
    from tactiled.physics import kernels

    ref = kernels.REFERENCE
    jac = _conditioned(rows, k, seed)
    r = np.random.default_rng(seed + 1).normal(size=rows)
    got, want = kernels.normal_equations(jac, r), ref["normal_equations"](jac, r)
    for g_, w_ in zip(got, want):
        np.testing.assert_allclose(g_, w_, rtol=1e-12, atol=1e-13 * np.abs(w_).max())
    jtj, g, diag = want
    scale = np.full(k, 1e3)
    s_got, s_want = kernels.damped_step(jtj, g, diag, lam, scale), ref["damped_step"](jtj, g, diag, lam, scale)
    # two backward-stable solves of the damped system agree to its condition number times the
    # rounding (normwise), not better: lam down to 1e-9 leaves it nearly as ill-conditioned as
    # J^T J (up to ~1e13 here)
    damped = jtj + np.diag(lam * diag)
    tol = max(1e-12, 100.0 * np.finfo(float).eps * np.linalg.cond(damped))
    np.testing.assert_allclose(s_got[0], s_want[0], rtol=1e-9, atol=tol * np.abs(s_want[0]).max())
    assert s_got[1] == pytest.approx(s_want[1], rel=max(1e-9, tol))
    assert s_got[2] == pytest.approx(s_want[2], rel=max(1e-9, tol), abs=1e-12 * abs(s_want[2]))
    grad = np.random.default_rng(seed + 2).normal(size=(3, k))
    (std_g, cond_g), (std_w, cond_w) = (kernels.cramer_rao(jac, grad, sigma),
                                        ref["cramer_rao"](jac, grad, sigma))
    np.testing.assert_allclose(std_g, std_w, rtol=1e-9)
    assert cond_g == pytest.approx(cond_w, rel=1e-9)
    assert kernels.finite_cost(r, jac) == ref["finite_cost"](r, jac)


def test_a_singular_step_raises_numpys_error_and_a_bad_jacobian_costs_inf() -> None:
    from tactiled.physics import kernels

    with pytest.raises(np.linalg.LinAlgError):
        kernels.damped_step(np.zeros((2, 2)), np.ones(2), np.zeros(2), 1.0, np.ones(2))
    jac = np.ones((3, 2))
    jac[1, 1] = np.nan
    assert kernels.finite_cost(np.ones(3), jac) == math.inf
    std, cond = kernels.cramer_rao(np.zeros((4, 2)), np.ones((1, 2)), 1.0)
    assert cond == math.inf and np.isnan(std).all()


# --- line contact ------------------------------------------------------------------------------

IMP = np.array([1.6, 0.45, 1.9, 0.3])


@settings(max_examples=200, deadline=None)
@given(dist=finite, psi=st.one_of(st.floats(-7.0, 7.0), st.sampled_from([0.0, math.pi / 2, 1e-8, 1e-13])),
       px=finite, py=finite, want=st.booleans())
def test_line_response_equals_the_reference(dist, psi, px, py, want) -> None:
    from tactiled.physics import line

    ref = line.REFERENCE
    # with its partials the response is the closed form's real arithmetic (bit-equal); its
    # value alone is along_line's complex residues
    (same if want else close)(line.across_line(dist, psi, IMP, want), ref["across_line"](dist, psi, IMP, want))
    c, s = math.cos(psi), math.sin(psi)
    close(line.along_line(px, py, c, s, IMP), ref["along_line"](px, py, c, s, IMP))


@settings(max_examples=60, deadline=None)
@given(ln_r=st.floats(0.0, 4.0), psi=st.floats(-4.0, 4.0), ln_p=st.floats(-5.0, 0.0),
       off=st.floats(-3.0, 3.0), rows=st.integers(1, 4), cols=st.integers(1, 4),
       nodes=st.integers(3, 9), seed=st.integers(0, 1000))
def test_line_residual_and_strain_equal_the_reference(ln_r, psi, ln_p, off, rows, cols, nodes, seed) -> None:
    from tactiled.physics import line
    from tactiled.physics.quadrature_rules import _rule_s

    ref = line.REFERENCE
    rng = np.random.default_rng(seed)
    xs, ys = np.arange(rows) * 2.0, np.arange(cols) * 2.5
    n = rows * cols
    ex, ey = rng.normal(0, 0.1, n), rng.normal(0, 0.1, n)
    same(line.line_points(xs, ys, ex, ey), ref["line_points"](xs, ys, ex, ey))
    px, py, rx, ry = ref["line_points"](xs, ys, ex, ey)
    u, w = _rule_s(nodes)
    p = np.array([ln_r, psi, ln_p, off])
    target, valid, inv = rng.normal(size=n), rng.uniform(size=n) < 0.8, rng.uniform(0.5, 2.0, n)
    same(line.line_residual(p, px, py, rx, ry, IMP, 0.3, 0.02, u, w, target, valid, inv),
         ref["line_residual"](p, px, py, rx, ry, IMP, 0.3, 0.02, u, w, target, valid, inv))
    same(line.line_strain_points(0.05, 0.4, psi, rx, ry, px, py, IMP, 0.3, u, w),
         ref["line_strain_points"](0.05, 0.4, psi, rx, ry, px, py, IMP, 0.3, u, w))

@settings(max_examples=80, deadline=None)
@given(psi=st.one_of(st.floats(-7.0, 7.0), st.sampled_from([0.0, math.pi / 2, -math.pi, 1e-13])),
       hw=st.floats(0.01, 3.0), nodes=st.integers(1, 12),
       dx=st.floats(0.3, 3.0), dy=st.floats(0.3, 3.0), nux=st.floats(0.0, 0.49),
       nuy=st.floats(0.0, 0.49), seed=st.integers(0, 1000))
def test_line_strain_is_the_reference_bit_for_bit_and_the_residues_summed(
        psi, hw, nodes, dx, dy, nux, nuy, seed) -> None:
    """The line's strain is the closed form across the line (line.py's _coefficients), one
    real division a point: the core repeats the reference's operations, bit for bit, and both
    are along_line's two complex residues summed over the nodes, to 1e-12 of the largest
    strain (an independent computation, point by point; on an axis its principal value, and
    not within 1e-3 rad of one, where along_line loses digits to cancellation or takes the
    axis's principal value for a line 1e-13 rad off it, 3e-12 from the closed form, which
    agrees with 40-digit arithmetic)."""
    from tactiled.physics import line
    from tactiled.physics.quadrature_rules import _rule_s

    c, s = math.cos(psi), math.sin(psi)
    rng = np.random.default_rng(seed)
    imp = np.array([dx, nux, dy, nuy])
    px, py = rng.uniform(-20.0, 20.0, 40), rng.uniform(-20.0, 20.0, 40)
    u, w = _rule_s(nodes)
    cx, cy, load, modulus = 0.7, -1.3, 0.05, 0.3
    got = line.line_strain_points(load, hw, psi, cx, cy, px, py, imp, modulus, u, w)
    same(got, line.REFERENCE["line_strain_points"](load, hw, psi, cx, cy, px, py, imp, modulus, u, w))
    assume(min(abs(c), abs(s)) < 1e-15 or min(abs(c), abs(s)) > 1e-3)
    along = line.REFERENCE["along_line"]
    want = np.array([2.0 * load / (math.pi * modulus) * sum(
        wi * along(x - cx + hw * ui * s, y - cy - hw * ui * c, c, s, imp) for ui, wi in zip(u, w))
        for x, y in zip(px, py)])
    np.testing.assert_allclose(got, want, rtol=0.0, atol=1e-12 * np.abs(want).max())


# --- window, start, flat field -----------------------------------------------------------------

frames = arrays(np.float64, st.tuples(st.integers(1, 9), st.integers(1, 9)),
                elements=st.floats(-2.0, 5.0, allow_nan=False))


@settings(max_examples=300, deadline=None)
@given(strain=frames, size=st.integers(1, 6), max_strain=st.floats(0.5, 10.0),
       min_peak=st.floats(-1.0, 3.0), sigma=st.floats(1e-3, 1.0), dx=st.floats(0.5, 3.0))
def test_window_stages_equal_the_reference(strain, size, max_strain, min_peak, sigma, dx) -> None:
    from tactiled.fit import window

    ref = window.REFERENCE
    same(window.plain_window(strain, size, max_strain), ref["plain_window"](strain, size, max_strain))
    same(window.plain_frame(strain, size, max_strain, min_peak, sigma),
         ref["plain_frame"](strain, size, max_strain, min_peak, sigma))
    m, n = np.unravel_index(int(np.argmax(strain)), strain.shape)
    same(window.peak_centre(strain, int(m), int(n), dx, 1.3), ref["peak_centre"](strain, int(m), int(n), dx, 1.3))
    rows = strain.shape[0]
    for lower, upper in ((0.1, 0.2), (0.2, 0.1), (-math.inf, 0.3)):
        same(window.window_origin(int(m), size, rows, lower, upper),
             ref["window_origin"](int(m), size, rows, lower, upper))


@settings(max_examples=300, deadline=None)
@given(strain=frames, total=st.floats(-10.0, 100.0), modulus=st.floats(0.05, 5.0),
       dx=st.floats(0.5, 3.0), dy=st.floats(0.5, 3.0), nu=st.floats(0.0, 0.5))
def test_start_stages_equal_the_reference(strain, total, modulus, dx, dy, nu) -> None:
    from tactiled.fit import start

    ref = start.REFERENCE
    rows, cols = strain.shape
    m, n = (int(i) for i in np.unravel_index(int(np.argmax(strain)), strain.shape))
    args = (strain, m, n, total, modulus, rows, dx, 1.5, nu, cols, dy, 1.8, 0.4)
    same(start.start_point(*args), ref["start_point"](*args))
    same(start.line_sum(rows, dx, 0.7, 1.5, nu), ref["line_sum"](rows, dx, 0.7, 1.5, nu))


@settings(max_examples=100, deadline=None)
@given(n=st.integers(1, 60), width=st.integers(1, 9), k=st.integers(1, 70), seed=st.integers(0, 10**6),
       count=st.integers(1, 6), sep=st.floats(0.0, 90.0))
def test_nearest_and_separated_picks_equal_the_reference(n, width, k, seed, count, sep) -> None:
    from tactiled.fit import start

    rng = np.random.default_rng(seed)
    table = np.round(rng.normal(size=(n, width)), 1)  # ties, as a real table has
    feat = np.round(rng.normal(size=width), 1)
    feat[rng.uniform(size=width) < 0.2] = np.nan
    same(start.nearest(table, feat, k), start.REFERENCE["nearest"](table, feat, k))
    angles = np.round(rng.uniform(0.0, 180.0, n), 0)
    same(start.pick_separated(angles, count, sep), start.REFERENCE["pick_separated"](angles, count, sep))


@settings(max_examples=100, deadline=None)
@given(k=st.integers(1, 16), seed=st.integers(0, 10**6), w=st.floats(0.1, 1e3), poison=st.booleans())
def test_flat_field_accumulation_equals_the_reference(k, seed, w, poison) -> None:
    from tactiled.fit import flatfield

    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(k, k)))
    resid_op = q[:, : max(1, k // 2)] @ q[:, : max(1, k // 2)].T
    m, jx, jy, r = (rng.normal(size=k) for _ in range(4))
    if poison:
        r[rng.integers(k)] = np.inf
    u = rng.normal(size=3 * k + 5)
    idx = rng.permutation(3 * k + 5)[: 3 * k].astype(np.int64)
    ata_c, atb_c = np.ones((3 * k, 3 * k)), np.ones(3 * k)
    ata_r, atb_r = ata_c.copy(), atb_c.copy()
    got = flatfield._accumulate(ata_c, atb_c, resid_op, m, jx, jy, r, u, idx, w)
    want = flatfield.REFERENCE["_accumulate"](ata_r, atb_r, resid_op, m, jx, jy, r, u, idx, w)
    same(got, want)
    same(ata_c, ata_r)
    same(atb_c, atb_r)


# --- the search --------------------------------------------------------------------------------

def test_the_work_units_are_the_budgets() -> None:
    from tactiled.fit import budget

    for nu, ns, pts in ((3, 3, 16), (64, 64, 16), (100, 100, 25), (1024, 3, 1)):
        assert native.core.evaluation_work(nu, ns, pts) == budget.evaluation_work(nu, ns, pts)
        assert native.core.line_work(nu, pts) == budget.line_work(nu, pts)
    assert native.core.LINE_CHARGED_TACTELS == budget.LINE_CHARGED_TACTELS


@settings(max_examples=25, deadline=None)
@given(kind=st.integers(0, 2), r1=st.floats(2.0, 60.0), psi=st.floats(10.0, 170.0),
       force=st.floats(0.1, 5.0), x0=st.floats(4.0, 14.0), y0=st.floats(4.0, 14.0),
       shift=st.floats(-0.5, 0.5), max_iter=st.integers(0, 40))
def test_the_search_agrees_with_the_reference(kind, r1, psi, force, x0, y0, shift, max_iter) -> None:
    from tactiled.sensors.model import DEFAULT_SENSOR
    from tactiled.fit import compiled
    from tactiled.fit.models import MODELS
    from tactiled.physics.contact import Contact
    from tactiled.physics.quadrature_rules import MAX_NODES
    from tactiled.physics.strain import StrainModel

    model = StrainModel(DEFAULT_SENSOR)
    g = DEFAULT_SENSOR.geometry
    truth = Contact(r1, (math.inf, r1, 3.0 * r1)[kind], psi, force, x0, y0)
    strain = model.predict(truth)
    m, n = np.unravel_index(int(np.argmax(strain)), strain.shape)
    r0, c0 = min(max(int(m) - 1, 0), g.rows - 4), min(max(int(n) - 1, 0), g.cols - 4)
    window = strain[r0:r0 + 4, c0:c0 + 4]
    peak = float(window.max())
    assume(peak > 0.0)
    xs, ys = (r0 + np.arange(4)) * g.dx, (c0 + np.arange(4)) * g.dy
    wargs = (xs, ys, window.ravel().copy(), np.ones(16, bool), np.full(16, 1.0 / peak),
             np.zeros(16), np.zeros(16))
    name = ("cylinder", "sphere", "general")[kind]
    p0 = MODELS[name].from_values(r1 * 1.5, truth.r2, psi + 10.0, force * 0.7, x0 + shift, y0 - shift)
    k = p0.size
    args = (kind, p0, np.full(k, 1.0), max_iter, 1e-9, 1e-10, 1e-3, 0.0, np.full(k, -np.inf),
            np.full(k, np.inf), model._rf, model._k, model._scale, model._dmin, 1e-9, model._imp,
            *wargs, *compiled.rule_tables(), math.inf, MAX_NODES, math.inf, 0.0, -1.0, False)
    got = compiled.search(*args)
    want = compiled.REFERENCE["search"](*args)
    status, p, r, jac, cost, it, evals, conv, msg, rem, work = want
    assert got[0] == status and got[8] == msg and got[7] == conv
    np.testing.assert_allclose(got[1], p, rtol=1e-9, atol=1e-9)
    assert got[4] == pytest.approx(cost, rel=1e-9, abs=1e-24)
    # the same evaluations, or (a tie broken by the last bit) within a step of them
    assert abs(got[5] - it) <= 1 and abs(got[6] - evals) <= 2

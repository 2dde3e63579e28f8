"""The core's tracker kernels (core/tracker.cpp) against their Python reference
(``tactiled.pipeline.kernels.REFERENCE``), and the line's band (core/linewindow.cpp) and the
half-space's Green's sum (core/halfspace.cpp) against theirs, on hypothesis-drawn inputs.

Bit-equal where the arithmetic is the same: the filters, the constants, the tests of a step,
the estimate's numbers and the residual sums run on Python floats in the reference in the
core's order, with the same libm.  The exceptions, with their tolerance and why:

- ``measure_window`` (and the step and residual of ``measure_point``): the reference's two
  matrix products and the weighted sum go through numpy's BLAS (blocked, vectorised sums); the
  core sums in index order.  Both round each of n <= 100 products once: they agree to
  n eps of the terms' magnitude, rtol 1e-9 with an atol of 1e-12 of the largest term.
- ``green_weighted``: the reference sums through ``einsum`` in another order than the core's
  node by node: rtol 1e-11 (a few hundred positive-dominated terms), atol 1e-14 of the scale.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactiled import native
from tactiled.fit import linewindow
from tactiled.physics import halfspace
from tactiled.pipeline import kernels

pytestmark = pytest.mark.skipif(native.core is None, reason="TACTILED_CORE=python: no core to compare")
core = native.core
REF = kernels.REFERENCE
SETTINGS = settings(max_examples=150, deadline=None)


def same(got, want) -> None:
    """Bit-equal, element by element and through tuples (NaN equal to NaN), same types."""
    if isinstance(want, tuple | list):
        assert len(got) == len(want)
        for g, w in zip(got, want):
            same(g, w)
        return
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want), strict=True)


def close(got, want, rtol: float = 1e-9, scale: float | None = None) -> None:
    """Equal to ``rtol``, atol 1e-12 of ``scale`` (default: the largest magnitude of ``want``;
    a residual that cancels its terms is compared at the terms' scale)."""
    w = np.asarray(want, dtype=float)
    if scale is None:
        scale = float(np.abs(w).max()) if w.size else 0.0
    np.testing.assert_allclose(np.asarray(got, dtype=float), w, rtol=rtol, atol=1e-12 * scale)


def _window(seed: int, size: int, n: int, k: int, read_only: bool):
    rng = np.random.default_rng(seed)
    frame = rng.normal(0.0, 1e-3, size)
    frame.setflags(write=not read_only)
    index = np.sort(rng.choice(size, n, replace=False)).astype(np.intp)
    at = rng.normal(0.0, 1e-3, n)
    jacobian = rng.normal(0.0, 1.0, (n, k))
    gain = np.linalg.pinv(jacobian)
    weight = rng.uniform(0.5, 2.0, n) * 1e6
    return frame, index, at, gain, jacobian, weight


def _state(rng: np.random.Generator, k: int) -> np.ndarray:
    """A tracker's state table (rows X .. DRIFT): positive variances, a correlation < 1."""
    s = np.empty((6, k))
    s[kernels.X] = rng.normal(0.0, 1.0, k)
    s[kernels.V] = rng.normal(0.0, 0.5, k)
    pxx, pvv = rng.uniform(1e-4, 1.0, k), rng.uniform(1e-4, 1.0, k)
    s[kernels.PXX], s[kernels.PVV] = pxx, pvv
    s[kernels.PXV] = rng.uniform(-0.9, 0.9, k) * np.sqrt(pxx * pvv)
    s[kernels.DRIFT] = rng.normal(0.0, 2.0, k)
    return s


def _constants(rng: np.random.Generator, k: int, with_state: bool = True) -> np.ndarray:
    c = np.empty((8, k))
    c[kernels.C_R] = rng.uniform(1e-4, 0.1, k)
    c[kernels.C_MOVING] = rng.integers(0, 2, k)
    c[kernels.C_POINT] = rng.normal(0.0, 1.0, k)
    c[kernels.C_SD1] = np.sqrt(c[kernels.C_R])
    c[kernels.C_LOW] = -rng.uniform(0.5, 3.0, k)
    c[kernels.C_HIGH] = rng.uniform(0.5, 3.0, k)
    c[kernels.C_LOG] = rng.integers(0, 2, k)
    c[kernels.C_LIN_SD] = rng.uniform(1e-3, 1.0, k) if with_state else np.nan
    return c


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), size=st.sampled_from([64, 256]), n=st.integers(6, 60),
       k=st.integers(4, 6), read_only=st.booleans())
def test_measure_window_equals_the_reference(seed, size, n, k, read_only) -> None:
    args = _window(seed, size, n, k, read_only)
    frame, index, at, gain, jacobian, weight = args
    (c1, dp1, e1), (c0, dp0, e0) = core.measure_window(*args), REF["measure_window"](*args)
    terms = float(np.abs(frame[index] - at).max())  # e is d less its fit: cancels to ~0 at n = k
    close(dp1, dp0, scale=float(np.abs(gain).max()) * terms)
    close(e1, e0, scale=terms)
    # chi2 = sum(e^2 weight) of each one's own residual (that residual compared above)
    assert c1 == pytest.approx(float(np.sum(e1 * e1 * weight)), rel=1e-12, abs=1e-300)
    assert c0 == pytest.approx(float(np.sum(e0 * e0 * weight)), rel=1e-12, abs=1e-300)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 40), nan=st.booleans())
def test_largest_excess_equals_the_reference(seed, n, nan) -> None:
    rng = np.random.default_rng(seed)
    frame = rng.normal(0.0, 1.0, 64)
    if nan:
        frame[rng.integers(64, size=3)] = np.nan
    index = rng.choice(64, n, replace=False).astype(np.intp)
    expected = rng.normal(0.0, 1.0, n)
    same(core.largest_excess(frame, index, expected), REF["largest_excess"](frame, index, expected))


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 50), frames=st.integers(1, 30),
       fade=st.floats(0.5, 1.0), least=st.floats(0.5, 40.0))
def test_fold_residuals_equals_the_reference(seed, n, frames, fade, least) -> None:
    rng = np.random.default_rng(seed)
    total0, count0 = rng.normal(0.0, 1e-3, 64), rng.uniform(0.0, 50.0, 64)
    index = rng.choice(64, n, replace=False).astype(np.intp)
    buffered0 = rng.normal(0.0, 1e-3, n)
    outs = []
    for kernel in (core.fold_residuals, REF["fold_residuals"]):
        total, count, buffered = total0.copy(), count0.copy(), buffered0.copy()
        r = kernel(total, count, index, buffered, float(frames), fade, least)
        outs.append((r, total, count, buffered))
    same(outs[0], outs[1])


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(4, 6), with_state=st.booleans(),
       zero_scale=st.floats(0.0, 2.0))
def test_linearization_constants_equal_the_reference(seed, k, with_state, zero_scale) -> None:
    rng = np.random.default_rng(seed)
    a = rng.normal(0.0, 1.0, (k, k))
    cov = a @ a.T + 0.1 * np.eye(k)
    p = rng.normal(0.0, 1.0, k)
    s = _state(rng, k) if with_state else np.zeros((6, 0))
    systematic = rng.normal(0.0, 1e-3, (k, k)) * rng.integers(0, 2)
    table = _constants(rng, k)
    same(core.linearization_constants(table, cov, p, s, systematic, zero_scale),
         REF["linearization_constants"](table, cov, p, s, systematic, zero_scale))


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(4, 6), limit=st.floats(1.0, 1e4),
       step=st.sampled_from([1e-3, 0.3, 3.0]))
def test_measure_point_equals_the_reference(seed, k, limit, step) -> None:
    frame, index, at, gain, jacobian, weight = _window(seed, 64, 30, k, True)
    rng = np.random.default_rng(seed + 1)
    at = at + (jacobian @ rng.normal(0.0, step, k)) * 1e-3  # a step the window measures
    const = _constants(rng, k)
    args = (frame, index, at, gain, jacobian, weight, const, limit, k - 3, 5.0, 1.5)
    (ok1, z1, e1), (ok0, z0, e0) = core.measure_point(*args), REF["measure_point"](*args)
    assert ok1 == ok0
    close(z1, z0, scale=float(np.abs(z0).max()) + float(np.abs(gain).max()) * 1e-3)
    close(e1, e0, scale=float(np.abs(frame[index] - at).max()))


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(4, 6), dt=st.floats(1e-4, 0.1),
       fitted=st.booleans(), reset_sigma=st.sampled_from([1.0, 5.0, 1e3]),
       drift_limit=st.sampled_from([0.5, 3.0, 1e3]))
def test_filter_frame_equals_the_reference(seed, k, dt, fitted, reset_sigma, drift_limit) -> None:
    rng = np.random.default_rng(seed)
    s0, const = _state(rng, k), _constants(rng, k)
    z = s0[kernels.X] + rng.normal(0.0, 1.0, k)
    outs = []
    for kernel in (core.filter_frame, REF["filter_frame"]):
        s = s0.copy()
        r = kernel(z, s, const, dt, 36.0 * dt, dt * dt, fitted, reset_sigma, 0.1, drift_limit)
        outs.append((r, s))
    assert type(outs[0][0]) is int and outs[0][0] == outs[1][0]
    same(outs[0][1], outs[1][1])


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(4, 6), sigmas=st.floats(0.1, 10.0),
       sharpen=st.floats(1.0, 5.0), with_state=st.booleans())
def test_moved_from_point_equals_the_reference(seed, k, sigmas, sharpen, with_state) -> None:
    rng = np.random.default_rng(seed)
    s, const = _state(rng, k), _constants(rng, k, with_state)
    assert core.moved_from_point(s, const, sigmas, sharpen) == REF["moved_from_point"](
        s, const, sigmas, sharpen)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), model=st.sampled_from(["cylinder", "sphere", "general"]),
       dt=st.sampled_from([0.0, 1e-3, 0.05]), excess=st.floats(0.5, 4.0), has_sys=st.booleans(),
       beta=st.sampled_from([0.0, 0.5, 1.0, 1.7, -2.0]))
def test_estimate_numbers_equal_the_reference(seed, model, dt, excess, has_sys, beta) -> None:
    rng = np.random.default_rng(seed)
    k = {"cylinder": 5, "sphere": 4, "general": 6}[model]
    s, const = _state(rng, k), _constants(rng, k)
    if model == "general":
        s[kernels.X, 1], s[kernels.V, 1] = beta, 0.0
    a = rng.normal(0.0, 1.0, (k, k))
    cov = a @ a.T + 0.1 * np.eye(k)
    sd = np.sqrt(np.diag(cov))
    corr = cov / np.outer(sd, sd)
    sys = rng.normal(0.0, 1e-3, (k, k))
    # (a drift detector's weight of 1/32, as the tracker's, and of 1/2: a held parameter's
    # lag is corrected for the frames it has gathered, both ways)
    args = (kernels.MODEL_CODES[model], s, const, dt, excess, corr, sys, has_sys, 0.5,
            float(rng.choice([1.0 / 32.0, 0.5])))
    got, want = core.estimate_numbers(*args), REF["estimate_numbers"](*args)
    same(got, want)
    assert type(got[3]) is int


def test_a_zero_variance_raises_as_the_reference_does() -> None:
    """A float division by zero raises ZeroDivisionError in both (never a silent inf)."""
    k = 4
    s, const = np.zeros((6, k)), np.zeros((8, k))
    for kernel in (core.filter_frame, REF["filter_frame"]):
        with pytest.raises(ZeroDivisionError):
            kernel(np.zeros(k), s.copy(), const, 0.01, 1.0, 1e-4, False, 5.0, 0.1, 3.0)


def test_bad_arguments_are_refused_not_read_out_of_bounds() -> None:
    """An index beyond the frame, a state table of the wrong dtype (its writes would go to a
    copy), or shapes that disagree: a clear error, never a read or write outside an array."""
    frame, index, at, gain, jacobian, weight = _window(1, 64, 20, 5, False)
    bad = index.copy()
    bad[3] = 64
    with pytest.raises(IndexError):
        core.measure_window(frame, bad, at, gain, jacobian, weight)
    with pytest.raises(IndexError):
        core.largest_excess(frame, -index - 1, at)
    with pytest.raises(ValueError):
        core.measure_window(frame, index, at[:-1], gain, jacobian, weight)
    rng = np.random.default_rng(2)
    s, const = _state(rng, 5), _constants(rng, 5)
    with pytest.raises(TypeError, match="s:"):
        core.filter_frame(np.zeros(5), s.astype(np.float32), const, 0.01, 1.0, 1e-4, False, 5.0,
                          0.1, 3.0)
    with pytest.raises(ValueError):
        core.filter_frame(np.zeros(4), s, const, 0.01, 1.0, 1e-4, False, 5.0, 0.1, 3.0)
    with pytest.raises(ValueError):
        core.estimate_numbers(2, s, const, 0.0, 1.0, np.eye(5), np.eye(5), False, 0.5, 0.03)


# --- the line's band, the half-space -----------------------------------------------------------

@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), rows=st.integers(1, 20), cols=st.integers(1, 20),
       holes=st.floats(0.0, 0.3), threshold=st.floats(-0.5, 1.0))
def test_ridge_band_equals_the_reference(seed, rows, cols, holes, threshold) -> None:
    rng = np.random.default_rng(seed)
    clean = rng.normal(0.0, 1.0, (rows, cols))
    ok = rng.random((rows, cols)) >= holes
    m, n = int(rng.integers(rows)), int(rng.integers(cols))
    same(core.ridge_band(clean, ok, m, n, threshold),
         linewindow.REFERENCE["ridge_band"](clean, ok, m, n, threshold))


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), points=st.integers(1, 40), nodes=st.integers(1, 60),
       sets=st.integers(1, 3), z=st.floats(0.2, 5.0), nu=st.floats(0.0, 0.5))
def test_green_weighted_equals_the_reference(seed, points, nodes, sets, z, nu) -> None:
    rng = np.random.default_rng(seed)
    px, py = rng.uniform(0, 10, points), rng.uniform(0, 10, points)
    ox, oy = rng.uniform(0, 10, nodes), rng.uniform(0, 10, nodes)
    weights = rng.normal(0.0, 1.0, (sets, 3, nodes))
    g = halfspace.shear_modulus(1.0, nu)
    got = core.green_weighted(px, py, ox, oy, weights, z, g, nu)
    want = halfspace.REFERENCE["green_weighted"](px, py, ox, oy, weights, z, g, nu)
    assert got.shape == want.shape == (sets, 3, 3, points)
    np.testing.assert_allclose(got, want, rtol=1e-11, atol=1e-14 * float(np.abs(want).max()))


def test_the_green_sum_of_one_unit_force_is_green_itself() -> None:
    """An independent check of both: one node, a unit force along each axis in turn, gives
    :func:`halfspace.green` at each point (Johnson 1985, eqs. 3.19 and 3.86)."""
    px, py = np.array([0.3, 1.0, -2.0]), np.array([0.0, 0.7, 1.5])
    weights = np.eye(3)[:, :, None]  # set j: a unit force along axis j
    want = halfspace.green(px - 0.25, py + 0.5, 1.2, 0.4, 0.45)  # (3, 3, points)
    for fn in (core.green_weighted, halfspace.REFERENCE["green_weighted"]):
        got = fn(px, py, np.array([0.25]), np.array([-0.5]), weights, 1.2, 0.4, 0.45)
        for j in range(3):
            np.testing.assert_allclose(got[j, :, j], want[:, j], rtol=1e-13)

"""The core's one-call tracked frame (core/track_step.cpp, ``TrackStep``) against its Python
reference (``tactiled.pipeline.kernels.REFERENCE["TrackStep"]``), on hypothesis-drawn windows,
states and streams of frames.

The filters' step, the lag's running means and the rate's widening run in the reference on
numpy arrays element by element in the core's order: given the same measurement they are
bit-equal (``advance`` of a fit's own point, no residual).  The measurement goes through
``measure_window``, whose reference sums through numpy's BLAS (tests/native/
test_tracker_core.py): there the two agree to rtol 1e-9 of the terms, and a stream of
frames carries such differences through the filters, so a stream is compared to 1e-8 (the
filters' gains are below 1: they do not grow a difference).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactiled import native
from tactiled.pipeline import kernels
from test_tracker_core import _constants, _state, _window

pytestmark = pytest.mark.skipif(native.core is None, reason="TACTILED_CORE=python: no core to compare")
core = native.core
REF = kernels.REFERENCE
SETTINGS = settings(max_examples=100, deadline=None)


MODEL_OF = {4: 1, 5: 0, 6: 2}  # sphere, cylinder, general: their parameter counts
#: each parameter's lagged value (VALUE_KEYS index) as the tracker gives it: ..., ln_f, x0, y0
LAG_KEYS = {4: [-1, 2, 0, 1], 5: [-1, 5, 2, 0, 1], 6: [-1, -1, 5, 2, 0, 1]}


def _constants_of(k: int, limit: float, beta: int, has_sys: bool = True) -> tuple[float, ...]:
    """TRACK_CONSTANTS: the tracker's own (contact_filter) but the drawn limit and floor."""
    return (limit, k - 3, 5.0, 3.0, beta, -1.0 if beta >= 0 else 1.0, 0.1, 30.0, 1.0 / 32.0,
            0.87, 0.5, 2.0, 0.25, MODEL_OF[k], float(has_sys), 0.5)


def _covariances(rng: np.random.Generator, k: int) -> tuple[np.ndarray, np.ndarray]:
    a = rng.normal(0.0, 1.0, (k, k))
    cov = a @ a.T + 0.1 * np.eye(k)
    sd = np.sqrt(np.diag(cov))
    return cov / np.outer(sd, sd), rng.normal(0.0, 1e-3, (k, k))


def _pair(seed: int, k: int, limit: float, beta: int):
    """The same tracker's arrays twice (core, reference) and the window's frame."""
    frame, index, at, gain, jacobian, weight = _window(seed, 64, 30, k, True)
    rng = np.random.default_rng(seed + 7)
    s, c = _state(rng, k), _constants(rng, k)
    c[kernels.C_LOW], c[kernels.C_HIGH] = -50.0, 50.0
    c[kernels.C_LOG] = 0.0
    lag = np.abs(rng.normal(0.0, 1.0, (2, k)))
    corr, sys = _covariances(rng, k)
    keys = np.array(LAG_KEYS[k], dtype=np.intp)
    out = []
    for make in (core.TrackStep, REF["TrackStep"]):
        arrays = (s.copy(), lag.copy(), c.copy(), np.zeros(k), np.zeros(index.size))
        out.append((make(*arrays, index, at, gain, jacobian, weight, corr, sys, keys,
                         _constants_of(k, limit, beta)), arrays))
    return out, (frame, index, at, gain, jacobian, weight), rng


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(4, 6), dt=st.floats(1e-4, 0.3))
def test_advance_of_a_point_equals_the_reference_bit_for_bit(seed, k, dt) -> None:
    """A fit's own point (no residual) through the filters: the same answer (updated, a jump's
    mask, a restart past the gap) and the same arrays, bit for bit."""
    (one, a1), (ref, a0) = _pair(seed, k, 1e9, -1)[0]
    rng = np.random.default_rng(seed)
    z = a0[0][kernels.X] + rng.normal(0.0, 1.0, k)
    one.z[:] = z
    ref.z[:] = z
    got, want = one.advance(dt, True), ref.advance(dt, True)
    assert type(got) is int and got == want
    for g, w in zip(a1, a0):
        np.testing.assert_array_equal(g, w, strict=True)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(4, 6), frames=st.integers(1, 30),
       limit=st.sampled_from([1e-3, 1e9]), beta=st.sampled_from([-1, 1]),
       gap=st.booleans())
def test_a_stream_of_frames_equals_the_reference(seed, k, frames, limit, beta, gap) -> None:
    """Frames measured through the window, one call each (``step``): the same answer every
    frame, the same state, lag, measurement and buffered residuals to 1e-8."""
    pair, (frame, index, at, gain, jacobian, weight), rng = _pair(seed, k, limit, beta)
    (one, a1), (ref, a0) = pair
    for i in range(frames):
        # a frame the window measures near the point, with noise; now and then a gap
        f = frame.copy()
        f[index] = at + jacobian @ rng.normal(0.0, 0.05, k) + rng.normal(0.0, 1e-4, index.size)
        dt = 0.5 if gap and i % 7 == 3 else 1e-3
        got, want = one.step(f, dt), ref.step(f, dt)
        assert got == want, f"frame {i}"
        for g, w in zip(a1, a0):
            scale = float(np.nanmax(np.abs(w))) if w.size else 0.0
            np.testing.assert_allclose(g, w, rtol=1e-8, atol=1e-12 * max(scale, 1e-300))
    (v1, var1, rf1, ab1), (v0, var0, rf0, ab0) = one.estimate(0.0, 1.5), ref.estimate(0.0, 1.5)
    assert ab1 == ab0 and type(ab1) is int and type(v1) is list
    np.testing.assert_allclose(v1, v0, rtol=1e-8)
    np.testing.assert_allclose(var1, var0, rtol=1e-8)
    np.testing.assert_allclose(rf1, rf0, rtol=1e-8)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(4, 6), dt=st.sampled_from([0.0, 1e-3, 0.05]),
       excess=st.floats(0.5, 4.0), lagged=st.booleans())
def test_the_estimate_equals_the_reference_bit_for_bit(seed, k, dt, excess, lagged) -> None:
    """The same state and lag: the same numbers, variances (each moving value's lag in its
    unit added where it is significant), covariance and absent values, bit for bit."""
    pair, _, rng = _pair(seed, k, 1e9, -1)
    (one, a1), (ref, a0) = pair
    if lagged:  # running means well beyond their noise: every moving value lags
        for lag in (a1[1], a0[1]):
            lag[0] = 10.0 * np.sqrt(lag[1] + 1.0)
    got, want = one.estimate(dt, excess), ref.estimate(dt, excess)
    assert type(got[0]) is list and type(got[3]) is int
    np.testing.assert_array_equal(np.array(got[0]), np.array(want[0]), strict=True)
    np.testing.assert_array_equal(np.array(got[1]), np.array(want[1]), strict=True)
    assert got[2] == want[2] or (math.isnan(got[2]) and math.isnan(want[2]))
    assert got[3] == want[3]
    if lagged:  # the lag is there: the variances differ from the numbers without it
        plain = kernels.estimate_numbers(MODEL_OF[k], a0[0], a0[2], dt, excess,
                                         ref.corr, ref.sys, True, 0.5, 1.0 / 32.0)[1]
        assert np.nansum(np.array(want[1])) > np.nansum(plain)


def test_bad_arrays_are_refused_not_read_out_of_bounds() -> None:
    """A state of the wrong dtype (its writes would go to a copy), shapes that disagree, an
    index beyond the frame: a clear error, never a read or write outside an array."""
    frame, index, at, gain, jacobian, weight = _window(3, 64, 20, 5, False)
    rng = np.random.default_rng(3)
    s, c = _state(rng, 5), _constants(rng, 5)
    corr, sys = _covariances(rng, 5)
    good = (s, np.zeros((2, 5)), c, np.zeros(5), np.zeros(20), index, at, gain, jacobian, weight,
            corr, sys, np.array(LAG_KEYS[5], dtype=np.intp), _constants_of(5, 1e9, -1))
    with pytest.raises(TypeError, match="s:"):
        core.TrackStep(s.astype(np.float32), *good[1:])
    with pytest.raises(ValueError, match="lag"):
        core.TrackStep(s, np.zeros((2, 4)), *good[2:])
    with pytest.raises(ValueError, match="constants"):
        core.TrackStep(*good[:-1], good[-1][:-1])
    with pytest.raises(ValueError, match="lag_key"):
        core.TrackStep(*good[:-2], np.array([0, 0, 0, 0, 9], dtype=np.intp), good[-1])
    with pytest.raises(ValueError, match="corr"):
        core.TrackStep(*good[:10], np.eye(4), *good[11:])
    one = core.TrackStep(*good)
    with pytest.raises(IndexError):
        one.step(frame[:10], 1e-3)
    with pytest.raises(TypeError, match="frame"):
        one.step(frame.astype(np.float32), 1e-3)
    assert one.step(frame, math.nan) in (kernels.STEP_UNMEASURED, kernels.STEP_RESTART)

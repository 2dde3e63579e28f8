"""The core's calibration kernels (core/calibrate.cpp) against their NumPy reference
(tactiled.calibration.fused_reference): the same bits out, on hypothesis-drawn frames, tables,
baselines and hysteresis states, and frame after frame through a whole calibration stage on a
simulated finger (contacts, drift followed, hysteresis learnt)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactiled import _core
from tactiled.calibration import fused_reference as ref
from tactiled.calibration.detection import ContactDetector
from tactiled.calibration.fused import filter_bands
from tactiled.calibration.lut import LookupTable
from tactiled.sensors import load_description

SETTINGS = settings(max_examples=150, deadline=None)
SENSOR = load_description("fearing1988").sensor_model()
ROWS, COLS = SENSOR.geometry.rows, SENSOR.geometry.cols
N = ROWS * COLS
DETECTOR = ContactDetector(sensor=SENSOR)


def _table(seed: int) -> LookupTable:
    """A non-linear table per tactel (as tests/calibration/test_fused_stage.py draws them)."""
    rng = np.random.default_rng(seed)
    counts, strain = [], []
    for _ in range(N):
        c = np.array([0.0, 8000.0, 10000.0, 14000.0, 30000.0, 65535.0]) + rng.uniform(-50, 50, 6)
        gain = rng.uniform(0.9, 1.1) * (1.0 + np.array([0.0, 0.02, 0.0, -0.03, -0.08, -0.1]))
        counts.append(c)
        strain.append((c - 10000.0) / 20000.0 * gain)
    return LookupTable(ROWS, COLS, counts, strain)


def _same(a: object, b: object) -> None:
    """Equal to the bit (NaN where NaN), arrays and scalars alike."""
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b), strict=True)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), dtype=st.sampled_from([np.uint16, np.int64]),
       fraction=st.sampled_from([0.0, 0.03, 0.2]), decay=st.floats(0.5, 1.0),
       active=st.booleans(), spread=st.sampled_from([10.0, 3000.0, 30000.0]))
def test_zero_frame_equals_the_reference(seed: int, dtype: type, fraction: float, decay: float,
                                         active: bool, spread: float) -> None:
    rng = np.random.default_rng(seed)
    seg = _table(seed % 7)._forward
    raw = np.clip(10000 + rng.normal(0, spread, N), 0, 65535).astype(dtype)
    baseline = rng.normal(0.0, 1e-3, N)
    peak = np.abs(rng.normal(0.0, 0.05, N))
    sigma = 1e-3
    out = []
    for kernel in (ref.zero_frame, _core.zero_frame):
        pk = peak.copy()
        z, residual, tmap = np.empty(N), np.full(N, -7.0), np.empty(DETECTOR._total.size)
        r = kernel(raw, seg._offset, seg._breaks, seg._first, seg._params, baseline, pk,
                   fraction, decay, 5 * sigma, 2 * sigma, active, DETECTOR._ax, DETECTOR._ay_t,
                   DETECTOR._bands, z, residual, tmap)
        out.append((r, pk, z, residual, tmap))
    (r0, *a0), (r1, *a1) = out
    assert r0 == r1 and isinstance(r1[0], int)
    for x, y in zip(a0, a1):
        _same(x, y)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), average=st.integers(1, 5), frames=st.integers(1, 12))
def test_average_maps_equals_the_reference(seed: int, average: int, frames: int) -> None:
    p = 20
    state = []
    for kernel in (ref.average_maps, _core.average_maps):
        ring, total = np.zeros((average, p)), np.zeros(p)
        count = head = 0
        stats = []
        maps = np.random.default_rng(seed).normal(0, 1e-3, (frames, p))
        for tmap in maps:
            count, head, stat = kernel(ring, total, tmap, count, head)
            stats.append((count, head, stat))
        state.append((stats, ring, total))
    assert state[0][0] == state[1][0]
    _same(state[0][1], state[1][1])
    _same(state[0][2], state[1][2])


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), weight=st.floats(1e-4, 1.0), clip=st.booleans(),
       scale=st.sampled_from([1e-4, 1e-2]))
def test_follow_baseline_equals_the_reference(seed: int, weight: float, clip: bool,
                                              scale: float) -> None:
    rng = np.random.default_rng(seed)
    z0, b0 = rng.normal(0, scale, N), rng.normal(0, 1e-3, N)
    outs = []
    for kernel in (ref.follow_baseline, _core.follow_baseline):
        z, b = z0.copy(), b0.copy()
        kernel(b, z, weight, 1e-3, clip)
        outs.append((z, b))
    _same(outs[0][0], outs[1][0])
    _same(outs[0][1], outs[1][1])


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), nan=st.booleans())
def test_drift_kernels_equal_the_reference(seed: int, nan: bool) -> None:
    rng = np.random.default_rng(seed)
    zeroed, predicted = rng.normal(0, 1e-3, N), rng.normal(0, 1e-3, N)
    if nan:
        zeroed[rng.integers(N)] = np.nan
    inside = rng.random(N) < 0.4
    inside[0], inside[1] = True, False
    baseline0 = rng.normal(0, 1e-3, N)
    outs = []
    for err_k, pull_k in ((ref.drift_error, ref.pull_baseline),
                          (_core.drift_error, _core.pull_baseline)):
        error, baseline = np.empty(N), baseline0.copy()
        r = err_k(zeroed, predicted, inside, error)
        pull_k(baseline, error, inside, 1e-3, 0.01, N - r[0])
        outs.append((r, error, baseline))
    assert outs[0][0][0] == outs[1][0][0] and outs[0][0][2] == outs[1][0][2]
    _same(outs[0][0][1], outs[1][0][1])
    _same(outs[0][1], outs[1][1])
    _same(outs[0][2], outs[1][2])


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), dt=st.sampled_from([0.0, 0.01, 0.3]))
def test_learn_hysteresis_equals_the_reference(seed: int, dt: float) -> None:
    rng = np.random.default_rng(seed)
    taus = np.geomspace(0.1, 5.0, 10)
    peaks0 = np.abs(rng.normal(0, 0.02, (10, N)))
    predicted, unexplained = rng.normal(0.005, 0.01, N), rng.normal(0, 1e-3, N)
    outside = rng.random(N) < 0.7
    normal0, moment0 = rng.normal(0, 1, (10, 3, 3)), rng.normal(0, 1, (10, 3))
    outs = []
    for kernel in (ref.learn_hysteresis, _core.learn_hysteresis):
        peaks, normal, moment = peaks0.copy(), normal0.copy(), moment0.copy()
        r = kernel(peaks, taus, dt, predicted, unexplained, outside, 0.005, normal, moment, 0.999)
        outs.append((r, peaks, normal, moment))
    assert outs[0][0] == outs[1][0]
    for x, y in zip(outs[0][1:], outs[1][1:]):
        _same(x, y)


def test_an_output_array_of_the_wrong_kind_is_refused_not_copied() -> None:
    """The kernels write in place: a float32 or read-only output would be written to a copy
    the caller never sees, so it is refused naming the argument."""
    b = np.zeros(N, dtype=np.float32)
    with pytest.raises(TypeError, match="baseline"):
        _core.follow_baseline(b, np.zeros(N), 0.5, 1.0, False)
    frozen = np.zeros(N)
    frozen.setflags(write=False)
    with pytest.raises(ValueError, match="read-only"):
        _core.follow_baseline(frozen, np.zeros(N), 0.5, 1.0, False)
    with pytest.raises(ValueError, match="values"):
        _core.follow_baseline(np.zeros(N), np.zeros(N - 1), 0.5, 1.0, False)


def test_an_input_of_another_layout_is_read_for_its_values() -> None:
    """Inputs the core only reads may come in any layout (a strided view): it reads their
    values (the reference, given them contiguous, gives the same bits)."""
    rng = np.random.default_rng(3)
    error = rng.normal(0, 1e-3, 2 * N)[::2]  # strided
    assert not error.flags.c_contiguous
    inside = np.zeros(N, dtype=bool)
    inside[: N // 2] = True
    outs = []
    for kernel, e in ((ref.pull_baseline, np.ascontiguousarray(error)),
                      (_core.pull_baseline, error)):
        baseline = np.zeros(N)
        kernel(baseline, e, inside, 1e-3, 0.5, N - N // 2)
        outs.append(baseline)
    _same(outs[0], outs[1])


def test_the_bands_are_the_filters_own() -> None:
    """(The inputs above are the detector's: its bands come from its matrices.)"""
    _same(filter_bands(DETECTOR._ax, DETECTOR._ay_t), DETECTOR._bands)

"""Lookup tables: linearisation against np.interp, extrapolation, inverse, monotonicity."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactiled.calibration import LookupTable
from tactiled.errors import CalibrationError


def _reference(counts_knots, strain_knots, x):
    """Independent per-tactel evaluation: np.interp inside, end-segment lines outside."""
    c, s = counts_knots, strain_knots
    y = np.interp(x, c, s)
    lo, hi = x < c[0], x > c[-1]
    y[lo] = s[0] + (s[1] - s[0]) / (c[1] - c[0]) * (x[lo] - c[0])
    y[hi] = s[-1] + (s[-1] - s[-2]) / (c[-1] - c[-2]) * (x[hi] - c[-1])
    return y


def test_linearisation_matches_np_interp_per_tactel(random_knots):
    rng = np.random.default_rng(1)
    counts, strain = random_knots(rng, 64, knots=10)
    table = LookupTable(8, 8, counts, strain)
    raw = rng.integers(0, 1 << 16, (500, 8, 8), dtype=np.uint16)
    got = table.to_strain(raw)
    assert got.dtype == np.float64 and got.shape == raw.shape
    for k in range(64):
        m, n = divmod(k, 8)
        x = raw[:, m, n].astype(float)
        inside = (x >= counts[k][0]) & (x <= counts[k][-1])
        np.testing.assert_allclose(got[:, m, n][inside],
                                   np.interp(x[inside], counts[k], strain[k]), rtol=0, atol=1e-12)
        np.testing.assert_allclose(got[:, m, n], _reference(counts[k], strain[k], x),
                                   rtol=0, atol=1e-12)


def test_single_frame_equals_batch_and_accepts_other_dtypes(random_knots):
    rng = np.random.default_rng(2)
    table = LookupTable(8, 8, *random_knots(rng, 64))
    raw = rng.integers(0, 1 << 16, (20, 8, 8), dtype=np.uint16)
    batch = table.to_strain(raw)
    for i in range(raw.shape[0]):
        np.testing.assert_array_equal(table.to_strain(raw[i]), batch[i])
        np.testing.assert_array_equal(table(raw[i].astype(np.int64)), batch[i])
        np.testing.assert_array_equal(table(raw[i].tolist()), batch[i])


def test_knots_map_exactly_to_their_strain(random_knots):
    rng = np.random.default_rng(3)
    counts, strain = random_knots(rng, 4)
    table = LookupTable(2, 2, counts, strain)
    for k in range(4):
        for c, s in zip(counts[k], strain[k]):
            frame = np.array([cc[0] for cc in counts], dtype=float).reshape(2, 2)
            frame.flat[k] = c
            assert table.to_strain(frame).flat[k] == pytest.approx(s, abs=1e-15)


def test_extrapolates_linearly_beyond_end_knots():
    table = LookupTable(1, 1, [[1000.0, 2000.0, 3000.0]], [[0.0, 0.05, 0.08]])
    raw = np.array([[[0]], [[500]], [[4000]], [[65535]]], dtype=np.uint16)
    got = table.to_strain(raw).ravel()
    np.testing.assert_allclose(got, [-0.05, -0.025, 0.11, 0.08 + 0.03e-3 * 62535], atol=1e-14)


def test_linear_table_is_identity_like_and_inverts():
    table = LookupTable.linear(8, 8, counts_per_strain=20000.0, offset=10000.0, sensor_id=5)
    assert table.sensor_id == 5
    raw = np.arange(64, dtype=np.uint16).reshape(8, 8) * 1000
    np.testing.assert_allclose(table.to_strain(raw), (raw - 10000.0) / 20000.0, atol=1e-15)
    gains = np.linspace(1e4, 3e4, 64).reshape(8, 8)
    per_tactel = LookupTable.linear(8, 8, counts_per_strain=gains, offset=5000.0)
    np.testing.assert_allclose(per_tactel.to_strain(raw), (raw - 5000.0) / gains, atol=1e-15)
    with pytest.raises(ValueError, match="counts_per_strain"):
        LookupTable.linear(2, 2, counts_per_strain=0.0)


def test_inverse_round_trips_counts_and_strain(random_knots):
    rng = np.random.default_rng(4)
    counts, strain = random_knots(rng, 64)
    strain = [np.linspace(0, 0.1, len(c)) for c in counts]  # strictly increasing: exact inverse
    table = LookupTable(8, 8, counts, strain)
    raw = rng.integers(0, 1 << 16, (200, 8, 8), dtype=np.uint16)
    back = table.to_counts(table.to_strain(raw))
    assert back.dtype == np.uint16
    np.testing.assert_array_equal(back, raw)
    # strain -> counts -> strain: off by at most half a count times the local slope
    s = rng.uniform(-0.02, 0.12, (200, 8, 8))
    c = table.to_counts(s)
    inside = (c > 0) & (c < 65535)
    slope = np.max([np.max(np.diff(st) / np.diff(ct)) for ct, st in zip(counts, strain)])
    assert np.all(np.abs(table.to_strain(c) - s)[inside] <= 0.5 * slope + 1e-12)


def test_inverse_rounds_clips_and_handles_flat_runs():
    table = LookupTable(1, 2, [[0.0, 10.0, 20.0, 30.0], [100.0, 200.0]],
                        [[0.0, 1.0, 1.0, 2.0], [0.5, 0.5]])
    got = table.to_counts(np.array([[[0.5, 7.0]], [[1.0, 0.5]], [[1.5, -3.0]], [[1e9, 0.0]],
                                    [[-1e9, 0.0]]]))
    # flat run at strain 1 -> its upper end (20); flat tactel -> the middle of its knots
    np.testing.assert_array_equal(got[:, 0, 0], [5, 20, 25, 65535, 0])
    np.testing.assert_array_equal(got[:, 0, 1], [150] * 5)
    with pytest.raises(ValueError, match="finite"):
        table.to_counts(np.array([[np.nan, 0.0]]))


def test_nan_counts_give_nan_without_crashing():
    table = LookupTable.linear(2, 2)
    out = table.to_strain(np.array([[np.nan, 1e4], [np.inf, -np.inf]]))
    assert np.isnan(out[0, 0]) and out[0, 1] == pytest.approx(0.0, abs=1e-15)
    assert not np.any(np.isfinite(out[1]))


def test_shape_mismatch_is_a_value_error():
    table = LookupTable.linear(8, 8)
    with pytest.raises(ValueError, match=r"\(\.\.\., 8, 8\)"):
        table.to_strain(np.zeros((8, 7), np.uint16))
    with pytest.raises(ValueError, match="shape"):
        table.to_counts(np.zeros(64))


def test_constructor_refuses_bad_knots_naming_the_tactel():
    c, s = [[0.0, 60000.0]] * 4, [[0.0, 0.1]] * 4
    with pytest.raises(CalibrationError, match=r"tactel \[1, 0\] \(index 2\): 'counts' knots must "
                                               r"be strictly increasing"):
        LookupTable(2, 2, c[:2] + [[1.0, 1.0]] + c[3:], s)
    with pytest.raises(CalibrationError, match=r"tactel \[0, 1\] .*'strain' knots must be "
                                               r"non-decreasing"):
        LookupTable(2, 2, c, [s[0], [0.1, 0.05], s[0], s[0]])
    with pytest.raises(CalibrationError, match="need 4 tactels"):
        LookupTable(2, 2, c[:3], s[:3])
    with pytest.raises(CalibrationError, match=r"tactel \[0, 0\] .*'counts' knot 1 .* outside"):
        LookupTable(2, 2, [[0.0, 2e5]] + c[1:], s)
    with pytest.raises(CalibrationError, match=r"tactel \[1, 1\] .*reaches strain .*too close"):
        LookupTable(2, 2, c[:3] + [[0.0, 1e-9]], s)
    with pytest.raises(CalibrationError, match=r"tactel \[0, 0\] .*'strain' knot 1 is not finite"):
        LookupTable(2, 2, c, [[0.0, np.nan]] + s[1:])
    with pytest.raises(CalibrationError, match="unknown flag 'broken'"):
        LookupTable(2, 2, c, s, flags=[(), ("broken",), (), ()])


@st.composite
def tables(draw):
    rows = draw(st.integers(1, 4))
    cols = draw(st.integers(1, 4))
    counts, strain = [], []
    for _ in range(rows * cols):
        k = draw(st.integers(2, 7))
        start = draw(st.floats(-1000.0, 40000.0))
        gaps = draw(st.lists(st.floats(0.5, 15000.0), min_size=k - 1, max_size=k - 1))
        steps = draw(st.lists(st.one_of(st.just(0.0), st.floats(0.0, 0.02)),
                              min_size=k - 1, max_size=k - 1))
        s0 = draw(st.floats(-1.0, 1.0))
        counts.append(start + np.concatenate(([0.0], np.cumsum(gaps))))
        strain.append(s0 + np.concatenate(([0.0], np.cumsum(steps))))
    return LookupTable(rows, cols, counts, strain)


@settings(max_examples=60, deadline=None)
@given(table=tables(), seed=st.integers(0, 2**32 - 1))
def test_output_is_non_decreasing_in_counts_for_every_tactel(table, seed):
    rng = np.random.default_rng(seed)
    # Every knot (and its neighbours) plus random counts, sorted, fed to all tactels at once.
    knot_counts = np.concatenate([table.knots(m, n)[0] for m in range(table.rows)
                                  for n in range(table.cols)])
    probes = np.concatenate([knot_counts, np.nextafter(knot_counts, -np.inf),
                             np.nextafter(knot_counts, np.inf), rng.uniform(0, 65535, 300),
                             [0.0, 65535.0]])
    probes = np.sort(probes[(probes >= 0) & (probes <= 65535)])
    frames = np.broadcast_to(probes[:, None, None], (probes.size,) + table.shape)
    out = table.to_strain(frames)
    assert np.all(np.diff(out, axis=0) >= 0.0)
    ints = np.arange(0, 65536, 97, dtype=np.uint16)
    out = table.to_strain(np.broadcast_to(ints[:, None, None], (ints.size,) + table.shape))
    assert np.all(np.diff(out, axis=0) >= 0.0)

"""The table builder: recovery of a known nonlinear response, flags, press-file validation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled.calibration import PressSet, build_table, synthesize_presses
from tactiled.io.presses import load_presses, save_presses
from tactiled.errors import CalibrationError



def _tolerance(truth, presses: PressSet, knots: int, s_max: float) -> np.ndarray:
    """Per-tactel bound on |table(counts(s)) - s| over 0 <= s <= s_max, in strain.

    Two parts, both converted from counts to strain by the smallest local gain ``g_min``:
    * bias: a straight segment of length ``d`` in strain against the quadratic response
      ``c0 + g s + h s^2`` deviates by at most ``|h| d^2 / 4`` counts (the interpolation error,
      ``max|f''| d^2 / 8`` with ``f'' = 2h``); a least-squares segment by no more;
    * noise: each knot value averages about ``N / (K - 1)`` presses of noise ``sigma_c``; allow
      5 standard errors with a factor 2 for the hat basis' variance inflation.
    """
    n = len(presses)
    d = s_max / (knots - 1)
    g_min = np.minimum(truth.slope(0.0), truth.slope(s_max))
    bias = np.abs(truth.h) * d * d / 4.0
    noise = 5.0 * 2.0 * truth.noise_counts / math.sqrt(n / (knots - 1))
    return (bias + noise) / g_min


@pytest.mark.parametrize("knots", [6, 8, 11])
def test_recovers_a_known_nonlinear_response(synthetic, knots):
    presses, truth = synthetic
    report = build_table(presses, knots=knots)
    assert not report.flagged.any()
    s = np.linspace(0.0, 0.1, 101)[:, None, None] * np.ones(presses.shape)
    err = np.abs(report.table.to_strain(truth.counts(s)) - s).max(axis=0)
    tol = _tolerance(truth, presses, knots, 0.1)
    assert np.all(err <= tol), f"worst error/tolerance {np.max(err / tol):.2f}"
    # with 11 levels and 11 knots the knots sit on the levels: the bias part is all that is left
    # beyond noise, and the typical error is well inside the bound
    assert np.median(err / tol) < 0.5
    # RMS residual is the count noise seen through the local gain (0.5 .. 1.2 sigma_c / g_min)
    sigma_s = truth.noise_counts / np.minimum(truth.slope(0.0), truth.slope(0.1))
    ratio = report.rms_residual / sigma_s
    assert np.all((ratio > 0.4) & (ratio < 1.5))
    assert report.table.sensor_id == presses.sensor_id
    np.testing.assert_array_equal(report.table.rms_residual, report.rms_residual)


def test_levels_become_knots_when_few(synthetic):
    presses, _ = synthetic
    report = build_table(presses, knots=16)
    np.testing.assert_array_equal(report.knots, 11)  # 11 distinct plate levels
    c, s = report.table.knots(0, 0)
    np.testing.assert_allclose(s, np.linspace(0.0, 0.1, 11), atol=1e-15)


def test_flags_dead_and_non_monotone_tactels(synthetic_faulty):
    presses, truth = synthetic_faulty
    report = build_table(presses)
    assert np.argwhere(report.dead).tolist() == [[2, 5]]
    assert np.argwhere(report.non_monotone).tolist() == [[6, 6]]
    assert not report.unexercised.any()
    assert report.violation[6, 6] > 0.3 and report.violation[report.flagged == 0].max() < 0.01
    table = report.table
    assert table.flags[2 * 8 + 5] == ("dead",) and table.flags[6 * 8 + 6] == ("non-monotone",)
    # a dead tactel reads 0 whatever the counts: it can never raise a false contact
    np.testing.assert_array_equal(table.to_strain(presses.counts)[:, 2, 5], 0.0)
    assert table.dead_mask[2, 5] and table.dead_mask.sum() == 1
    text = report.format()
    assert "D" in text.splitlines()[5] and "N" in text.splitlines()[9]
    assert "dead: 1 ([2, 5]); non-monotone: 1 ([6, 6]); unexercised: 0" in text


def test_flags_unexercised_tactels():
    field = np.ones((4, 4))
    field[0, 0] = 0.01  # the reference strain there spans only 0.001
    presses, _ = synthesize_presses(4, 4, field_shape=field, seed=3)
    report = build_table(presses)
    assert np.argwhere(report.unexercised).tolist() == [[0, 0]]
    assert report.table.flags[0] == ("unexercised",)
    assert not report.dead.any()


def test_all_tactels_unexercised_is_an_error():
    presses, _ = synthesize_presses(2, 2, levels=[0.0, 0.001], seed=1)
    with pytest.raises(CalibrationError, match="do not exercise the sensor"):
        build_table(presses)


def test_sensor_id_must_be_known_and_consistent(synthetic):
    presses, _ = synthetic
    anonymous = PressSet(presses.counts, presses.strain_ref, None)
    with pytest.raises(CalibrationError, match="no 'sensor_id'; give one with --sensor-id"):
        build_table(anonymous)
    assert build_table(anonymous, sensor_id=9).table.sensor_id == 9
    with pytest.raises(CalibrationError, match="recorded from sensor 1, not 2"):
        build_table(presses, sensor_id=2)
    with pytest.raises(ValueError, match="knots"):
        build_table(presses, knots=1)


def test_press_file_round_trip(synthetic, tmp_path):
    presses, _ = synthetic
    loaded = load_presses(save_presses(presses, tmp_path / "p.npz"))
    np.testing.assert_array_equal(loaded.counts, presses.counts)
    np.testing.assert_array_equal(loaded.strain_ref, presses.strain_ref)
    assert loaded.sensor_id == presses.sensor_id


@pytest.mark.parametrize(
    ("arrays", "message"),
    [
        ({"counts": np.zeros((3, 2, 2), np.uint16)}, r"missing array 'strain_ref'"),
        ({"counts": np.zeros((3, 2, 2), np.uint16), "strain_ref": np.zeros((3, 2, 3))},
         r"'strain_ref' shape \(3, 2, 3\) does not match 'counts' shape \(3, 2, 2\)"),
        ({"counts": np.zeros((3, 4), np.uint16), "strain_ref": np.zeros((3, 4))},
         r"'counts' must be \(N, rows, cols\)"),
        ({"counts": np.zeros((1, 2, 2), np.uint16), "strain_ref": np.zeros((1, 2, 2))},
         r"need at least 2 presses"),
        ({"counts": np.full((3, 2, 2), 70000), "strain_ref": np.zeros((3, 2, 2))},
         r"'counts' outside 0\.\.65535"),
        ({"counts": np.zeros((3, 2, 2)), "strain_ref": np.zeros((3, 2, 2))},
         r"'counts' must be integers"),
        ({"counts": np.zeros((3, 2, 2), np.uint16),
          "strain_ref": np.where(np.arange(12).reshape(3, 2, 2) == 7, np.nan, 0.0)},
         r"'strain_ref' is not finite at press 1, tactel \[1, 1\]"),
        ({"counts": np.zeros((3, 2, 2), np.uint16), "strain_ref": np.zeros((3, 2, 2)),
          "sensor_id": np.array([1, 2])}, r"'sensor_id' must be an integer scalar"),
    ],
)
def test_press_file_refusals(tmp_path, arrays, message):
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    with pytest.raises(CalibrationError, match=r"bad\.npz: " + message):
        load_presses(path)


def test_truncated_or_foreign_press_files(synthetic, tmp_path):
    good = save_presses(synthetic[0], tmp_path / "p.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(good[: len(good) // 2])
    with pytest.raises(CalibrationError, match=r"cut\.npz: not a complete \.npz press file .*truncated"):
        load_presses(tmp_path / "cut.npz")
    corrupt = bytearray(good)
    corrupt[len(good) // 2] ^= 0xFF  # a flipped byte inside an array: zip CRC mismatch
    (tmp_path / "flip.npz").write_bytes(bytes(corrupt))
    with pytest.raises(CalibrationError, match=r"flip\.npz: array '\w+' is corrupt"):
        load_presses(tmp_path / "flip.npz")
    (tmp_path / "x.npz").write_text("{}")
    with pytest.raises(CalibrationError, match=r"x\.npz: not an \.npz press file"):
        load_presses(tmp_path / "x.npz")
    with pytest.raises(CalibrationError, match=r"missing\.npz: no such file"):
        load_presses(tmp_path / "missing.npz")

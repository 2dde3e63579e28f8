"""The tracker's compiled kernels against the numpy arithmetic they replace."""

from __future__ import annotations

import numpy as np
import pytest

from tactiled.pipeline.kernels import largest_excess, measure_window


def _case(rng: np.random.Generator, size: int, n: int, k: int):
    frame = rng.normal(0.0, 1e-3, size)
    index = np.sort(rng.choice(size, n, replace=False)).astype(np.intp)
    at = rng.normal(0.0, 1e-3, n)
    jacobian = rng.normal(0.0, 1.0, (n, k))
    gain = np.linalg.pinv(jacobian)
    weight = rng.uniform(0.5, 2.0, n) * 1e6
    return frame, index, at, gain, jacobian, weight


@pytest.mark.parametrize("size,n,k", [(64, 25, 5), (256, 100, 6), (64, 8, 8)])
def test_measure_window_matches_numpy(size: int, n: int, k: int) -> None:
    rng = np.random.default_rng(size + n + k)
    for _ in range(20):
        frame, index, at, gain, jacobian, weight = _case(rng, size, n, k)
        d = frame[index] - at
        dp = gain @ d
        e = d - jacobian @ dp
        chi2 = float((e * e) @ weight)
        got_chi2, got_dp, got_e = measure_window(frame, index, at, gain, jacobian, weight)
        np.testing.assert_allclose(got_dp, dp, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(got_e, e, rtol=1e-9, atol=1e-15)
        assert got_chi2 == pytest.approx(chi2, rel=1e-9)


def test_measure_window_takes_read_only_frames_and_any_matrix_layout() -> None:
    """The pipeline's frames are read-only; a linearisation's matrices come back from a worker
    in whatever layout it pickled them."""
    rng = np.random.default_rng(3)
    frame, index, at, gain, jacobian, weight = _case(rng, 64, 30, 5)
    frame.flags.writeable = False
    expected = measure_window(frame.copy(), index, at, gain, jacobian, weight)
    got = measure_window(frame, index, at, np.asfortranarray(gain), jacobian.T.copy().T, weight)
    assert got[0] == pytest.approx(expected[0], rel=1e-12)
    np.testing.assert_allclose(got[1], expected[1], rtol=1e-12)
    np.testing.assert_allclose(got[2], expected[2], rtol=1e-12)


def test_measure_window_lets_nan_through_to_the_caller() -> None:
    """A NaN is the caller's to judge (Tracker.measure refuses a non-finite step): the kernel
    must not turn it into a number."""
    rng = np.random.default_rng(4)
    frame, index, at, gain, jacobian, weight = _case(rng, 64, 20, 5)
    frame[index[3]] = np.nan
    chi2, dp, _ = measure_window(frame, index, at, gain, jacobian, weight)
    assert np.isnan(chi2) and np.isnan(dp).all()


def test_largest_excess_matches_numpy() -> None:
    rng = np.random.default_rng(5)
    frame = rng.normal(size=256)
    frame.flags.writeable = False
    index = np.flatnonzero(rng.random(256) < 0.7).astype(np.intp)
    expected = rng.normal(size=index.size)
    assert largest_excess(frame, index, expected) == float((frame[index] - expected).max())
    assert largest_excess(frame, index[:0], expected[:0]) == -np.inf


def test_several_contacts_with_overlapping_windows_measure_as_the_plain_arithmetic() -> None:
    """ContactTrackers hands each filter its window less its own point's strain and the
    others' (moved to their states where windows overlap) through the kernel: the same
    measurement as the numpy arithmetic written out."""
    from tactiled.fit.linearize import Linearization, SeveralLinearizations
    from tactiled.pipeline.several import ContactTrackers
    from tactiled.pipeline.tracker import Tracker

    rng = np.random.default_rng(8)
    size, k = 64, 4
    lins = []
    for lo, centre in ((0, 2.0), (20, 6.0)):  # windows 0..39 and 20..59: 20 tactels shared
        index = np.arange(lo, lo + 40)
        jacobian = rng.normal(0.0, 1e-3, (40, k))
        lins.append(Linearization(
            model="sphere", p=np.array([1.0, 0.0, centre, centre]), index=index,
            strain=rng.normal(0.0, 1e-3, 40), jacobian=jacobian,
            gain=np.linalg.pinv(jacobian), weight=np.full(40, 1e6), cov=np.eye(k) * 1e-4,
            sigma=1e-3, systematic=np.zeros((k, k)),
            predicted=rng.normal(0.0, 1e-3, size).reshape(8, 8)))
    trackers = ContactTrackers(Tracker, gate_mm=3.0)
    base = {"contacts": [{"x_mm": 2.0, "y_mm": 2.0}, {"x_mm": 6.0, "y_mm": 6.0}]}
    assert trackers.adopt(SeveralLinearizations(tuple(lins)), 0.0, base)
    for i, tr in enumerate(trackers.trackers):  # each filter a little off its point
        tr.x = list(lins[i].p + rng.normal(0.0, 1e-2, k))
    frame = rng.normal(0.0, 1e-3, size)
    frame.flags.writeable = False
    for i, (tr, (index, at)) in enumerate(zip(trackers.trackers, trackers._windows(frame))):
        j = 1 - i
        other = lins[j]
        own = frame[lins[i].index] - other.predicted.ravel()[lins[i].index]
        _, mine, theirs = np.intersect1d(lins[i].index, other.index, return_indices=True)
        assert mine.size == 20
        own[mine] -= other.jacobian[theirs] @ (np.asarray(trackers.trackers[j].x) - other.p)
        d = own - lins[i].strain
        dp = lins[i].gain @ d
        _, got_dp, got_e = measure_window(frame, index, at, tr._gain, tr._jacobian,
                                          tr._weight)
        np.testing.assert_allclose(got_dp, dp, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(got_e, d - lins[i].jacobian @ dp, rtol=1e-9, atol=1e-15)


def test_fold_residuals_matches_numpy() -> None:
    from tactiled.pipeline.kernels import fold_residuals

    rng = np.random.default_rng(9)
    total, count = rng.normal(size=256), rng.uniform(0.0, 40.0, 256)
    index = np.sort(rng.choice(256, 60, replace=False)).astype(np.intp)
    buffered = rng.normal(size=60)
    t, c, b = total.copy(), count.copy(), buffered.copy()
    t *= 0.9
    c *= 0.9
    t[index] += b
    c[index] += 8.0
    used = c >= 16.0
    used_n, chi2 = fold_residuals(total, count, index, buffered, 8.0, 0.9, 16.0)
    np.testing.assert_allclose(total, t, rtol=1e-15)
    np.testing.assert_allclose(count, c, rtol=1e-15)
    assert not buffered.any()
    assert used_n == int(used.sum()) and 0 < used_n < 256
    assert chi2 == pytest.approx(float(np.sum(t[used] ** 2 / c[used])), rel=1e-12)

"""Pool-adjacent-violators against the min-max formula of isotonic regression."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactiled.calibration import isotonic_increasing


def _minmax(y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Independent reference: f_i = max_{j<=i} min_{k>=i} weighted mean of y[j..k]."""
    n = y.size
    out = np.empty(n)
    for i in range(n):
        out[i] = max(
            min(np.dot(w[j:k + 1], y[j:k + 1]) / w[j:k + 1].sum() for k in range(i, n))
            for j in range(i + 1)
        )
    return out


values = st.floats(-1e3, 1e3, allow_nan=False)


@settings(max_examples=150, deadline=None)
@given(data=st.lists(st.tuples(values, st.floats(0.01, 100.0)), min_size=1, max_size=12))
def test_matches_min_max_formula_and_is_monotone(data):
    y = np.array([d[0] for d in data])
    w = np.array([d[1] for d in data])
    f = isotonic_increasing(y, w)
    assert np.all(np.diff(f) >= 0)
    np.testing.assert_allclose(f, _minmax(y, w), rtol=1e-9, atol=1e-9)
    # the weighted mean is preserved (pooling only averages)
    assert np.dot(w, f) == pytest.approx(np.dot(w, y), rel=1e-9, abs=1e-6)


@given(st.lists(values, min_size=1, max_size=30))
def test_already_monotone_input_is_returned_unchanged(ys):
    y = np.sort(np.array(ys))
    np.testing.assert_array_equal(isotonic_increasing(y), y)


def test_known_example():
    np.testing.assert_allclose(isotonic_increasing([1, 3, 2, 4, 3.5, 5]),
                               [1, 2.5, 2.5, 3.75, 3.75, 5])
    np.testing.assert_allclose(isotonic_increasing([3, 2, 1], [1, 1, 2]), [1.75, 1.75, 1.75])


def test_rejects_bad_weights():
    with pytest.raises(ValueError, match="positive"):
        isotonic_increasing([1.0, 2.0], [1.0, 0.0])
    with pytest.raises(ValueError, match="shape"):
        isotonic_increasing([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="finite"):
        isotonic_increasing([1.0, np.nan])

"""The start table's exhaustive nearest-pattern lookup answers as scipy's k-d tree did (the
same rows in the same order, the same distances to the last bit), so the cold starts, and
with them every fit, are what they were."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tactiled.sensors.model import SensorModel
from tactiled.fit.start import _NEAREST, nearest, start_table


def test_nearest_matches_the_kd_tree() -> None:
    table = start_table(SensorModel()).features
    tree = cKDTree(table)
    rng = np.random.default_rng(7)
    n = 3000
    spread = rng.choice([1e-3, 1e-2, 0.1, 1.0], (n, 1))
    queries = table[rng.integers(0, len(table), n)] + rng.normal(0.0, 1.0, (n, table.shape[1])) * spread
    dist, near = tree.query(queries, k=_NEAREST)
    for q, d, i in zip(queries, dist, near):
        got_d, got_i = nearest(table, q, _NEAREST)
        np.testing.assert_array_equal(got_i, i)
        np.testing.assert_array_equal(got_d, d)


def test_nearest_reads_nan_as_zero_and_clips_infinities() -> None:
    table = start_table(SensorModel()).features
    q = table[100].copy()
    q[0], q[3] = np.nan, np.inf
    ref = q.copy()
    ref[0], ref[3] = 0.0, 1e6
    d, i = nearest(table, q, 5)
    d_ref, i_ref = cKDTree(table).query(ref, k=5)
    np.testing.assert_array_equal(i, i_ref)
    np.testing.assert_array_equal(d, d_ref)

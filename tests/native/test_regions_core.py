"""The core's pressed regions (core/regions.cpp ``watershed``) against their Python reference
(``tactiled.fit.regions.REFERENCE``): bit-equal on hypothesis-drawn frames of several bumps,
noise, unusable tactels and plateaus of equal strains (ties ranked alike), and the regions
``find_regions`` builds from either alike."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactiled import native
from tactiled.fit import regions

pytestmark = pytest.mark.skipif(native.core is None, reason="TACTILED_CORE=python: no core to compare")
core = native.core
REF = regions.REFERENCE["watershed"]
CONSTANTS = (regions.SUPPORT_Z, regions.SIGNIFICANT_Z, regions.SEPARATION_Z,
             regions.SEPARATION_SHARE, regions.ABSORBED_SHARE)


def _frame(seed: int, rows: int, cols: int, bumps: int, holes: float, steps: int) -> np.ndarray:
    """Gaussian bumps 10-80 noise sigmas high plus unit noise; with ``steps`` the strains
    rounded to that many levels (plateaus: equal heights); unusable tactels -inf."""
    rng = np.random.default_rng(seed)
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    s = rng.normal(0.0, 1.0, (rows, cols))
    for _ in range(bumps):
        m, n, w = rng.uniform(0, rows), rng.uniform(0, cols), rng.uniform(0.7, 3.0)
        s += rng.uniform(10.0, 80.0) * np.exp(-((r - m) ** 2 + (c - n) ** 2) / (2 * w * w))
    if steps:
        s = np.round(s * steps / max(float(s.max()), 1e-9)) * (float(s.max()) / steps)
    s[rng.random((rows, cols)) < holes] = -np.inf
    return s


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), rows=st.integers(1, 24), cols=st.integers(1, 24),
       bumps=st.integers(0, 5), holes=st.floats(0.0, 0.2), steps=st.sampled_from([0, 0, 6, 20]))
def test_watershed_equals_the_reference(seed, rows, cols, bumps, holes, steps) -> None:
    s = _frame(seed, rows, cols, bumps, holes, steps).ravel()
    got = core.watershed(s, rows, cols, 1.0, *CONSTANTS)
    want = REF(s, rows, cols, 1.0, *CONSTANTS)
    assert len(got) == len(want) == 5
    for g, w in zip(got, want):
        assert g.shape == w.shape
        np.testing.assert_array_equal(g, w)  # NaN saddles equal NaN


def test_find_regions_builds_the_same_regions_from_either(monkeypatch) -> None:
    """Three bumps, two merged by the cover (one absorbed maximum), one of its own: the
    regions, their tactels, saddles and absorbed maxima alike from the core and the
    reference."""
    r, c = np.meshgrid(np.arange(16), np.arange(16), indexing="ij")
    s = sum(h * np.exp(-((r - m) ** 2 + (c - n) ** 2) / 6.0)
            for h, m, n in ((60.0, 4, 4), (40.0, 4, 9), (50.0, 12, 11)))
    native_regions = regions.find_regions(s, 1.0)
    monkeypatch.setattr(regions, "watershed", REF)
    reference_regions = regions.find_regions(s, 1.0)
    assert len(native_regions) == 2
    assert native_regions[0].absorbed == 1 and native_regions[1].saddle is not None
    assert len(native_regions) == len(reference_regions)
    for a, b in zip(native_regions, reference_regions):
        assert (a.peak_idx, a.peak, a.absorbed, a.absorbed_at, a.saddle, a.members) == (
            b.peak_idx, b.peak, b.absorbed, b.absorbed_at, b.saddle, b.members)
        np.testing.assert_array_equal(a.tactels, b.tactels)

"""Shared fixtures for the calibration tests: synthetic press sets with a known response."""

from __future__ import annotations

import numpy as np
import pytest

from tactiled.calibration import PressSet, SyntheticResponse, synthesize_presses

#: Synthetic procedure used across tests: 11 uniform-plate levels 0..0.1 strain, 20 repeats.
NOISE_COUNTS = 10.0


@pytest.fixture(scope="session")
def synthetic() -> tuple[PressSet, SyntheticResponse]:
    """A clean 8x8 press set (no dead or folded tactels) and its true response."""
    return synthesize_presses(noise_counts=NOISE_COUNTS, seed=11)


@pytest.fixture(scope="session")
def synthetic_faulty() -> tuple[PressSet, SyntheticResponse]:
    """As :func:`synthetic` but tactel [2, 5] dead and [6, 6] folded (non-monotone)."""
    return synthesize_presses(noise_counts=NOISE_COUNTS, dead=((2, 5),), folded=((6, 6),), seed=12)


@pytest.fixture(scope="session")
def random_knots():
    """:func:`random_table_knots`."""
    return random_table_knots


def random_table_knots(rng: np.random.Generator, n: int, knots: int = 6):
    """Random valid knots for ``n`` tactels: counts strictly increasing in 2000..60000, strain
    non-decreasing with some flat runs."""
    counts, strain = [], []
    for _ in range(n):
        k = int(rng.integers(2, knots + 1))
        c = np.sort(rng.choice(np.arange(2000, 60000), k, replace=False)).astype(float)
        c += rng.uniform(0, 0.9, k)  # fractional knots, as the builder writes
        s = np.cumsum(rng.choice([0.0, 1.0], k, p=[0.2, 0.8]) * rng.uniform(0, 0.05, k))
        counts.append(c)
        strain.append(s - 0.01)
    return counts, strain

"""Shared fixtures for the calibration tests: synthetic press sets with a known response."""

from __future__ import annotations

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

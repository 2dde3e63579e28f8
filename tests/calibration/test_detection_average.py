"""The streaming detector's frame averaging (the daemon uses average=2)."""

import math

import numpy as np
import pytest

from tactiled.calibration.detection import ContactDetector
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel


def test_statistic_is_the_filter_of_the_mean_frame():
    rng = np.random.default_rng(0)
    det = ContactDetector(average=3, exit_fraction=1.0)
    frames = rng.normal(0, 0.0005, (5, 8, 8))
    for i, f in enumerate(frames):
        det.update(f)
        if i >= 2:
            expected = det.statistic(frames[i - 2:i + 1].mean(axis=0))
            assert det.last_statistic == pytest.approx(expected, rel=1e-12)


def test_threshold_scales_with_the_averaged_noise():
    one = ContactDetector(sigma=0.0005)
    four = ContactDetector(sigma=0.0005, average=4)
    assert four.enter_threshold == pytest.approx(one.enter_threshold / 2, rel=1e-12)


def test_false_contacts_stay_below_the_target_while_weak_contacts_are_held():
    rng = np.random.default_rng(7)
    det = ContactDetector(sigma=0.0005, average=2)
    noise = rng.normal(0, 0.0005, (60_000, 8, 8))
    false = sum(det.update(f) for f in noise)
    assert false <= 15  # 1e-4 per frame would be 6 expected; the bound is conservative
    weak = StrainModel().predict(Contact(7.0, math.inf, 90.0, 0.05, 11.5, 13.6))
    det.reset()
    held = [det.update(weak + rng.normal(0, 0.0005, (8, 8))) for _ in range(200)]
    assert sum(held[2:]) >= 0.99 * 198


def test_bad_average_is_refused():
    with pytest.raises(ValueError, match="average"):
        ContactDetector(average=0)

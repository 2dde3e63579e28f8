"""The hand scene: several contacts on one array at once, their strain the sum of each one's."""

from __future__ import annotations

import numpy as np
import pytest

from tactiled.physics.strain import predict_strain
from tactiled.sensors import load_description
from tactiled.sim import (HAND_DURATION_S, HAND_PARTS, MultiScene, Pose, SceneBuilder,
                          FingerSimulator, named_scene, render_sum)
from tactiled.physics.strain import StrainModel


def _sensor(description: str):
    return load_description(description).sensor_model()


@pytest.mark.parametrize("part", ["palm", "finger2"])
def test_a_hand_part_renders_the_sum_of_its_contacts(part: str) -> None:
    """Noise, drift and hysteresis off: each tick's strain is the sum of predict_strain of
    each true contact, computed here independently; the palm holds three contacts at once,
    the index finger two."""
    scene, description = HAND_PARTS[part]
    sensor = _sensor(description)
    sim = FingerSimulator(sensor, scene, noise=0.0, drift=None, hysteresis=None)
    most = 0
    checked = 0
    for k in range(0, sim.ticks_per_pass, 97):  # across the whole pass
        sim.next_index = k
        tick = sim.step()
        expected = np.zeros(sim.shape)
        for c in tick.contacts:
            expected += predict_strain(c, sensor)
        np.testing.assert_allclose(tick.physics, expected, rtol=1e-12, atol=1e-15)
        if tick.contacts:
            assert tick.contact == max(tick.contacts, key=lambda c: c.force)
            checked += 1
        else:
            assert tick.contact is None and not tick.physics.any()
        most = max(most, len(tick.contacts))
    assert most == (3 if part == "palm" else 2) and checked > 10


def test_render_sum_adds_what_render_gives_alone() -> None:
    sensor = _sensor("flat16")
    model = StrainModel(sensor)
    a = Pose(r1=6.0, r2=6.0, force=1.0, x0=10.0, y0=10.0).contact()
    b = Pose(r1=6.0, r2=6.0, force=2.0, x0=25.0, y0=20.0).contact()
    np.testing.assert_allclose(render_sum([a, b], model),
                               predict_strain(a, sensor) + predict_strain(b, sensor), rtol=1e-12)
    assert not render_sum([], model).any()


def test_every_part_of_the_hand_grasps_and_lets_go_together() -> None:
    """Six devices, one 4 s pass each: all free for the first 0.7 s (time to tare), all
    touching in the middle of the grasp, all free again after it."""
    for scene, description in HAND_PARTS.values():
        sc = named_scene(scene, _sensor(description).geometry)
        assert isinstance(sc, MultiScene) and sc.duration == pytest.approx(HAND_DURATION_S)
        assert sc.idle_spans()[0] == pytest.approx((0.0, 0.7))
        assert sc.contacts_at(0.5) == [] and sc.contacts_at(3.5) == []
        assert len(sc.contacts_at(2.0)) >= 1


def test_a_shorter_track_must_end_released() -> None:
    press = SceneBuilder(Pose(x0=5, y0=5)).idle(0.5).press(0.5, force=1.0).build()
    long = SceneBuilder(Pose(x0=15, y0=15)).idle(2.0).build()
    with pytest.raises(ValueError, match="track 0 ends at 1 s of 2 s still touching"):
        MultiScene([press, long])
    with pytest.raises(ValueError, match="needs at least one track"):
        MultiScene([])


def test_a_multi_contact_finger_is_deterministic_and_streams_counts() -> None:
    a = FingerSimulator(_sensor("flat16"), "hand-palm", seed=4)
    b = FingerSimulator(_sensor("flat16"), "hand-palm", seed=4)
    a.skip(1500)
    b.skip(1500)
    for _ in range(5):
        ta, tb = a.step(), b.step()
        assert np.array_equal(ta.counts, tb.counts) and ta.counts.shape == (16, 16)
        assert len(ta.contacts) >= 2

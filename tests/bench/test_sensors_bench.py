"""``tactiled bench --suite sensors``: a short run scores every kind of contact on a flat
array within loose bars, and a line's offset is scored along its own reported normal."""

from __future__ import annotations

import math

import pytest

from tactiled_bench import sensors
from tactiled.physics.contact import LineContact
from tactiled.sensors import load_description


def test_a_line_offset_is_scored_along_the_normal_of_the_angle_it_reports() -> None:
    centre = (10.0, 10.0)
    line = LineContact(5.0, 0.5, 0.1, 10.0, 11.0)  # 1 mm off the centre, at 0.5 deg
    truth = line.offset_from(*centre)
    assert truth == pytest.approx(math.cos(math.radians(0.5)), rel=1e-9)
    # an estimate at 0.4 deg: the same normal, the same sign
    assert sensors._offset_err(truth + 0.01, 0.4, truth, 0.5) == pytest.approx(0.01)
    # the same line reported at 179.6 deg (angles are modulo 180): its normal is turned, and
    # the offset it reports has the other sign; the error is still 0.01 mm, not 2 mm
    assert sensors._offset_err(-truth - 0.01, 179.6, truth, 0.5) == pytest.approx(-0.01)
    # with no reported angle the offset is compared as it is
    assert sensors._offset_err(truth, None, truth, 0.5) == 0.0


def test_a_short_run_on_a_flat_array_is_near_the_bound() -> None:
    s = sensors.score_description(load_description("xela_uskin_4x4"), contacts=3, draws=8, seed=5)
    for kind in sensors.KINDS:
        names = [n for n in s.seen if n.startswith(f"{kind}/")]
        assert names, kind
    for name in s.z:
        rms = s.rms_over_crb(name)
        assert rms is not None and 0.3 < rms < 2.5, (name, rms)
        assert s.coverage(name) >= 0.6, name
    assert sum(s.withheld.values()) <= 0.25 * sum(s.seen.values())
    assert len(s.fit_ms) == len(s.auto_ms) == 3 * 3 * 8

"""The calibration stage end to end: raw frames -> zeroed strain + contact flag."""

from __future__ import annotations

import numpy as np
import pytest

from tactiled.calibration import CalibrationStage, LookupTable
from tactiled.errors import CalibrationError
from tactiled.frames import Frame


def test_raw_frames_become_zeroed_strain_with_contact_flags():
    rng = np.random.default_rng(0)
    gains = rng.uniform(15000, 25000, (8, 8))
    offsets = rng.uniform(8000, 12000, (8, 8))
    table = LookupTable.linear(8, 8, counts_per_strain=gains, offset=offsets, sensor_id=3)
    stage = CalibrationStage(table)
    m, n = np.mgrid[0:8, 0:8]
    blob = 0.01 * np.exp(-((m - 4) ** 2 + (n - 3) ** 2) / 1.6)
    drift = 0.004  # the sensor's zero has moved since calibration: zeroing removes it
    flags, last = [], None
    for k in range(300):  # 100 Hz: 1 s idle, 1 s pressed, 1 s released
        strain = drift + rng.normal(0.0, 0.0005, (8, 8)) + (blob if 100 <= k < 200 else 0.0)
        frame = Frame(seq=k, device_time_us=k * 10_000, raw=table.to_counts(strain), sensor_id=3)
        flags.append(stage.process(frame))
        assert frame.strain is not None and frame.strain.shape == (8, 8)
        if k == 199:
            last = frame.strain
    assert not any(flags[30:100]) and all(flags[101:200]) and not any(flags[205:])
    assert last[4, 3] == pytest.approx(0.01, abs=0.002)  # drift removed, contact kept
    assert stage.in_contact is False
    with pytest.raises(CalibrationError, match="frame from sensor 4, but the calibration is for "
                                               "sensor 3"):
        stage.process(Frame(seq=0, device_time_us=0, raw=np.zeros((8, 8), np.uint16),
                            sensor_id=4))

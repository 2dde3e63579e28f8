"""The published records built by make_estimate / make_zeroed_frame are the dataclasses'
own: every field set, equal to the constructor's, frozen, and the same JSON."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from tactiled.pipeline.estimate import Estimate, ZeroedFrame, make_estimate, make_zeroed_frame


def test_make_estimate_is_the_constructors_estimate() -> None:
    fit = {"contact": True, "x_mm": 1.5, "contacts": []}
    made = make_estimate(sensor="f0", sensor_id=3, seq=7, device_time_us=7000, host_time=12.5,
                         gate="fit", fitted_seq=7, worker_ms=1.25, fit=fit)
    assert set(vars(made)) == {f.name for f in dataclasses.fields(Estimate)}
    built = Estimate(**{f.name: getattr(made, f.name) for f in dataclasses.fields(Estimate)})
    assert made == built
    assert made.to_json_dict() == built.to_json_dict()
    assert made.latency_ms == built.latency_ms and made.contact
    with pytest.raises(dataclasses.FrozenInstanceError):
        made.seq = 8  # type: ignore[misc]


def test_make_zeroed_frame_is_the_constructors_frame() -> None:
    strain = np.arange(64, dtype=float).reshape(8, 8) * 1e-5
    made = make_zeroed_frame(sensor="f0", sensor_id=3, seq=7, device_time_us=7000,
                             host_time=12.5, contact=True, statistic=2e-4, strain=strain)
    assert set(vars(made)) == {f.name for f in dataclasses.fields(ZeroedFrame)}
    built = ZeroedFrame("f0", 3, 7, 7000, 12.5, True, 2e-4, strain)
    assert repr(made) == repr(built)
    assert json.dumps(made.to_json_dict()) == json.dumps(built.to_json_dict())
    with pytest.raises(dataclasses.FrozenInstanceError):
        made.contact = False  # type: ignore[misc]

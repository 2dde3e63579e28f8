"""The published records built by make_estimate / zeroed_frame are the dataclasses'
own: every field set, equal to the constructor's, and the same JSON; an estimate is a slots
record whose JSON form is built once and shared, a zeroed frame a frozen dataclass."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from tactiled.pipeline.estimate import Estimate, ZeroedFrame, make_estimate, zeroed_frame


def test_make_estimate_is_the_constructors_estimate() -> None:
    fit = {"contact": True, "x_mm": 1.5, "contacts": []}
    made = make_estimate(sensor="f0", sensor_id=3, seq=7, device_time_us=7000, host_time=12.5,
                         gate="fit", fitted_seq=7, worker_ms=1.25, fit=fit, stamp=1.7e9)
    assert not hasattr(made, "__dict__")  # a slots record: no per-instance dict
    built = Estimate(**{f.name: getattr(made, f.name) for f in dataclasses.fields(Estimate)
                        if f.init})
    assert made == built
    assert made.to_json_dict() == built.to_json_dict()
    assert made.latency_ms == built.latency_ms and made.contact
    with pytest.raises(AttributeError):
        made.speed = 1.0  # type: ignore[attr-defined]  # (slots: no field of another name)


def test_the_json_form_is_built_once_and_to_json_dict_is_the_callers_own() -> None:
    fit = {"contact": True, "x_mm": 1.5, "std": {"x_mm": 0.1}}
    est = make_estimate(sensor="f0", sensor_id=3, seq=7, device_time_us=7000, host_time=12.5,
                        gate="fit", fitted_seq=7, worker_ms=1.25, fit=fit, stamp=math.nan)
    shared = est.json_dict
    assert est.json_dict is shared  # built once: every consumer reads this one
    assert list(shared)[:11] == ["type", "sensor", "sensor_id", "seq", "device_time_us",
                                 "host_time", "time", "latency_ms", "worker_ms", "gate",
                                 "fitted_seq"]
    assert shared["x_mm"] == 1.5 and shared["std"] is fit["std"]
    assert math.isfinite(shared["time"])  # no clock's stamp: the time it was published
    mine = est.to_json_dict()
    assert mine == shared and mine is not shared
    mine["x_mm"] = None  # the caller's own dict: the shared form is untouched
    assert est.json_dict["x_mm"] == 1.5
    assert json.loads(json.dumps(shared, allow_nan=False)) == shared


def test_zeroed_frame_is_the_constructors_frame() -> None:
    strain = np.arange(64, dtype=float).reshape(8, 8) * 1e-5
    made = zeroed_frame("f0", 3, 7, 7000, 12.5, True, 2e-4, strain)
    assert set(vars(made)) == {f.name for f in dataclasses.fields(ZeroedFrame)}
    built = ZeroedFrame("f0", 3, 7, 7000, 12.5, True, 2e-4, strain)
    assert repr(made) == repr(built)
    assert json.dumps(made.to_json_dict()) == json.dumps(built.to_json_dict())
    with pytest.raises(dataclasses.FrozenInstanceError):
        made.contact = False  # type: ignore[misc]

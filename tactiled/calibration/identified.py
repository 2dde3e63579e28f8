"""The identified finger model a version 2 calibration file carries, validated.

Written by ``tactiled calibrate --identify`` (:mod:`tactiled.calibration.identify`), read by the
daemon and ``tactiled fit --calibration``: the rubber's constants, the tactels' positions, the
model-error floor, each constant's 1-sigma bound and which were held at the paper's value.
A constant outside its physical range (:data:`~tactiled.sensors.model.COVER_RANGES`) is refused
at load, naming the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from tactiled.sensors.model import (
    COVER_KEYS,
    COVER_RANGES,
    IMPULSE_KEYS,
    MAX_POSITION_ERROR,
    Geometry,
    ImpulseResponse,
    Material,
    ModelError,
    NoiseModel,
    SensorModel,
    TactelPositions,
    cover_constants,
)
from tactiled.errors import CalibrationError



@dataclass(frozen=True)
class FingerModel:
    """A finger's identified model (see the module docstring)."""

    impulse: ImpulseResponse
    material: Material
    positions: TactelPositions = field(default_factory=TactelPositions)
    model_error: ModelError = field(default_factory=ModelError)
    sigma: dict[str, float | None] = field(default_factory=dict)
    held: dict[str, str] = field(default_factory=dict)
    identification: dict[str, Any] = field(default_factory=dict)

    def sensor_model(self, geometry: Geometry | None = None, noise: NoiseModel | None = None) -> SensorModel:
        """The :class:`SensorModel` of this finger on ``geometry`` with sensor ``noise``."""
        return SensorModel(geometry=geometry or Geometry(), impulse=self.impulse, material=self.material,
                           noise=noise or NoiseModel(), positions=self.positions,
                           model_error=self.model_error)

    def constants(self) -> dict[str, float]:
        """The rubber's constants by name (mm, ratios, N/mm^2)."""
        return cover_constants(self.impulse, self.material)

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready ``model`` object of a version 2 calibration file."""
        c = self.constants()
        pos = None
        if not self.positions.nominal:
            pos = {"ex": list(self.positions.ex), "ey": list(self.positions.ey)}
        return {
            "impulse": {k: c[k] for k in IMPULSE_KEYS},
            "modulus": c["modulus"],
            "sigma": {k: self.sigma.get(k) for k in COVER_KEYS},
            "held": dict(self.held),
            "model_error": {"strain": self.model_error.strain, "relative": self.model_error.relative},
            "positions_mm": pos,
            "identification": dict(self.identification),
        }

    @classmethod
    def from_dict(cls, doc: Any, tactels: int) -> FingerModel:
        """Validate a file's ``model`` object (``tactels`` = rows * cols); a
        :class:`CalibrationError` names the offending key."""
        if not isinstance(doc, dict):
            raise CalibrationError("key 'model' must be an object")
        imp = doc.get("impulse")
        if not isinstance(imp, dict):
            raise CalibrationError("key 'model.impulse' must be an object with depth_x, nu_x, depth_y, nu_y")
        vals: dict[str, float] = {}
        for k in IMPULSE_KEYS:
            vals[k] = _number(imp.get(k), f"model.impulse.{k}")
        vals["modulus"] = _number(doc.get("modulus"), "model.modulus")
        for k, v in vals.items():
            lo, hi = COVER_RANGES[k]
            if not lo <= v <= hi:
                key = f"model.impulse.{k}" if k in IMPULSE_KEYS else "model.modulus"
                raise CalibrationError(f"key {key!r} is {v!r}, outside its physical range {lo:g}..{hi:g}")
        me = doc.get("model_error", {"strain": 0.0, "relative": 0.0})
        if not isinstance(me, dict):
            raise CalibrationError("key 'model.model_error' must be an object with strain, relative")
        try:
            floor = ModelError(_number(me.get("strain", 0.0), "model.model_error.strain"),
                               _number(me.get("relative", 0.0), "model.model_error.relative"))
        except ValueError as err:
            raise CalibrationError(f"key 'model.model_error': {err}") from None
        positions = TactelPositions()
        pos = doc.get("positions_mm")
        if pos is not None:
            if not isinstance(pos, dict):
                raise CalibrationError("key 'model.positions_mm' must be an object with ex, ey (or null)")
            arrays = []
            for axis in ("ex", "ey"):
                arr = pos.get(axis)
                if not isinstance(arr, list) or len(arr) != tactels:
                    raise CalibrationError(f"key 'model.positions_mm.{axis}' must be a list of {tactels} numbers")
                vs = [_number(v, f"model.positions_mm.{axis}[{i}]") for i, v in enumerate(arr)]
                for i, v in enumerate(vs):
                    if abs(v) > MAX_POSITION_ERROR:
                        raise CalibrationError(f"key 'model.positions_mm.{axis}[{i}]' is {v!r}, beyond "
                                               f"+/-{MAX_POSITION_ERROR:g} mm of the nominal pitch")
                arrays.append(tuple(vs))
            positions = TactelPositions(arrays[0], arrays[1])
        sigma = doc.get("sigma", {})
        held = doc.get("held", {})
        if not isinstance(sigma, dict) or not isinstance(held, dict):
            raise CalibrationError("keys 'model.sigma' and 'model.held' must be objects")
        ident = doc.get("identification", {})
        return cls(
            impulse=ImpulseResponse(vals["depth_x"], vals["nu_x"], vals["depth_y"], vals["nu_y"]),
            material=Material(vals["modulus"]),
            positions=positions,
            model_error=floor,
            sigma={k: (None if sigma.get(k) is None else _number(sigma[k], f"model.sigma.{k}"))
                   for k in COVER_KEYS},
            held={str(k): str(v) for k, v in held.items()},
            identification=ident if isinstance(ident, dict) else {},
        )


def _number(v: Any, key: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise CalibrationError(f"key {key!r} must be a finite number, got {v!r}")
    return float(v)


def constants_report(sensor: SensorModel, model: FingerModel | None, source: str | None,
                     description: str = "fearing1988") -> dict[str, Any]:
    """What ``/v1/sensors`` says of a sensor's model: the constants in use and where they came
    from (``source``: the calibration file of an identified ``model``; else the sensor
    ``description``'s name, "paper" for the paper's finger)."""
    out: dict[str, Any] = {
        **cover_constants(sensor.impulse, sensor.material),
        "model_error": {"strain": sensor.model_error.strain, "relative": sensor.model_error.relative},
        "positions_identified": 0 if sensor.positions.nominal
        else sum(1 for x, y in zip(sensor.positions.ex, sensor.positions.ey) if x or y),
    }
    if model is None:
        out.update(source="paper" if description == "fearing1988" else f"description: {description}",
                   sigma=dict.fromkeys(COVER_KEYS), held={})
    else:
        out.update(source=f"identified: {source}", sigma={k: model.sigma.get(k) for k in COVER_KEYS},
                   held=dict(model.held))
    return out

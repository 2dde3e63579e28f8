"""The calibration file: a versioned JSON document holding one sensor's lookup tables.

``docs/reference/file-formats.md`` is the format's reference.
"""

# Format (``docs/reference/file-formats.md`` is the reference)::
#
#     {
#       "format": "tactiled-calibration",
#       "version": 1,
#       "sensor_id": 3,                      # integer 0..65535, the id the sensor sends in frames
#       "rows": 8, "cols": 8,
#       "created": "2024-05-01T12:00:00Z",   # ISO 8601, informational
#       "tactels": [                         # rows*cols entries, row-major: k = m*cols + n
#         {"index": [0, 0],                  # optional; if present must equal [m, n]
#          "counts": [9980.0, 10512.5, ...], # strictly increasing, raw counts
#          "strain": [0.0, 0.0251, ...],     # non-decreasing, same length (>= 2)
#          "flags": [],                      # optional: "dead", "non-monotone", "unexercised"
#          "rms_residual": 0.00049},         # optional: calibration residual in strain
#         ...
#       ],
#       "build": {...}                       # optional, informational: how the builder ran
#     }
#
# Version 2 (written by ``tactiled calibrate --identify``) adds the finger's identified model::
#
#       "version": 2,
#       "model": {
#         "impulse": {"depth_x": 5.0, "nu_x": 0.4, "depth_y": 6.6, "nu_y": 0.6},   # mm; ratios
#         "modulus": 0.32,                                   # N/mm^2
#         "sigma": {"depth_x": 0.002, ..., "modulus": 0.0003},  # 1-sigma bounds (null: held)
#         "held": {"nu_y": "why it was held at the paper's value"},
#         "model_error": {"strain": 0.0, "relative": 0.004},  # the model-error floor
#         "positions_mm": {"ex": [...], "ey": [...]},          # rows*cols each, or null
#         "identification": {...}                              # informational report
#       }
#
# Version 1 files keep working (the paper's model, nominal positions, no floor).
#
# The loader refuses anything else with a :class:`CalibrationError` naming the file and the key
# (and the tactel); it never returns a half-valid table.  Writing is atomic (temp file + rename)
# so a crash never leaves a truncated file where the daemon will look for it.

from __future__ import annotations

import datetime as _dt
import json
import math
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from tactiled.calibration.lut import LookupTable, tactel_label
from tactiled.calibration.identified import FingerModel
from tactiled.sensors.model import Geometry, NoiseModel, SensorModel
from tactiled.errors import CalibrationError
from tactiled.io.files import atomic_output, read_text

FORMAT = "tactiled-calibration"
VERSION = 1
#: The version a file with an identified model is written as; the loader reads both.
VERSION_MODEL = 2
VERSIONS = (VERSION, VERSION_MODEL)
_REQUIRED = ("format", "version", "sensor_id", "rows", "cols", "created", "tactels")


def utc_now() -> str:
    """The current UTC time as ``YYYY-MM-DDTHH:MM:SSZ`` (the ``created`` field)."""
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def table_to_dict(table: LookupTable, build: dict[str, Any] | None = None,
                  model: FingerModel | None = None) -> dict[str, Any]:
    """The JSON-ready document for ``table`` (``build``: optional builder metadata; ``model``:
    an identified finger model, which makes it a version 2 document)."""
    tactels = []
    for k in range(table.rows * table.cols):
        m, n = divmod(k, table.cols)
        counts, strain = table.knots(m, n)
        entry: dict[str, Any] = {
            "index": [m, n],
            "counts": [float(v) for v in counts],
            "strain": [float(v) for v in strain],
            "flags": list(table.flags[k]),
        }
        rms = float(table.rms_residual[m, n])
        if math.isfinite(rms):
            entry["rms_residual"] = rms
        tactels.append(entry)
    doc: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "sensor_id": table.sensor_id,
        "rows": table.rows,
        "cols": table.cols,
        "created": table.created or utc_now(),
        "tactels": tactels,
    }
    if build:
        doc["build"] = build
    if model is not None:
        doc["version"] = VERSION_MODEL
        doc["model"] = model.to_dict()
    return doc


def table_from_dict(doc: Any, source: str = "calibration") -> LookupTable:
    """Validate a parsed document and build its :class:`LookupTable`.

    ``source`` prefixes every error message (the file name when loading a file).
    """
    def fail(msg: str) -> CalibrationError:
        return CalibrationError(f"{source}: {msg}")

    if not isinstance(doc, dict):
        raise fail(f"top level must be a JSON object, got {type(doc).__name__}")
    for key in _REQUIRED:
        if key not in doc:
            raise fail(f"missing key {key!r}")
    if doc["format"] != FORMAT:
        raise fail(f"key 'format' is {doc['format']!r}, expected {FORMAT!r}")
    version = doc["version"]
    if not _is_int(version) or version not in VERSIONS:
        raise fail(f"key 'version' is {version!r}; this tactiled reads versions "
                   f"{', '.join(map(str, VERSIONS))}")
    for key in ("rows", "cols"):
        if not _is_int(doc[key]) or doc[key] < 1:
            raise fail(f"key {key!r} must be a positive integer, got {doc[key]!r}")
    sensor_id = doc["sensor_id"]
    if not _is_int(sensor_id) or not 0 <= sensor_id <= 0xFFFF:
        raise fail(f"key 'sensor_id' must be an integer 0..65535, got {sensor_id!r}")
    if not isinstance(doc["created"], str):
        raise fail(f"key 'created' must be a string, got {doc['created']!r}")
    rows, cols = doc["rows"], doc["cols"]
    tactels = doc["tactels"]
    if not isinstance(tactels, list):
        raise fail(f"key 'tactels' must be a list, got {type(tactels).__name__}")
    if len(tactels) != rows * cols:
        raise fail(
            f"key 'tactels' has {len(tactels)} entries, expected rows*cols = {rows}*{cols} "
            f"= {rows * cols}"
        )
    counts, strain, flags = [], [], []
    rms = np.full(rows * cols, np.nan)
    for k, entry in enumerate(tactels):
        label = tactel_label(k, cols)
        if not isinstance(entry, dict):
            raise fail(f"{label}: entry must be an object, got {type(entry).__name__}")
        for key in ("counts", "strain"):
            if key not in entry:
                raise fail(f"{label}: missing key {key!r}")
            if not isinstance(entry[key], list):
                raise fail(f"{label}: key {key!r} must be a list of numbers")
            if any(_is_bool(v) for v in entry[key]):
                raise fail(f"{label}: key {key!r} must hold numbers, not booleans")
        if "index" in entry and entry["index"] != [k // cols, k % cols]:
            raise fail(f"{label}: key 'index' is {entry['index']!r}, expected "
                       f"[{k // cols}, {k % cols}] (tactels are listed row-major)")
        f = entry.get("flags", [])
        if not (isinstance(f, list) and all(isinstance(x, str) for x in f)):
            raise fail(f"{label}: key 'flags' must be a list of strings")
        r = entry.get("rms_residual")
        if r is not None:
            if not isinstance(r, (int, float)) or _is_bool(r):
                raise fail(f"{label}: key 'rms_residual' must be a number, got {r!r}")
            rms[k] = float(r)
        counts.append(entry["counts"])
        strain.append(entry["strain"])
        flags.append(f)
    try:
        return LookupTable(rows, cols, counts, strain, sensor_id=sensor_id,
                           created=doc["created"], flags=flags, rms_residual=rms)
    except CalibrationError as err:
        raise fail(str(err)) from err


def dumps(doc: dict[str, Any]) -> str:
    """JSON text of a calibration document: top-level keys one per line, one line per tactel
    (diff-friendly and readable; floats in shortest round-trip form)."""
    head = {k: v for k, v in doc.items() if k != "tactels"}
    lines = [f" {json.dumps(k)}: {json.dumps(v, allow_nan=False)}," for k, v in head.items()]
    body = ",\n".join(f"  {json.dumps(t, allow_nan=False)}" for t in doc.get("tactels", []))
    return "{\n" + "\n".join(lines) + '\n "tactels": [\n' + body + "\n ]\n}\n"


def save_calibration(table: LookupTable, path: str | os.PathLike[str],
                     build: dict[str, Any] | None = None, model: FingerModel | None = None) -> Path:
    """Write ``table`` (and an identified ``model``: version 2) to ``path`` atomically;
    returns the path.  I/O failures raise :class:`CalibrationError`."""
    text = dumps(table_to_dict(table, build, model))
    with atomic_output(path, CalibrationError, "w") as fh:
        fh.write(text)
    return Path(path)


def load_calibration(
    path: str | os.PathLike[str],
    *,
    shape: tuple[int, int] | None = None,
    sensor_id: int | None = None,
) -> LookupTable:
    """Read and validate a calibration file; its lookup table (see :func:`load_calibration_file`
    for the identified model of a version 2 file too).

    ``shape`` / ``sensor_id``, when given, must match the file (the sensor this table is about to
    be used for); a mismatch is refused like any other defect.
    """
    return load_calibration_file(path, shape=shape, sensor_id=sensor_id).table


@dataclass(frozen=True)
class Calibration:
    """A calibration file's content: the lookup table, the identified finger model (None for a
    version 1 file: the paper's model) and the file it came from."""

    table: LookupTable
    model: FingerModel | None
    source: str

    def sensor_model(self, noise: NoiseModel | None = None, geometry: Geometry | None = None,
                     base: SensorModel | None = None) -> SensorModel:
        """The :class:`SensorModel` the fitter should use for this sensor, on the sensor's
        ``geometry`` (default: the nominal array; the caller checks the table fits it): the
        identified model's cover, or without one ``base``'s (a sensor description's; default
        the paper's)."""
        g = geometry or (base.geometry if base is not None else Geometry())
        if self.model is None:
            if base is not None:
                return replace(base, geometry=g, noise=noise or base.noise)
            return SensorModel(geometry=g, noise=noise or NoiseModel())
        return self.model.sensor_model(g, noise)


def load_calibration_file(
    path: str | os.PathLike[str],
    *,
    shape: tuple[int, int] | None = None,
    sensor_id: int | None = None,
) -> Calibration:
    """Read and validate a calibration file of either version (see :func:`load_calibration`)."""
    path = Path(path)
    text = read_text(path, "calibration file", CalibrationError)
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as err:
        # A complete calibration document ends with '}'; without one, say so first.
        hint = " (truncated?)" if not text.rstrip().endswith("}") else ""
        raise CalibrationError(
            f"{path}: not valid JSON{hint}: {err.msg} at line {err.lineno} column {err.colno}"
        ) from err
    table = table_from_dict(doc, source=str(path))
    model = None
    if doc.get("version") == VERSION_MODEL:
        if "model" not in doc:
            raise CalibrationError(f"{path}: missing key 'model' (version {VERSION_MODEL})")
        try:
            model = FingerModel.from_dict(doc["model"], table.rows * table.cols)
        except CalibrationError as err:
            raise CalibrationError(f"{path}: {err}") from err
    if shape is not None and table.shape != tuple(shape):
        raise CalibrationError(
            f"{path}: table shape {table.shape} (keys 'rows', 'cols') does not match the "
            f"sensor's {tuple(shape)}"
        )
    if sensor_id is not None and table.sensor_id != sensor_id:
        raise CalibrationError(
            f"{path}: key 'sensor_id' is {table.sensor_id}, but the sensor reports {sensor_id}"
        )
    return Calibration(table, model, str(path))


def _is_bool(v: Any) -> bool:
    return isinstance(v, bool)


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)

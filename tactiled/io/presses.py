"""The press file (``.npz``): a :class:`~tactiled.calibration.presses.PressSet` on disk.

* ``counts``: ``(N, rows, cols)`` integer raw counts in 0..65535 (stored as ``uint16``);
* ``strain_ref``: ``(N, rows, cols)`` float reference strain (positive under compression);
* ``contacts`` (for ``tactiled calibrate --identify``, in place of ``strain_ref``): ``(N, 6)``
  float, columns ``r1_mm, r2_mm (inf = cylinder), angle_deg, force_n, x_mm, y_mm``;
* ``sensor_id`` (optional): integer scalar, the sensor's id.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from tactiled.calibration.presses import PressSet, _checked, _checked_contacts
from tactiled.errors import CalibrationError
from tactiled.io.files import plain, read_npz, write_npz


def load_presses(path: str | os.PathLike[str]) -> PressSet:
    """Read and validate a press file; every defect raises :class:`CalibrationError`."""
    path = Path(path)
    data = read_npz(path, "press file", CalibrationError)
    has = ", ".join(data) or "none"
    if "counts" not in data:
        raise CalibrationError(f"{path}: missing array 'counts' (has: {has})")
    if "strain_ref" not in data and "contacts" not in data:
        raise CalibrationError(
            f"{path}: missing array 'strain_ref' (or 'contacts', for --identify) (has: {has})")
    counts = data["counts"]
    strain_ref = data.get("strain_ref")
    contacts = data.get("contacts")
    sid = data.get("sensor_id")
    sensor_id = None
    if sid is not None:
        if sid.shape != () or sid.dtype.kind not in "ui" or not 0 <= int(sid) <= 0xFFFF:
            raise CalibrationError(f"{path}: 'sensor_id' must be an integer scalar 0..65535, "
                                   f"got {plain(sid)}")
        sensor_id = int(sid)
    if strain_ref is not None:
        counts, strain_ref = _checked(counts, strain_ref, str(path))
    if contacts is not None:
        counts, contacts = _checked_contacts(counts, contacts, str(path))
    return PressSet(counts, strain_ref, sensor_id, contacts)


def save_presses(presses: PressSet, path: str | os.PathLike[str]) -> Path:
    """Write ``presses`` as an ``.npz`` (uncompressed, atomically, under the name given) and
    return the path."""
    arrays: dict[str, np.ndarray] = {"counts": presses.counts}
    if presses.strain_ref is not None:
        arrays["strain_ref"] = presses.strain_ref
    if presses.contacts is not None:
        arrays["contacts"] = presses.contacts
    if presses.sensor_id is not None:
        arrays["sensor_id"] = np.array(presses.sensor_id, dtype=np.int64)
    return write_npz(path, arrays, compressed=False, error=CalibrationError)

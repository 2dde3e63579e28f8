"""Frame files (.npz): the exchange format of ``tactiled fit`` and ``tactiled simulate``.

An .npz holding ``strain``, a float array ``(N, rows, cols)`` of linearised, zeroed strain
(positive under compression), and optionally the scalars ``dx``, ``dy`` (tactel pitch in mm).
``tactiled simulate`` also stores the true contact parameters per frame (``true_r1``,
``true_r2`` (inf for a cylinder), ``true_angle``, ``true_force``, ``true_x``, ``true_y``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tactiled.calibration.lut import LookupTable
from tactiled.errors import FrameError
from tactiled.io.files import plain, read_npz, write_npz


@dataclass
class FrameFile:
    strain: np.ndarray  # (N, rows, cols)
    dx: float | None = None
    dy: float | None = None
    extras: dict[str, np.ndarray] = field(default_factory=dict)


#: The optional scalars a frame file may hold: key -> (what it is, zero allowed).
SCALARS = {"dx": ("tactel pitch in mm", False), "dy": ("tactel pitch in mm", False),
           "noise_sigma": ("strain noise, 1 sigma", True),
           "noise_quantum": ("strain quantisation step", True)}


def _scalar(data: dict[str, np.ndarray], key: str, path: Path) -> float | None:
    if key not in data:
        return None
    what, zero = SCALARS[key]
    arr = data[key]
    if arr.size != 1 or not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise FrameError(f"{path}: '{key}' must be a single number ({what}), got {plain(arr)}")
    value = float(arr.reshape(()))
    if not (math.isfinite(value) and (value >= 0 if zero else value > 0)):
        sign = "non-negative" if zero else "positive"
        raise FrameError(f"{path}: '{key}' must be a {sign} number ({what}), got {plain(value)}")
    return value


def _extras(path: Path, data: dict[str, np.ndarray], *taken: str) -> dict[str, np.ndarray]:
    """The arrays beside the frames, the optional scalars among them checked."""
    for key in ("noise_sigma", "noise_quantum"):
        _scalar(data, key, path)
    return {k: v for k, v in data.items() if k not in (*taken, "dx", "dy")}


def load_frame_file(path: str | Path, allow_nonfinite: bool = False,
                    table: LookupTable | None = None) -> FrameFile:
    """Read and validate a frame file; :class:`FrameError` names the problem.

    With a lookup ``table`` (a calibration file's), the file may hold ``counts`` (N, rows,
    cols) raw readings in place of ``strain``: they are linearised by the table (strain 0 at
    the table's zero-load point), and an optional ``sensor_id`` must match the table's."""
    path = Path(path)
    data = read_npz(path, "frame file", FrameError)
    if "strain" not in data and "counts" in data and table is not None:
        return _counts_file(path, data, table)
    if "strain" not in data:
        hint = " ('counts' needs --calibration CAL.json)" if "counts" in data else ""
        found = ", ".join(sorted(data)) or "nothing"
        raise FrameError(f"{path}: missing array 'strain' (found: {found}){hint}")
    strain = data["strain"]
    if not np.issubdtype(strain.dtype, np.number) or np.iscomplexobj(strain):
        raise FrameError(f"{path}: 'strain' must be a real numeric array, got dtype {strain.dtype.name}")
    if strain.ndim != 3 or strain.shape[1] < 2 or strain.shape[2] < 2:
        raise FrameError(f"{path}: 'strain' must have shape (N, rows, cols) with rows, cols >= 2, "
                         f"got {plain(strain.shape)}")
    if strain.shape[0] < 1:
        raise FrameError(f"{path}: 'strain' holds no frames")
    strain = strain.astype(float)
    if not allow_nonfinite:
        bad = ~np.isfinite(strain)
        if bad.any():
            f, m, n = (int(i) for i in np.argwhere(bad)[0])
            raise FrameError(
                f"{path}: 'strain' has {int(bad.sum())} non-finite value(s), first at frame {f} "
                f"tactel [{m}, {n}] ({plain(strain[f, m, n])})"
            )
    extras = _extras(path, data, "strain")
    return FrameFile(strain, _scalar(data, "dx", path), _scalar(data, "dy", path), extras)


def save_frame_file(path: str | Path, strain: np.ndarray, dx: float, dy: float, **extras: np.ndarray) -> None:
    """Write a frame file (compressed, atomically, under the name given)."""
    write_npz(path, dict(strain=np.asarray(strain, dtype=float), dx=float(dx), dy=float(dy), **extras),
              error=FrameError)


def _counts_file(path: Path, data: dict[str, np.ndarray], table: LookupTable) -> FrameFile:
    """A frame file of raw ``counts``, linearised through ``table``."""
    counts = data["counts"]
    if counts.dtype.kind not in "ui":
        raise FrameError(f"{path}: 'counts' must be integer raw readings 0..65535, got dtype "
                         f"{counts.dtype.name}")
    if counts.ndim != 3 or counts.shape[1:] != table.shape or counts.shape[0] < 1:
        raise FrameError(f"{path}: 'counts' must have shape (N, {table.rows}, {table.cols}) (the "
                         f"calibration's array), got {plain(counts.shape)}")
    if counts.min() < 0 or counts.max() > 0xFFFF:
        raise FrameError(f"{path}: 'counts' outside 0..65535 (min {plain(counts.min())}, max "
                         f"{plain(counts.max())})")
    if "sensor_id" in data:
        sid = data["sensor_id"]
        if sid.shape != () or sid.dtype.kind not in "ui" or int(sid) != table.sensor_id:
            raise FrameError(f"{path}: 'sensor_id' is {plain(sid)}, but the calibration is for "
                             f"sensor {table.sensor_id}")
    strain = table.to_strain(counts.astype(np.float64))
    extras = _extras(path, data, "counts")
    return FrameFile(strain, _scalar(data, "dx", path), _scalar(data, "dy", path), extras)

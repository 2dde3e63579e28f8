"""Frame files (.npz): the exchange format of ``tactiled fit`` and ``tactiled simulate``.

An .npz holding ``strain``, a float array ``(N, rows, cols)`` of linearised, zeroed strain
(positive under compression), and optionally the scalars ``dx``, ``dy`` (tactel pitch in mm).
``tactiled simulate`` also stores the true contact parameters per frame (``true_r1``,
``true_r2`` (inf for a cylinder), ``true_angle``, ``true_force``, ``true_x``, ``true_y``).
"""

from __future__ import annotations

import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tactiled.calibration.lut import LookupTable
from tactiled.errors import FrameError


@dataclass
class FrameFile:
    strain: np.ndarray  # (N, rows, cols)
    dx: float | None = None
    dy: float | None = None
    extras: dict[str, np.ndarray] = field(default_factory=dict)


def _scalar(data, key: str, path: Path) -> float | None:
    if key not in data:
        return None
    arr = np.asarray(data[key])
    if arr.size != 1 or not np.issubdtype(arr.dtype, np.number):
        raise FrameError(f"{path}: '{key}' must be a single number (tactel pitch in mm), got shape {arr.shape}")
    value = float(arr.reshape(()))
    if not (math.isfinite(value) and value > 0):
        raise FrameError(f"{path}: '{key}' must be a positive pitch in mm, got {value!r}")
    return value


def load_frame_file(path: str | Path, allow_nonfinite: bool = False,
                    table: LookupTable | None = None) -> FrameFile:
    """Read and validate a frame file; :class:`FrameError` names the problem.

    With a lookup ``table`` (a calibration file's), the file may hold ``counts`` (N, rows,
    cols) raw readings in place of ``strain``: they are linearised by the table (strain 0 at
    the table's zero-load point), and an optional ``sensor_id`` must match the table's."""
    path = Path(path)
    try:
        data = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise FrameError(f"{path}: no such file") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        raise FrameError(f"{path}: not a readable .npz file ({err})") from err
    with data:
        if "strain" not in data and "counts" in data and table is not None:
            return _counts_file(path, data, table)
        if "strain" not in data:
            hint = " ('counts' needs --calibration CAL.json)" if "counts" in data else ""
            raise FrameError(f"{path}: missing array 'strain' (found: {sorted(data.files) or 'nothing'}){hint}")
        try:
            strain = np.asarray(data["strain"])
        except (ValueError, OSError, zipfile.BadZipFile) as err:
            raise FrameError(f"{path}: 'strain' cannot be read ({err})") from err
        if not np.issubdtype(strain.dtype, np.number) or np.iscomplexobj(strain):
            raise FrameError(f"{path}: 'strain' must be a real numeric array, got dtype {strain.dtype}")
        if strain.ndim != 3 or strain.shape[1] < 2 or strain.shape[2] < 2:
            raise FrameError(f"{path}: 'strain' must have shape (N, rows, cols) with rows, cols >= 2, got {strain.shape}")
        strain = strain.astype(float)
        if not allow_nonfinite:
            bad = ~np.isfinite(strain)
            if bad.any():
                f, m, n = (int(i) for i in np.argwhere(bad)[0])
                raise FrameError(
                    f"{path}: 'strain' has {int(bad.sum())} non-finite value(s), first at frame {f} "
                    f"tactel [{m}, {n}] ({strain[f, m, n]!r})"
                )
        extras = {k: np.asarray(data[k]) for k in data.files if k not in ("strain", "dx", "dy")}
        return FrameFile(strain, _scalar(data, "dx", path), _scalar(data, "dy", path), extras)


def save_frame_file(path: str | Path, strain: np.ndarray, dx: float, dy: float, **extras: np.ndarray) -> None:
    """Write a frame file (compressed)."""
    np.savez_compressed(Path(path), strain=np.asarray(strain, dtype=float), dx=float(dx), dy=float(dy), **extras)


def _counts_file(path: Path, data, table: LookupTable) -> FrameFile:
    """A frame file of raw ``counts``, linearised through ``table``."""
    try:
        counts = np.asarray(data["counts"])
    except (ValueError, OSError, zipfile.BadZipFile) as err:
        raise FrameError(f"{path}: 'counts' cannot be read ({err})") from err
    if counts.dtype.kind not in "ui":
        raise FrameError(f"{path}: 'counts' must be integer raw readings 0..65535, got dtype {counts.dtype}")
    if counts.ndim != 3 or counts.shape[1:] != table.shape:
        raise FrameError(f"{path}: 'counts' must have shape (N, {table.rows}, {table.cols}) (the "
                         f"calibration's array), got {counts.shape}")
    if counts.size and (counts.min() < 0 or counts.max() > 0xFFFF):
        raise FrameError(f"{path}: 'counts' outside 0..65535 (min {counts.min()}, max {counts.max()})")
    if "sensor_id" in data.files:
        sid = np.asarray(data["sensor_id"])
        if sid.shape != () or sid.dtype.kind not in "ui" or int(sid) != table.sensor_id:
            raise FrameError(f"{path}: 'sensor_id' is {sid!r}, but the calibration is for sensor "
                             f"{table.sensor_id}")
    strain = table.to_strain(counts.astype(np.float64))
    extras = {k: np.asarray(data[k]) for k in data.files if k not in ("counts", "dx", "dy")}
    return FrameFile(strain, _scalar(data, "dx", path), _scalar(data, "dy", path), extras)

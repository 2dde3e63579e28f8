"""Recorded calibration presses: the builder's input, its file, and a synthesiser for tests.

A press set is ``N`` frames of raw counts, each with the strain frame the lab's reference says
the sensor should read (``docs/calibration.md`` describes the procedure).  File: an ``.npz`` with

* ``counts``: ``(N, rows, cols)`` integer raw counts in 0..65535 (stored as ``uint16``);
* ``strain_ref``: ``(N, rows, cols)`` float reference strain (positive under compression);
* ``sensor_id`` (optional): integer scalar, the sensor's id.
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from tactiled.errors import CalibrationError


@dataclass
class PressSet:
    """``counts`` ``(N, rows, cols)`` uint16; ``strain_ref`` same shape float64; ``sensor_id``
    ``None`` when the recording did not say."""

    counts: np.ndarray
    strain_ref: np.ndarray
    sensor_id: int | None = None

    def __post_init__(self) -> None:
        self.counts, self.strain_ref = _checked(self.counts, self.strain_ref, "press set")

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.counts.shape[1]), int(self.counts.shape[2]))

    def __len__(self) -> int:
        return int(self.counts.shape[0])


def _checked(
    counts: ArrayLike, strain_ref: ArrayLike, source: str
) -> tuple[np.ndarray, np.ndarray]:
    c = np.asarray(counts)
    s = np.asarray(strain_ref)
    if c.ndim != 3:
        raise CalibrationError(f"{source}: 'counts' must be (N, rows, cols), got shape {c.shape}")
    if s.shape != c.shape:
        raise CalibrationError(
            f"{source}: 'strain_ref' shape {s.shape} does not match 'counts' shape {c.shape}"
        )
    if c.shape[0] < 2:
        raise CalibrationError(f"{source}: need at least 2 presses, got {c.shape[0]}")
    if c.dtype.kind not in "ui":
        raise CalibrationError(f"{source}: 'counts' must be integers (raw counts), got {c.dtype}")
    if c.size and (c.min() < 0 or c.max() > 0xFFFF):
        raise CalibrationError(
            f"{source}: 'counts' outside 0..65535 (min {c.min()}, max {c.max()})"
        )
    if s.dtype.kind not in "fiu":
        raise CalibrationError(f"{source}: 'strain_ref' must be numeric, got {s.dtype}")
    s = s.astype(np.float64)
    bad = np.argwhere(~np.isfinite(s))
    if bad.size:
        i, m, n = (int(v) for v in bad[0])
        raise CalibrationError(
            f"{source}: 'strain_ref' is not finite at press {i}, tactel [{m}, {n}] "
            f"({bad.shape[0]} non-finite values)"
        )
    return c.astype(np.uint16), s


def load_presses(path: str | os.PathLike[str]) -> PressSet:
    """Read and validate a press file; every defect raises :class:`CalibrationError`."""
    path = Path(path)
    if path.is_file() and not zipfile.is_zipfile(path):
        # np.load would guess "pickle" and say so, which misleads; say what is wrong instead.
        raise CalibrationError(f"{path}: not an .npz press file (no zip archive signature; "
                               "truncated, or another kind of file?)")
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in ("counts", "strain_ref") if k not in data.files]
            if missing:
                raise CalibrationError(
                    f"{path}: missing array {missing[0]!r} (has: {', '.join(data.files) or 'none'})"
                )
            counts = data["counts"]
            strain_ref = data["strain_ref"]
            sid = data["sensor_id"] if "sensor_id" in data.files else None
    except CalibrationError:
        raise
    except (FileNotFoundError, PermissionError, IsADirectoryError) as err:
        raise CalibrationError(f"cannot read press file {path}: {err.strerror}") from err
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as err:
        raise CalibrationError(f"{path}: not a readable .npz press file: {err}") from err
    sensor_id = None
    if sid is not None:
        if sid.shape != () or sid.dtype.kind not in "ui" or not 0 <= int(sid) <= 0xFFFF:
            raise CalibrationError(f"{path}: 'sensor_id' must be an integer scalar 0..65535, "
                                   f"got {sid!r}")
        sensor_id = int(sid)
    c, s = _checked(counts, strain_ref, str(path))
    return PressSet(c, s, sensor_id)


def save_presses(presses: PressSet, path: str | os.PathLike[str]) -> Path:
    """Write ``presses`` as an ``.npz`` (uncompressed) and return the path."""
    path = Path(path)
    arrays: dict[str, np.ndarray] = {"counts": presses.counts, "strain_ref": presses.strain_ref}
    if presses.sensor_id is not None:
        arrays["sensor_id"] = np.array(presses.sensor_id, dtype=np.int64)
    with open(path, "wb") as fh:  # a file object, so numpy does not append ".npz" to the name
        np.savez(fh, **arrays)
    return path


# --------------------------------------------------------------------------------------------
# Synthetic presses with a known true response (tests, docs, benchmarks)


@dataclass
class SyntheticResponse:
    """A known per-tactel response ``counts = c0 + g*s + h*s^2`` (plus Gaussian count noise).

    ``c0``, ``g``, ``h``: ``(rows, cols)`` arrays in counts, counts/strain, counts/strain^2.
    ``dead``/``folded``: boolean masks of tactels made dead (counts = c0 + noise) or
    non-monotone (``h = -g / s_max``: counts peak at half the strain range and fall back).
    """

    c0: np.ndarray
    g: np.ndarray
    h: np.ndarray
    noise_counts: float
    dead: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))
    folded: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))

    def counts(self, strain: np.ndarray) -> np.ndarray:
        """Noise-free counts (float) for ``strain`` of shape ``(..., rows, cols)``."""
        c = self.c0 + self.g * strain + self.h * strain**2
        return np.where(self.dead, self.c0 + 0.0 * strain, c)

    def strain(self, counts: np.ndarray) -> np.ndarray:
        """The true inverse (strain for noise-free ``counts``) on the rising branch."""
        d = np.asarray(counts, dtype=np.float64) - self.c0
        with np.errstate(invalid="ignore", divide="ignore"):
            disc = np.sqrt(np.maximum(self.g**2 + 4.0 * self.h * d, 0.0))
            quad = 2.0 * d / (self.g + disc)  # the stable root of h s^2 + g s - d = 0
        return quad

    def slope(self, strain: np.ndarray) -> np.ndarray:
        """``d counts / d strain`` at ``strain``."""
        return self.g + 2.0 * self.h * strain


def synthesize_presses(
    rows: int = 8,
    cols: int = 8,
    *,
    levels: ArrayLike | None = None,
    repeats: int = 20,
    offset: float = 10000.0,
    gain: float = 20000.0,
    quad: float = -40000.0,
    spread: float = 0.2,
    noise_counts: float = 10.0,
    dead: tuple[tuple[int, int], ...] = (),
    folded: tuple[tuple[int, int], ...] = (),
    field_shape: ArrayLike | None = None,
    sensor_id: int | None = 1,
    seed: int = 0,
) -> tuple[PressSet, SyntheticResponse]:
    """A press set from a uniform-plate procedure with a known nonlinear response.

    Each load level in ``levels`` (reference strain, default 0 .. 0.1 in 11 steps) is pressed
    ``repeats`` times; ``strain_ref = level * field_shape`` (default uniform, 1).  Per tactel,
    ``c0``, ``g``, ``h`` are the nominal ``offset``, ``gain``, ``quad`` times ``1 + U(-spread,
    spread)``; counts get ``N(0, noise_counts)`` noise, rounding and clipping to 0..65535.
    Returns the presses and the true response.
    """
    rng = np.random.default_rng(seed)
    lv = np.linspace(0.0, 0.1, 11) if levels is None else np.asarray(levels, dtype=np.float64)
    shape = (rows, cols)
    fs = np.ones(shape) if field_shape is None else np.broadcast_to(field_shape, shape)

    def jitter(nominal: float) -> np.ndarray:
        return nominal * (1.0 + rng.uniform(-spread, spread, shape))

    c0, g, h = jitter(offset), jitter(gain), jitter(quad)
    dead_mask = np.zeros(shape, bool)
    fold_mask = np.zeros(shape, bool)
    for m, n in dead:
        dead_mask[m, n] = True
    for m, n in folded:
        fold_mask[m, n] = True
    s_max = float(np.max(lv)) * float(np.max(fs)) or 1.0
    h = np.where(fold_mask, -g / s_max, h)
    truth = SyntheticResponse(c0, g, h, noise_counts, dead_mask, fold_mask)
    strain_ref = np.repeat(lv, repeats)[:, None, None] * fs[None, :, :]
    rng.shuffle(strain_ref, axis=0)  # presses in a random order, as a lab would randomise
    noisy = truth.counts(strain_ref) + rng.normal(0.0, noise_counts, strain_ref.shape)
    counts = np.clip(np.rint(noisy), 0, 0xFFFF).astype(np.uint16)
    return PressSet(counts, strain_ref, sensor_id), truth

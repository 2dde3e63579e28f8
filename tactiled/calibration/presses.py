"""Recorded calibration presses: the builder's input, checked, and a synthesiser for tests."""

# A press set is ``N`` frames of raw counts, each with the strain frame the lab's reference says
# the sensor should read (``docs/howto/calibration.md`` describes the procedure); its file is
# :mod:`tactiled.io.presses`.  A press set holds
#
# * ``counts``: ``(N, rows, cols)`` integer raw counts in 0..65535 (stored as ``uint16``);
# * ``strain_ref``: ``(N, rows, cols)`` float reference strain (positive under compression);
# * ``sensor_id`` (optional): integer scalar, the sensor's id.
#
# For identification (``tactiled calibrate --identify``) a press file may carry, in place of
# ``strain_ref``, the known contact of each press:
#
# * ``contacts``: ``(N, 6)`` float, columns ``r1_mm, r2_mm (inf = cylinder), angle_deg, force_n,
#   x_mm, y_mm``; a press with ``force_n`` 0 is unloaded (its other columns are ignored).

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from tactiled.sensors.model import Geometry
from tactiled.errors import CalibrationError
from tactiled.sensors.finger import FingerSpec


#: Columns of a press file's ``contacts`` array.
CONTACT_COLUMNS = ("r1_mm", "r2_mm", "angle_deg", "force_n", "x_mm", "y_mm")


@dataclass
class PressSet:
    """``counts`` ``(N, rows, cols)`` uint16; ``strain_ref`` same shape float64 (None when the
    presses carry ``contacts`` instead, ``(N, 6)``: see :data:`CONTACT_COLUMNS`);
    ``sensor_id`` ``None`` when the recording did not say."""

    counts: np.ndarray
    strain_ref: np.ndarray | None = None
    sensor_id: int | None = None
    contacts: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.strain_ref is None and self.contacts is None:
            raise CalibrationError("press set: needs 'strain_ref' or 'contacts'")
        if self.strain_ref is not None:
            self.counts, self.strain_ref = _checked(self.counts, self.strain_ref, "press set")
        if self.contacts is not None:
            self.counts, self.contacts = _checked_contacts(self.counts, self.contacts, "press set")

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


def _checked_contacts(counts: ArrayLike, contacts: ArrayLike, source: str) -> tuple[np.ndarray, np.ndarray]:
    """Validate the shapes and types of ``counts`` and ``contacts`` (the values' physics is
    checked by the identification, which knows the array)."""
    c = np.asarray(counts)
    k = np.asarray(contacts)
    if c.ndim != 3:
        raise CalibrationError(f"{source}: 'counts' must be (N, rows, cols), got shape {c.shape}")
    if c.dtype.kind not in "ui":
        raise CalibrationError(f"{source}: 'counts' must be integers (raw counts), got {c.dtype}")
    if c.size and (c.min() < 0 or c.max() > 0xFFFF):
        raise CalibrationError(f"{source}: 'counts' outside 0..65535 (min {c.min()}, max {c.max()})")
    if k.dtype.kind not in "fiu":
        raise CalibrationError(f"{source}: 'contacts' must be numeric, got {k.dtype}")
    if k.ndim != 2 or k.shape[1] != len(CONTACT_COLUMNS):
        raise CalibrationError(f"{source}: 'contacts' must be (N, {len(CONTACT_COLUMNS)}) "
                               f"({', '.join(CONTACT_COLUMNS)}), got shape {k.shape}")
    if k.shape[0] != c.shape[0]:
        raise CalibrationError(f"{source}: 'contacts' has {k.shape[0]} presses but 'counts' has "
                               f"{c.shape[0]}")
    return c.astype(np.uint16), k.astype(np.float64)


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


#: The indentors of the identification procedure (docs/howto/calibration.md): (r1, r2) in mm.
IDENTIFY_INDENTORS: tuple[tuple[float, float], ...] = (
    (3.0, 3.0), (6.0, 6.0), (4.0, math.inf), (10.0, math.inf), (2.0, math.inf))
#: ... on a flat array, where a cylinder is a line whose total force is not defined: spheres
#: and ellipsoids (the long axis's radius finite).
FLAT_IDENTIFY_INDENTORS: tuple[tuple[float, float], ...] = (
    (3.0, 3.0), (6.0, 6.0), (4.0, 12.0), (10.0, 30.0), (2.0, 8.0))


#: Cylinder orientations (deg) of the identification presses: away from the finger's axis,
#: where a cylinder's contact becomes a line longer than the finger (docs/concepts/model.md, limits).
CYLINDER_ANGLES = (30.0, 150.0)


def synthesize_contact_presses(
    finger: FingerSpec,
    n: int = 400,
    *,
    geometry: Geometry | None = None,
    indentors: tuple[tuple[float, float], ...] = IDENTIFY_INDENTORS,
    force_range: tuple[float, float] = (0.25, 2.0),
    unloaded_fraction: float = 0.1,
    frames_averaged: int = 32,
    noise_sigma: float = 0.0005,
    sensor_id: int | None = 1,
    seed: int = 0,
) -> PressSet:
    """Presses of known contacts on a simulated finger, as docs/howto/calibration.md's identification
    procedure records them: indentors from ``indentors`` (on a flat array, by default
    :data:`FLAT_IDENTIFY_INDENTORS`) at random orientations (spheres 0-180 deg, cylinders within
    :data:`CYLINDER_ANGLES`),
    forces uniform in ``force_range``, centres uniform over the array; a fraction unloaded; each
    press the mean of ``frames_averaged`` frames of strain noise ``noise_sigma``, rounded to
    integer counts through the finger's true tactel responses."""
    from tactiled.physics.contact import Contact
    from tactiled.physics.strain import StrainModel

    g = geometry or Geometry()
    if g.flat and indentors is IDENTIFY_INDENTORS:
        indentors = FLAT_IDENTIFY_INDENTORS
    rng = np.random.default_rng(seed)
    model = StrainModel(finger.sensor(g))
    contacts = np.zeros((n, 6))
    strain = np.zeros((n, g.rows, g.cols))
    for p in range(n):
        if rng.uniform() < unloaded_fraction:
            contacts[p] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            continue
        r1, r2 = indentors[int(rng.integers(len(indentors)))]
        # a cylinder along the finger makes a line contact outside the planar model
        angle = float(rng.uniform(0.0, 180.0) if r2 == r1 else rng.uniform(*CYLINDER_ANGLES))
        force = float(rng.uniform(*force_range))
        x, y = float(rng.uniform(0.0, g.span_x)), float(rng.uniform(0.0, g.span_y))
        contacts[p] = (r1, r2, angle, force, x, y)
        strain[p] = model.predict(Contact(r1, r2, angle, force, x, y))
    strain += rng.normal(0.0, noise_sigma / math.sqrt(frames_averaged), strain.shape)
    counts = finger.zero_counts(g) + finger.counts_per_strain(g) * strain
    counts = np.clip(np.rint(counts), 0, 0xFFFF).astype(np.uint16)
    return PressSet(counts, None, sensor_id, contacts)

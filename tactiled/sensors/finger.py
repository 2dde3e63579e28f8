"""A finger that is not the paper's: the simulator's description of one physical fingertip."""

# No real finger matches the paper's constants.  A :class:`FingerSpec` says how a simulated
# finger differs: its rubber (impulse-response depths and ratios, modulus), and each tactel's
# gain error, displacement from the nominal pitch and count offset at zero load, all drawn from
# one seed so the same spec always gives the same finger.  It yields
#
# * :meth:`FingerSpec.sensor`: the true :class:`~tactiled.sensors.model.SensorModel` (rubber and tactel
#   positions): the physics the simulator renders;
# * :meth:`FingerSpec.gains` / :meth:`FingerSpec.offsets`: the tactels' true response,
#   ``counts = ZERO_STRAIN_COUNTS + offset + COUNTS_PER_STRAIN * gain * strain``.
#
# The fitter knows none of this; ``tactiled calibrate --identify`` estimates it from presses.
# Used by the sim driver (``sim://?depth_x=5&gain_error=0.05...``), ``tactiled simulate`` and the
# benchmarks.  Units: mm, N/mm^2, counts.

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from functools import cached_property

import numpy as np

from tactiled.sensors.model import (
    MAX_POSITION_ERROR,
    Geometry,
    ImpulseResponse,
    Material,
    NoiseModel,
    SensorModel,
    TactelPositions,
    cover_constants,
)

#: Nominal counts per unit strain and counts at zero strain of a simulated tactel: the same as
#: :meth:`~tactiled.calibration.lut.LookupTable.linear`'s defaults, so a daemon with no
#: calibration file reads simulated counts back as the simulator's strain.  20000 counts per
#: unit strain = 20 counts per 0.001 strain (one count = 5e-5 strain, a tenth of the default
#: noise sigma); zero strain at 10000 counts, so 0 .. 65535 spans strain -0.5 .. +2.78, ample
#: room for tension, drift and the hardest press.
COUNTS_PER_STRAIN = 20000.0
ZERO_STRAIN_COUNTS = 10000.0

_PAPER_IMPULSE = ImpulseResponse()
_PAPER_MATERIAL = Material()


@dataclass(frozen=True)
class FingerSpec:
    """How a simulated finger departs from the paper's (the defaults are the paper's finger).

    ``gain_error`` is the standard deviation of the tactels' relative gains (0.05: gains
    ~ N(1, 0.05)); ``position_error`` the standard deviation (mm) of each tactel's displacement
    along x and along y; ``offset_counts`` the half-width of the uniform count offsets at zero
    load (300: each tactel's zero within +/-300 counts of nominal).  ``seed`` draws them.
    """

    depth_x: float = _PAPER_IMPULSE.depth_x
    nu_x: float = _PAPER_IMPULSE.nu_x
    depth_y: float = _PAPER_IMPULSE.depth_y
    nu_y: float = _PAPER_IMPULSE.nu_y
    modulus: float = _PAPER_MATERIAL.modulus
    gain_error: float = 0.0
    position_error: float = 0.0
    offset_counts: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        ImpulseResponse(self.depth_x, self.nu_x, self.depth_y, self.nu_y)  # ValueError naming it
        Material(self.modulus)
        for name, top in (("gain_error", 0.5), ("position_error", MAX_POSITION_ERROR / 3),
                          ("offset_counts", 20000.0)):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 <= v <= top):
                raise ValueError(f"{name} must lie in [0, {top:g}], got {v!r}")
        if not (isinstance(self.seed, int) and self.seed >= 0):
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")

    # -- parsing ----------------------------------------------------------------------------
    #: Names accepted by :meth:`from_params` (URL parameters, CLI flags); ``finger_seed`` is
    #: the seed (``seed`` names the noise seed in a sim URL).
    PARAMS = ("depth_x", "nu_x", "depth_y", "nu_y", "modulus", "gain_error", "position_error",
              "offset_counts", "finger_seed")

    @classmethod
    def of_sensor(cls, sensor: SensorModel, **changes: float | int) -> FingerSpec:
        """A spec whose rubber is ``sensor``'s cover (a sensor description's), with
        ``changes``."""
        return cls(**{**cover_constants(sensor.impulse, sensor.material), **changes})

    @classmethod
    def from_params(cls, params: Mapping[str, str | float | int],
                    base: SensorModel | None = None) -> FingerSpec:
        """A spec from string or number values keyed by :data:`PARAMS` (others ignored),
        departing from ``base``'s cover (default the paper's); ``ValueError`` naming the key
        for a bad value."""
        kw: dict[str, float | int] = {}
        for key in cls.PARAMS:
            if key not in params:
                continue
            raw = params[key]
            try:
                if key == "finger_seed":
                    kw["seed"] = int(raw)
                else:
                    kw[key] = float(raw)
            except (TypeError, ValueError):
                raise ValueError(f"{key}: expected a number, got {raw!r}") from None
        return cls(**kw) if base is None else cls.of_sensor(base, **kw)

    @property
    def is_paper(self) -> bool:
        """True when this is the paper's finger exactly (nothing to simulate differently)."""
        return self == replace(FingerSpec(), seed=self.seed)

    def describe(self) -> dict[str, float | int]:
        """The spec as a flat dict (for reports and the simulator's metadata)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    # -- the finger -------------------------------------------------------------------------
    @cached_property
    def _draws(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Standard draws for 32 x 32 tactels (any array up to that size takes its corner, so
        one seed gives the same tactel errors whatever else changes)."""
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 0x7ac7]))
        g = rng.standard_normal((32, 32))
        ex = rng.standard_normal((32, 32))
        ey = rng.standard_normal((32, 32))
        off = rng.uniform(-1.0, 1.0, (32, 32))
        return g, ex, ey, off

    def gains(self, geometry: Geometry | None = None) -> np.ndarray:
        """Each tactel's true gain, ``(rows, cols)``, relative to nominal (clipped to
        ``[0.5, 1.5]``)."""
        g = geometry or Geometry()
        return np.clip(1.0 + self.gain_error * self._draws[0][:g.rows, :g.cols], 0.5, 1.5)

    def offsets(self, geometry: Geometry | None = None) -> np.ndarray:
        """Each tactel's count offset at zero load, ``(rows, cols)`` counts."""
        g = geometry or Geometry()
        return self.offset_counts * self._draws[3][:g.rows, :g.cols]

    def positions(self, geometry: Geometry | None = None) -> TactelPositions:
        """Each tactel's true displacement from the nominal pitch (mm)."""
        g = geometry or Geometry()
        if self.position_error == 0.0:
            return TactelPositions()
        lim = MAX_POSITION_ERROR
        ex = np.clip(self.position_error * self._draws[1][:g.rows, :g.cols], -lim, lim)
        ey = np.clip(self.position_error * self._draws[2][:g.rows, :g.cols], -lim, lim)
        return TactelPositions.from_arrays(ex, ey)

    def sensor(self, geometry: Geometry | None = None, noise: NoiseModel | None = None) -> SensorModel:
        """The true :class:`SensorModel` of this finger: its rubber and tactel positions."""
        g = geometry or Geometry()
        return SensorModel(
            geometry=g,
            impulse=ImpulseResponse(self.depth_x, self.nu_x, self.depth_y, self.nu_y),
            material=Material(self.modulus),
            noise=noise or NoiseModel(),
            positions=self.positions(g),
        )

    def counts_per_strain(self, geometry: Geometry | None = None) -> np.ndarray:
        """Counts per unit strain of each tactel, ``(rows, cols)``."""
        return COUNTS_PER_STRAIN * self.gains(geometry)

    def zero_counts(self, geometry: Geometry | None = None) -> np.ndarray:
        """Counts each tactel reads at zero strain, ``(rows, cols)``."""
        return ZERO_STRAIN_COUNTS + self.offsets(geometry)

    def to_counts(self, strain: np.ndarray, geometry: Geometry | None = None) -> np.ndarray:
        """Raw ``uint16`` counts of strain frames ``(..., rows, cols)`` (rounded, clipped)."""
        c = np.rint(self.zero_counts(geometry) + self.counts_per_strain(geometry) * strain)
        return np.clip(c, 0, 65535).astype(np.uint16)

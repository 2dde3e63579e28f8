"""Typed settings of the sensor: geometry, material, impulse response, noise.

Units follow ``MODEL.md``: millimetres, newtons, N/mm^2; strain is dimensionless and positive
under compression.  These are frozen dataclasses so a model built from them can be cached and
shared with a worker process safely.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Geometry:
    """Tactel layout of the cylindrical array, unrolled to a plane (paper sec. 3).

    Tactel ``[m, n]`` sits at ``x = m*dx`` (along the finger axis), ``y = n*dy`` (arc length
    around the circumference); the origin is the centre of tactel ``[0, 0]``.
    """

    rows: int = 8
    cols: int = 8
    dx: float = 3.3  # mm, spacing along the finger axis
    dy: float = 3.9  # mm, arc spacing around the circumference (12.7 mm * sin 18 deg)
    finger_radius: float = 12.7  # mm, R_f

    def __post_init__(self) -> None:
        if self.rows < 1 or self.cols < 1:
            raise ValueError(f"array shape must be positive, got ({self.rows}, {self.cols})")
        for name in ("dx", "dy", "finger_radius"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite length in mm, got {value!r}")

    @property
    def span_x(self) -> float:
        """Distance in mm between the first and last tactel centres along x."""
        return (self.rows - 1) * self.dx

    @property
    def span_y(self) -> float:
        """Distance in mm between the first and last tactel centres along y."""
        return (self.cols - 1) * self.dy


@dataclass(frozen=True)
class ImpulseResponse:
    """Separable plane-stress line-load response parameters (paper eqs. 3-4)."""

    depth_x: float = 4.3  # mm, d_x
    nu_x: float = 0.5
    depth_y: float = 6.0  # mm, d_y
    nu_y: float = 0.7  # empirical, not a physical Poisson ratio

    def __post_init__(self) -> None:
        for name in ("depth_x", "depth_y"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive depth in mm, got {value!r}")


@dataclass(frozen=True)
class Material:
    """Finger rubber; the indentor is taken as rigid."""

    modulus: float = 0.25  # N/mm^2, E (2.5e5 N/m^2)
    poisson: float = 0.5  # nu_f

    def __post_init__(self) -> None:
        if not (math.isfinite(self.modulus) and self.modulus > 0):
            raise ValueError(f"modulus must be positive in N/mm^2, got {self.modulus!r}")
        if not (0.0 <= self.poisson <= 0.5):
            raise ValueError(f"poisson must lie in [0, 0.5], got {self.poisson!r}")

    @property
    def compliance(self) -> float:
        """``k = (1 - nu_f^2) / E`` in mm^2/N (rigid indentor)."""
        return (1.0 - self.poisson**2) / self.modulus


@dataclass(frozen=True)
class NoiseModel:
    """Strain noise of a linearised, zeroed tactel.

    ``sigma`` is the Gaussian part; ``quantum`` the quantisation step (0 for none).  The paper's
    +/-0.05 % quantisation bound is the default ``sigma = 0.0005``.
    """

    sigma: float = 0.0005
    quantum: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.sigma) and self.sigma >= 0):
            raise ValueError(f"sigma must be a finite non-negative strain, got {self.sigma!r}")
        if not (math.isfinite(self.quantum) and self.quantum >= 0):
            raise ValueError(f"quantum must be a finite non-negative strain, got {self.quantum!r}")
        if self.sigma == 0 and self.quantum == 0:
            raise ValueError("noise model needs sigma > 0 or quantum > 0")

    @property
    def effective_sigma(self) -> float:
        """Standard deviation of Gaussian noise plus uniform quantisation error, ``q^2/12``."""
        return math.sqrt(self.sigma**2 + self.quantum**2 / 12.0)


@dataclass(frozen=True)
class SensorModel:
    """Everything the physics and the fitter need to know about one sensor."""

    geometry: Geometry = field(default_factory=Geometry)
    impulse: ImpulseResponse = field(default_factory=ImpulseResponse)
    material: Material = field(default_factory=Material)
    noise: NoiseModel = field(default_factory=NoiseModel)


DEFAULT_SENSOR = SensorModel()

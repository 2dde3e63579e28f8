"""The physical model of one sensor: geometry, cover (impulse response, material), noise.

Units follow ``docs/concepts/model.md``: millimetres, newtons, N/mm^2; strain is dimensionless and positive
under compression.  These are frozen dataclasses so a model built from them can be cached and
shared with a worker process safely.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


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
    finger_radius: float = 12.7  # mm, R_f; math.inf for a flat array

    def __post_init__(self) -> None:
        if self.rows < 1 or self.cols < 1:
            raise ValueError(f"array shape must be positive, got ({self.rows}, {self.cols})")
        for name in ("dx", "dy"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite length in mm, got {value!r}")
        if not self.finger_radius > 0:  # inf is a flat array; NaN fails here too
            raise ValueError(f"finger_radius must be a positive length in mm (inf: flat), got {self.finger_radius!r}")

    @property
    def flat(self) -> bool:
        """True for a flat array (``1/R_f = 0``): a cylinder touches it along a line."""
        return math.isinf(self.finger_radius)

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
class TactelPositions:
    """Each tactel's displacement from its nominal grid position, mm, row-major
    (``k = m * cols + n``): tactel ``[m, n]`` sits at ``(m*dx + ex[k], n*dy + ey[k])``.

    Empty tuples (the default) mean every tactel is on its nominal pitch.  Tuples, not arrays,
    keep a :class:`SensorModel` hashable (fitters and start tables are cached per model).
    """

    ex: tuple[float, ...] = ()
    ey: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if len(self.ex) != len(self.ey):
            raise ValueError(f"ex and ey must have the same length, got {len(self.ex)} and {len(self.ey)}")
        for name in ("ex", "ey"):
            for k, v in enumerate(getattr(self, name)):
                if not (math.isfinite(v) and abs(v) <= MAX_POSITION_ERROR):
                    raise ValueError(f"{name}[{k}] must be a displacement within +/-{MAX_POSITION_ERROR} mm, got {v!r}")

    @property
    def nominal(self) -> bool:
        """True when every tactel is on the nominal grid."""
        return not self.ex or (not any(self.ex) and not any(self.ey))

    def arrays(self, rows: int, cols: int) -> tuple[np.ndarray, np.ndarray]:
        """``(ex, ey)`` as ``(rows, cols)`` arrays in mm (zeros when nominal)."""
        if not self.ex:
            return np.zeros((rows, cols)), np.zeros((rows, cols))
        if len(self.ex) != rows * cols:
            raise ValueError(f"{len(self.ex)} tactel positions for a {rows}x{cols} array")
        return (np.array(self.ex, dtype=float).reshape(rows, cols),
                np.array(self.ey, dtype=float).reshape(rows, cols))

    @classmethod
    def from_arrays(cls, ex: np.ndarray, ey: np.ndarray) -> TactelPositions:
        """From ``(rows, cols)`` arrays of displacements in mm."""
        return cls(tuple(float(v) for v in np.ravel(ex)), tuple(float(v) for v in np.ravel(ey)))


@dataclass(frozen=True)
class ModelError:
    """The model-error floor: how far a tactel's strain departs from the model's prediction
    beyond the sensor noise, as a standard deviation in strain

        sd_model = sqrt(strain**2 + (relative * s)**2)

    where ``s`` is the tactel's strain.  It is added in quadrature to the noise in the fit's
    weights and covariance.  Zero (the default) for a finger that matches its model exactly;
    ``tactiled calibrate --identify`` measures it on a real finger.
    """

    strain: float = 0.0  # absolute part, strain (dimensionless)
    relative: float = 0.0  # part proportional to the tactel's strain (0.01 = 1 %)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.strain) and 0.0 <= self.strain <= 0.1):
            raise ValueError(f"model error 'strain' must lie in [0, 0.1], got {self.strain!r}")
        if not (math.isfinite(self.relative) and 0.0 <= self.relative <= 1.0):
            raise ValueError(f"model error 'relative' must lie in [0, 1], got {self.relative!r}")

    @property
    def zero(self) -> bool:
        return self.strain == 0.0 and self.relative == 0.0


#: The cover's constants by name (mm, ratios, N/mm^2): what a description, a calibration file
#: and an identification all say of the rubber.
IMPULSE_KEYS = ("depth_x", "nu_x", "depth_y", "nu_y")
COVER_KEYS = (*IMPULSE_KEYS, "modulus")
#: Physical ranges of the cover's constants; a description or a calibration file outside them
#: is refused, naming the key.
COVER_RANGES: dict[str, tuple[float, float]] = {
    "depth_x": (0.5, 30.0), "nu_x": (-0.5, 0.99), "depth_y": (0.5, 30.0), "nu_y": (-0.5, 0.99),
    "modulus": (0.005, 100.0),
}


def cover_constants(impulse: ImpulseResponse, material: Material) -> dict[str, float]:
    """The cover's constants keyed by :data:`COVER_KEYS` (mm, ratios, N/mm^2)."""
    return {"depth_x": impulse.depth_x, "nu_x": impulse.nu_x, "depth_y": impulse.depth_y,
            "nu_y": impulse.nu_y, "modulus": material.modulus}


#: Largest tactel displacement from the nominal grid a model accepts, mm (a third of a pitch:
#: beyond that the tactel is not where the layout says, it is another tactel).
MAX_POSITION_ERROR = 1.0


@dataclass(frozen=True)
class SensorModel:
    """Everything the physics and the fitter need to know about one sensor.

    The defaults are the paper's finger (docs/concepts/model.md); a calibration file written by
    ``tactiled calibrate --identify`` replaces the rubber constants, the tactel positions and
    the model-error floor with the ones measured on the user's finger.
    """

    geometry: Geometry = field(default_factory=Geometry)
    impulse: ImpulseResponse = field(default_factory=ImpulseResponse)
    material: Material = field(default_factory=Material)
    noise: NoiseModel = field(default_factory=NoiseModel)
    positions: TactelPositions = field(default_factory=TactelPositions)
    model_error: ModelError = field(default_factory=ModelError)

    def __post_init__(self) -> None:
        n = len(self.positions.ex)
        if n and n != self.geometry.rows * self.geometry.cols:
            raise ValueError(f"{n} tactel positions for a {self.geometry.rows}x{self.geometry.cols} array")


DEFAULT_SENSOR = SensorModel()

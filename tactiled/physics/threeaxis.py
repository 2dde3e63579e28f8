"""Forward model of a 3-axis array: a contact's loads -> every taxel's x, y, z readings."""

# Each taxel of a 3-axis description (``axes = 3``, docs/concepts/shear.md) reads the
# displacement of a point at ``taxel_depth_mm`` under the cover's surface (a magnet over a Hall
# sensor), times its per-axis gain (readings per mm), plus Gaussian noise of ``axis_noise``
# readings.  The displacement is the half-space's (tactiled/physics/traction.py) under the Hertz
# pressure of a spherical indentor of radius ``r_mm`` on the array's surface (a curved array
# unrolled to a plane, as the normal model does: the contact is the Hertz ellipse of the sphere on
# the cylinder), the Cattaneo-Mindlin tangential traction and Lubkin's torsion.
#
# Frames are ``(rows, cols, 3)``: x along rows, y along columns, z positive into the cover.

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tactiled.physics.hertz import Ellipse, contact_ellipse
from tactiled.physics.traction import DisplacementModel, Traction
from tactiled.sensors.description import SensorDescription


@dataclass(frozen=True)
class ShearContact:
    """A sphere of radius ``r_mm`` pressed with ``force`` N at ``(x0, y0)`` mm, carrying the
    tangential force ``(fx, fy)`` N and torsion ``torque`` N mm, with the friction mobilised
    ``lam = |Q| / (mu P)`` in [0, 1]."""

    r_mm: float
    force: float
    x0: float
    y0: float
    fx: float = 0.0
    fy: float = 0.0
    torque: float = 0.0
    lam: float = 0.0

    @property
    def traction(self) -> Traction:
        return Traction(self.force, self.fx, self.fy, self.torque, self.lam)


class ThreeAxisModel:
    """The forward model of one 3-axis description (``ValueError`` for a 1-axis one)."""

    def __init__(self, desc: SensorDescription, tol: float = 1e-8) -> None:
        if desc.axes != 3:
            raise ValueError(f"sensor {desc.name!r} is a 1-axis array (axes = 1): no shear model")
        self.desc = desc
        sm = desc.sensor_model()
        self._rf = sm.geometry.finger_radius
        self._k = sm.material.compliance
        self.model = DisplacementModel(desc.taxel_depth_mm, desc.modulus_n_mm2, desc.cover_poisson, tol)
        gx, gy = np.meshgrid(np.arange(desc.rows) * desc.pitch_x_mm,
                             np.arange(desc.cols) * desc.pitch_y_mm, indexing="ij")
        self.px, self.py = gx.ravel(), gy.ravel()
        self.gain = np.asarray(desc.axis_gain, dtype=float)
        self.noise = np.asarray(desc.axis_noise, dtype=float)
        mask = desc.dead_mask()
        self.live = np.ones(desc.rows * desc.cols, bool) if mask is None else mask.ravel()

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.desc.rows, self.desc.cols, 3)

    def ellipse(self, r_mm: float, force: float) -> Ellipse:
        """The Hertz contact of a sphere of radius ``r_mm`` (mm) under ``force`` (N)."""
        ell, _ = contact_ellipse(1.0 / r_mm, 1.0 / r_mm, 0.0, force, self._rf, self._k)
        return ell

    def readings(self, c: ShearContact, px: np.ndarray | None = None, py: np.ndarray | None = None
                 ) -> np.ndarray:
        """Noise-free readings ``(points, 3)`` (every taxel, row-major, by default)."""
        px = self.px if px is None else px
        py = self.py if py is None else py
        u = self.model.displacement(self.ellipse(c.r_mm, c.force), c.traction, c.x0, c.y0, px, py)
        return u * self.gain

    def frame(self, c: ShearContact | None) -> np.ndarray:
        """Noise-free frame ``(rows, cols, 3)`` (zeros for no contact)."""
        if c is None:
            return np.zeros(self.shape)
        return self.readings(c).reshape(self.shape)

    def centre(self) -> tuple[float, float]:
        d = self.desc
        return (d.rows - 1) * d.pitch_x_mm / 2.0, (d.cols - 1) * d.pitch_y_mm / 2.0


def three_axis(desc: SensorDescription, depth_mm: float | None = None,
               noise_readings: float = 2.0) -> SensorDescription:
    """``desc`` made 3-axis (the bench's 16x16 pad and the paper's finger): magnets at
    ``depth_mm`` (default the cover's ``depth_x_mm``), 1000 readings per mm, ``noise_readings``
    of noise on each axis."""
    from dataclasses import replace

    depth = desc.depth_x_mm if depth_mm is None else depth_mm
    return replace(desc, name=f"{desc.name}_3axis", axes=3, taxel_depth_mm=depth,
                   axis_gain=(1000.0, 1000.0, 1000.0), axis_noise=(noise_readings,) * 3)


def lam_for(q: float, mu: float, force: float) -> float:
    """``Q / (mu P)`` clipped to [0, 1] (1: the contact slides)."""
    return min(1.0, abs(q) / (mu * force)) if mu > 0 and math.isfinite(mu) else 0.0

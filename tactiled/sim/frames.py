"""Contacts to noisy strain frames: the forward model the fitter inverts (``StrainModel``),
plus Gaussian noise and quantisation as in the paper (sec. 7: strain quantised in steps of
0.1 %).  :func:`simulate_frames` is what ``tactiled simulate OUT.npz`` writes.

Units: mm, N; strain is dimensionless and positive under compression.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from tactiled.physics.contact import Contact, LineContact
from tactiled.physics.strain import StrainModel
from tactiled.sensors.model import Geometry, NoiseModel, SensorModel


def add_noise(strain: np.ndarray, noise: NoiseModel, rng: np.random.Generator) -> np.ndarray:
    """``strain`` plus i.i.d. Gaussian noise of ``noise.sigma``, then rounded to multiples of
    ``noise.quantum`` (if non-zero).  Returns a new array."""
    out = strain + rng.normal(0.0, noise.sigma, size=np.shape(strain)) if noise.sigma > 0 else np.array(strain, dtype=float)
    if noise.quantum > 0:
        out = np.round(out / noise.quantum) * noise.quantum
    return out


def line_length(geometry: Geometry) -> float:
    """The length (mm) over which a simulated rod on a flat array spreads its force: the
    array's diagonal plus a pitch at each end (the rod is longer than the array)."""
    g = geometry
    return math.hypot(g.span_x, g.span_y) + 2.0 * max(g.dx, g.dy)


def as_line(contact: Contact | LineContact, geometry: Geometry) -> Contact | LineContact:
    """``contact`` as the array feels it: on a flat array a cylinder of force ``F`` is a
    line contact of load ``F / line_length`` N/mm through its centre; otherwise unchanged."""
    if not geometry.flat or isinstance(contact, LineContact) or contact.kappa_b != 0.0:
        return contact
    return LineContact(contact.r1, contact.psi_deg, contact.force / line_length(geometry),
                       contact.x0, contact.y0)


def render(contact: Contact | LineContact | None, model: StrainModel) -> np.ndarray:
    """Noise-free strain frame ``(rows, cols)`` for ``contact`` (zeros for ``None``; a
    cylinder on a flat array: :func:`as_line`)."""
    g = model.sensor.geometry
    if contact is None:
        return np.zeros((g.rows, g.cols))
    return model.predict(as_line(contact, g))


def render_sum(contacts: Sequence[Contact | LineContact], model: StrainModel) -> np.ndarray:
    """Noise-free strain frame ``(rows, cols)`` of several contacts pressing at once: the sum
    of each one's :func:`render` (the strain is linear in the pressure, and the pressures of
    separate contacts add); zeros for none."""
    g = model.sensor.geometry
    out = np.zeros((g.rows, g.cols))
    for c in contacts:
        out += render(c, model)
    return out


def simulate_frames(
    contacts: list[Contact | None],
    sensor: SensorModel | None = None,
    noise: NoiseModel | None = None,
    seed: int = 0,
) -> np.ndarray:
    """Noisy frames ``(N, rows, cols)`` for a list of contacts (``None`` = no contact)."""
    model = StrainModel(sensor or SensorModel())
    noise = noise or model.sensor.noise
    rng = np.random.default_rng(seed)
    return np.stack([add_noise(render(c, model), noise, rng) for c in contacts])

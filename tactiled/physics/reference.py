"""A slow, independent integration of eq. 13, for tests and benchmark ground truth.

It shares nothing with :mod:`tactiled.physics.strain` but the impulse response and the Hertz
ellipse: polar coordinates in the ellipse, ``x' = a sin(t) cos(phi)``, ``y' = b sin(t) sin(phi)``
(the ``sin`` substitution turns the pressure's square-root edge into a smooth ``cos^2 t sin t``),
composite 4-point Gauss-Legendre panels in t and the periodic trapezoid rule in phi, on a grid
that grows with the contact's size relative to the rubber depth.  ``resolution`` scales both grid
counts; tests double it to show the result has converged.
"""

from __future__ import annotations

import math

import numpy as np

from tactiled.sensors.model import SensorModel
from tactiled.physics.contact import Contact
from tactiled.physics.hertz import contact_ellipse
from tactiled.physics.impulse import line_response


def reference_strain(
    contact: Contact,
    sensor: SensorModel | None = None,
    resolution: float = 1.0,
    xs: np.ndarray | None = None,
    ys: np.ndarray | None = None,
) -> np.ndarray:
    """Strain frame ``(len(xs), len(ys))`` (whole array by default) by brute-force quadrature."""
    sensor = sensor or SensorModel()
    g, imp, mat = sensor.geometry, sensor.impulse, sensor.material
    xs = np.arange(g.rows) * g.dx if xs is None else np.asarray(xs, dtype=float)
    ys = np.arange(g.cols) * g.dy if ys is None else np.asarray(ys, dtype=float)
    ell, _ = contact_ellipse(
        contact.kappa_a, contact.kappa_b, contact.psi, contact.force,
        g.finger_radius, mat.compliance,
    )
    d = min(imp.depth_x, imp.depth_y)
    size = max(ell.a / d, 1.0)
    n_panels = int(math.ceil(resolution * max(24, 6 * size)))
    n_phi = int(math.ceil(resolution * max(96, 24 * math.pi * size)))
    gl_x, gl_w = np.polynomial.legendre.leggauss(4)
    edges = np.linspace(0.0, 0.5 * math.pi, n_panels + 1)
    half = 0.5 * (edges[1:] - edges[:-1])
    mid = 0.5 * (edges[1:] + edges[:-1])
    t = (mid[:, None] + half[:, None] * gl_x[None, :]).ravel()
    wt = (half[:, None] * gl_w[None, :]).ravel()
    phi = np.arange(n_phi) * (2.0 * math.pi / n_phi)
    wphi = 2.0 * math.pi / n_phi
    rho = np.sin(t)
    # pressure * area element = 3F/(2 pi a b) * cos t * (a b rho * cos t) dt dphi
    w_rad = wt * np.cos(t) ** 2 * rho * wphi
    xp = ell.a * (rho[:, None] * np.cos(phi)[None, :])
    yp = ell.b * (rho[:, None] * np.sin(phi)[None, :])
    c, s = math.cos(ell.theta), math.sin(ell.theta)
    xq = (contact.x0 + xp * c - yp * s).ravel()
    yq = (contact.y0 + xp * s + yp * c).ravel()
    w = np.repeat(w_rad, n_phi)
    hx = line_response(xs[:, None] - xq[None, :], imp.depth_x, imp.nu_x)
    hy = line_response(ys[:, None] - yq[None, :], imp.depth_y, imp.nu_y)
    total = (hx * w) @ hy.T
    return (3.0 * contact.force / (2.0 * math.pi * mat.modulus)) * total

"""Green's functions of the elastic half-space: the displacement under the surface of the cover
caused by a point force on it (Boussinesq for a normal force, Cerruti for a tangential one).
"""

# Conventions (docs/concepts/shear.md): ``x`` along rows, ``y`` along columns, ``z`` the depth
# into the cover, positive inward, so a normal force pressing on the cover is ``+z`` and the
# displacement it causes below it is ``u_z > 0`` (compression positive, as the strain of the
# normal model).  A point at offset ``(dx, dy)`` from the force and depth ``z > 0`` has
# ``rho = sqrt(dx^2 + dy^2 + z^2)``; with shear modulus ``G`` and Poisson ratio ``nu``
# (K. L. Johnson, Contact Mechanics, 1985, eqs. 3.19 and 3.86):
#
#     normal force P (Boussinesq):
#         u_x = P/(4 pi G) [ dx z / rho^3 - (1 - 2 nu) dx / (rho (rho + z)) ]
#         u_z = P/(4 pi G) [ z^2 / rho^3 + 2 (1 - nu) / rho ]
#     tangential force Q along x (Cerruti):
#         u_x = Q/(4 pi G) [ 1/rho + dx^2/rho^3 + (1 - 2 nu) (1/(rho + z) - dx^2/(rho (rho + z)^2)) ]
#         u_y = Q/(4 pi G) [ dx dy / rho^3 - (1 - 2 nu) dx dy / (rho (rho + z)^2) ]
#         u_z = Q/(4 pi G) [ dx z / rho^3 + (1 - 2 nu) dx / (rho (rho + z)) ]
#
# and the same with ``x`` and ``y`` exchanged.  Units: mm, N, N/mm^2; displacements in mm.

from __future__ import annotations

import math

import numpy as np

from tactiled import native


def shear_modulus(modulus: float, nu: float) -> float:
    """``G = E / (2 (1 + nu))`` in N/mm^2."""
    return modulus / (2.0 * (1.0 + nu))


def green(dx: np.ndarray, dy: np.ndarray, z: float, g: float, nu: float) -> np.ndarray:
    """The displacement (mm) per newton at offsets ``(dx, dy)`` (mm, any shape) from a surface
    point force, at depth ``z > 0`` mm: an array ``(3, 3, *shape)``, ``[i, j]`` the displacement
    along axis ``i`` (x, y, z) per unit force along axis ``j``.  ``g`` is the shear modulus
    (N/mm^2), ``nu`` Poisson's ratio (0..0.5)."""
    if not z > 0.0:
        raise ValueError(f"depth must be > 0 mm (the Green's function is singular on the surface), got {z!r}")
    dx = np.asarray(dx, dtype=float)
    dy = np.asarray(dy, dtype=float)
    rho2 = dx * dx + dy * dy + z * z
    rho = np.sqrt(rho2)
    inv_r = 1.0 / rho
    inv_r3 = inv_r / rho2
    rz = rho + z
    k = 1.0 - 2.0 * nu
    c = 1.0 / (4.0 * math.pi * g)
    out = np.empty((3, 3) + dx.shape)
    a = inv_r / rz  # 1 / (rho (rho + z))
    b = a / rz  # 1 / (rho (rho + z)^2)
    # tangential x (Cerruti) and y (by symmetry)
    out[0, 0] = c * (inv_r + dx * dx * inv_r3 + k * (1.0 / rz - dx * dx * b))
    out[1, 1] = c * (inv_r + dy * dy * inv_r3 + k * (1.0 / rz - dy * dy * b))
    cross = c * dx * dy * (inv_r3 - k * b)
    out[0, 1] = cross
    out[1, 0] = cross
    out[2, 0] = c * dx * (z * inv_r3 + k * a)
    out[2, 1] = c * dy * (z * inv_r3 + k * a)
    # normal (Boussinesq)
    out[0, 2] = c * dx * (z * inv_r3 - k * a)
    out[1, 2] = c * dy * (z * inv_r3 - k * a)
    out[2, 2] = c * (z * z * inv_r3 + 2.0 * (1.0 - nu) * inv_r)
    return out


def green_weighted(px: np.ndarray, py: np.ndarray, ox: np.ndarray, oy: np.ndarray, weights: np.ndarray,
                   z: float, g: float, nu: float) -> np.ndarray:
    """``out[k, i, j, p] = sum_n green(px[p] - ox[n], py[p] - oy[n])[i, j] * weights[k, j, n]``:
    the displacements at points ``p`` of ``k`` sets of point forces at nodes ``n`` (weights per
    force axis ``j``).  The core (core/halfspace.cpp) sums node after node; this reference
    through :func:`green` and one ``einsum`` (another order of the sums: equal to rounding)."""
    px, py = np.asarray(px, dtype=float), np.asarray(py, dtype=float)
    gf = green(px[:, None] - np.asarray(ox, dtype=float)[None, :],
               py[:, None] - np.asarray(oy, dtype=float)[None, :], z, g, nu)  # (3, 3, p, n)
    return np.einsum("ijpn,kjn->kijp", gf, np.asarray(weights, dtype=float))


#: The Python body the core is held to (tests/native), whichever runs.
REFERENCE = native.bind(globals(), ("green_weighted",))

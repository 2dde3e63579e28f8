"""The displacement of the cover at the taxels' depth under a contact's tractions: the Hertz
pressure, a Cattaneo-Mindlin tangential traction and a torsion (docs/concepts/shear.md).
"""

# A contact on an ellipse of semi-axes ``a >= b`` (major axis at ``theta``), centre
# ``(x0, y0)``, carries, with ``rho^2 = x'^2/a^2 + y'^2/b^2`` in the ellipse's axes:
#
# * the normal force ``P`` as the Hertz pressure ``p = 3P/(2 pi a b) sqrt(1 - rho^2)``;
# * the tangential force ``Q = (fx, fy)`` after Cattaneo and Mindlin (Johnson, Contact Mechanics,
#   sec. 7.2): with ``lam = Q/(mu P)`` (the friction mobilised, 0..1) the stick zone is the
#   similar ellipse of scale ``kappa = c/a = (1 - lam)^(1/3)`` and
#
#       q = Q/lam * 3/(2 pi a b) [ sqrt(1 - rho^2) - kappa sqrt(1 - rho^2/kappa^2) ]    (rho < kappa: both)
#
#   which at ``lam -> 0`` tends to full stick, ``q = Q / (2 pi a b sqrt(1 - rho^2))``, and at
#   ``lam = 1`` (gross slip) is ``mu p``.  The traction is taken along ``Q`` everywhere (Mindlin's
#   approximation: exact for ``nu = 0``);
# * the torsion ``T`` about the normal (N mm) as Lubkin's full-stick traction, circumferential,
#   ``q = K r / sqrt(1 - rho^2)`` with ``K = 3T / (2 pi a b (a^2 + b^2))`` (exact for a circle).
#
# The displacement at a point at depth ``d`` is each traction convolved with the half-space
# Green's functions (tactiled/physics/halfspace.py).  The integrals map the ellipse to the unit
# disk, as the normal model's (tactiled/physics/strain.py): ``sqrt(1 - rho^2)`` tractions by its
# Gauss-Jacobi x Gauss-Chebyshev-U rule, ``1/sqrt(1 - rho^2)`` ones by Gauss-Legendre x
# Gauss-Chebyshev-T, node counts from the kernel's pole at distance ``d`` (``nodes_for``).
# A curved array is unrolled to a plane as the normal model does.

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import roots_chebyt, roots_legendre

from tactiled.physics.halfspace import green_weighted
from tactiled.physics.hertz import Ellipse
from tactiled.physics.quadrature_rules import DEFAULT_TOL, disk_rule, nodes_for

#: Above this ``1 - lam`` the partial-slip traction is evaluated as full stick: the difference
#: of the two Hertz-like integrals divided by ``lam`` would lose the quadrature's accuracy.
FULL_STICK_LAM = 1e-4


@dataclass(frozen=True)
class Traction:
    """A contact's loads: normal force ``force`` (N), tangential ``fx``, ``fy`` (N), torsion
    ``torque`` (N mm, about +z, counter-clockwise from +x toward +y) and ``lam = |Q| / (mu P)``
    in ``[0, 1]``, the friction mobilised (0: full stick, 1: gross slip)."""

    force: float
    fx: float = 0.0
    fy: float = 0.0
    torque: float = 0.0
    lam: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.force) and self.force > 0):
            raise ValueError(f"force must be positive and finite in N, got {self.force!r}")
        if not 0.0 <= self.lam <= 1.0:
            raise ValueError(f"lam = Q/(mu P) must lie in [0, 1], got {self.lam!r}")
        for name in ("fx", "fy", "torque"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)!r}")


def stick_ratio(lam: float) -> float:
    """``c/a = (1 - lam)^(1/3)``: the stick zone's scale for ``lam = Q/(mu P)``."""
    return (1.0 - lam) ** (1.0 / 3.0)


@lru_cache(maxsize=256)
def inverse_sqrt_rule(n_u: int, n_s: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nodes ``(u, v)`` and weights of a unit-disk rule for weight ``1/sqrt(1 - u^2 - v^2)``
    (weights sum to ``2 pi``): ``v = sqrt(1 - u^2) s``, Gauss-Legendre in ``u`` times
    Gauss-Chebyshev (first kind) in ``s``."""
    u, wu = roots_legendre(n_u)
    s, ws = roots_chebyt(n_s)
    uu = np.repeat(u, n_s)
    v = np.sqrt(1.0 - uu * uu) * np.tile(s, n_u)
    w = np.repeat(wu, n_s) * np.tile(ws, n_u)
    for arr in (uu, v, w):
        arr.setflags(write=False)
    return uu, v, w


def _nodes(ell: Ellipse, scale: float, x0: float, y0: float, u: np.ndarray, v: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """Unit-disk nodes on the ellipse scaled by ``scale``: offsets from the centre (mm)."""
    c, s = math.cos(ell.theta), math.sin(ell.theta)
    au, bv = scale * ell.a * u, scale * ell.b * v
    return au * c - bv * s, au * s + bv * c


class DisplacementModel:
    """Displacement (mm) of points at depth ``depth`` mm under a contact's tractions, for a
    cover of modulus ``modulus`` (N/mm^2) and Poisson ratio ``nu``."""

    def __init__(self, depth: float, modulus: float, nu: float, tol: float = DEFAULT_TOL) -> None:
        if not depth > 0:
            raise ValueError(f"depth must be > 0 mm, got {depth!r}")
        self.depth, self.modulus, self.nu, self.tol = depth, modulus, nu, tol
        self.g = modulus / (2.0 * (1.0 + nu))

    def _sum(self, px: np.ndarray, py: np.ndarray, ox: np.ndarray, oy: np.ndarray,
             weights: np.ndarray) -> np.ndarray:
        """``(k, 3, 3, points)``: the Green's tensor between points and nodes summed over the
        nodes with ``weights`` ``(k, 3, nodes)`` (see :func:`green_weighted`)."""
        return green_weighted(px, py, np.ascontiguousarray(ox), np.ascontiguousarray(oy),
                              np.ascontiguousarray(weights), self.depth, self.g, self.nu)

    def hertz_shaped(self, ell: Ellipse, scale: float, x0: float, y0: float,
                     px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """``(3, 3, points)``: displacement per newton of a Hertz-shaped traction
        ``3/(2 pi a' b') sqrt(1 - rho'^2)`` on the ellipse scaled by ``scale``, along each axis."""
        u, v, w = disk_rule(nodes_for(scale * ell.a, self.depth, self.tol),
                            nodes_for(scale * ell.b, self.depth, self.tol))
        ox, oy = _nodes(ell, scale, x0, y0, u, v)
        wt = np.broadcast_to(w * (3.0 / (2.0 * math.pi)), (1, 3, w.size))
        return self._sum(px, py, x0 + ox, y0 + oy, wt)[0]

    def _inverse_shaped(self, ell: Ellipse, x0: float, y0: float, px: np.ndarray, py: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
        """Full-stick tangential ``(3, 2, points)`` per newton and Lubkin torsion ``(3, points)``
        per N mm."""
        u, v, w = inverse_sqrt_rule(nodes_for(ell.a, self.depth, self.tol),
                                    nodes_for(ell.b, self.depth, self.tol))
        ox, oy = _nodes(ell, 1.0, x0, y0, u, v)
        k = 3.0 / (2.0 * math.pi * (ell.a ** 2 + ell.b ** 2))  # per N mm, times ab du dv / ab
        weights = np.zeros((2, 3, w.size))
        weights[0, 0] = weights[0, 1] = w / (2.0 * math.pi)
        weights[1, 0], weights[1, 1] = -oy * w * k, ox * w * k
        out = self._sum(px, py, x0 + ox, y0 + oy, weights)
        return out[0, :, :2], out[1, :, 0] + out[1, :, 1]

    def displacement(self, ell: Ellipse, load: Traction, x0: float, y0: float,
                     px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Displacement ``(points, 3)`` in mm (x, y, z; z positive into the cover) at the points
        ``(px, py)`` (mm, flattened) under ``load`` on the contact ellipse ``ell`` at ``(x0, y0)``."""
        px = np.ascontiguousarray(px, dtype=float).ravel()
        py = np.ascontiguousarray(py, dtype=float).ravel()
        unit = self.hertz_shaped(ell, 1.0, x0, y0, px, py)
        out = load.force * unit[:, 2]
        need_inverse = load.torque != 0.0 or (load.lam < FULL_STICK_LAM and (load.fx or load.fy))
        if need_inverse:
            tang_stick, tors = self._inverse_shaped(ell, x0, y0, px, py)
            out = out + load.torque * tors
        if load.fx or load.fy:
            q = np.array((load.fx, load.fy))
            if load.lam < FULL_STICK_LAM:
                tang = tang_stick
            else:
                kappa = stick_ratio(load.lam)
                tang = unit[:, :2]
                if kappa > 0.0:
                    inner = self.hertz_shaped(ell, kappa, x0, y0, px, py)[:, :2]
                    tang = (tang - kappa ** 3 * inner) / load.lam
            out = out + np.einsum("ijp,j->ip", tang, q)
        return out.T

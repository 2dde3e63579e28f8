"""Contact models: how each model's free parameters map onto the physics' six inputs.

Each model fits an unconstrained vector whose every value is a valid contact (log radii, log
force), so the solver needs no clipping.  Units: curvatures 1/mm, angles rad, force N, mm.
"""

# The physics takes ``(kappa_a, kappa_b, psi, F, x0, y0)`` (curvatures in 1/mm, radians, N, mm).
# Each model fits an unconstrained vector whose every value is a valid contact, so the solver
# needs no clipping (lmfit's habit of bounded parameters, done by reparameterisation):
#
# - ``cylinder`` ``[ln R, psi, ln F, x0, y0]``: ``kappa_a = 1/R``, ``kappa_b = 0``.
# - ``sphere`` ``[ln R, ln F, x0, y0]``: ``kappa_a = kappa_b = 1/R``, ``psi = 0``.
# - ``general`` ``[ln R_a, beta, psi, ln F, x0, y0]``: ``kappa_a = 1/R_a``,
#   ``kappa_b = beta^2 kappa_a``.  ``beta^2 > 1`` means the axes swapped roles; reporting swaps
#   them back so that ``r1 <= r2`` and psi is the R2 axis.  ``beta = 0`` is a cylinder.
#
# ``psi`` is periodic: it is reported modulo 180 degrees.  Positive R and F hold by construction.

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tactiled import native

from tactiled.fit.params import VALUE_KEYS, report  # noqa: F401  (VALUE_KEYS re-exported)



@dataclass(frozen=True)
class Model:
    """A contact model: its name, parameter names, and the map to physics inputs."""

    name: str
    params: tuple[str, ...]

    @property
    def size(self) -> int:
        return len(self.params)

    def physical(self, p: np.ndarray) -> tuple[tuple[float, ...], np.ndarray]:
        """``(kappa_a, kappa_b, psi, F, x0, y0)`` and ``d(those)/d(p)`` of shape (6, size)."""
        raise NotImplementedError

    def from_values(
        self, r1: float, r2: float, psi_deg: float, force: float, x0: float, y0: float
    ) -> np.ndarray:
        """Internal vector for a contact given in user units (a start or a truth)."""
        raise NotImplementedError

    def report(self, p: np.ndarray) -> tuple[dict[str, float | None], np.ndarray]:
        """User-unit values (``VALUE_KEYS``) and the gradient matrix (6 keys x size) for the
        delta method; a row of NaN marks a value that does not exist in this model."""
        raise NotImplementedError


def physical_map(kind: int, p: np.ndarray, d: np.ndarray) -> tuple[float, float, float, float, float, float]:
    """Every model's map from its parameters to ``(kappa_a, kappa_b, psi, F, x0, y0)``, filling
    ``d`` (zeroed, (6, k)) with its Jacobian; ``kind`` 0 cylinder, 1 sphere, 2 general.  One
    compiled copy serves the Python models and the compiled search alike.  Too few parameters
    for the kind (a line contact's four given as a cylinder's) is a ValueError."""
    if p.shape[0] < (5, 4, 6)[kind]:
        raise ValueError(f"model kind {kind} takes {(5, 4, 6)[kind]} parameters, got {p.shape[0]}")
    if kind == 0:  # cylinder: ln_r, psi, ln_f, x0, y0
        ka, f = math.exp(-p[0]), math.exp(p[2])
        d[0, 0] = -ka
        d[2, 1] = 1.0
        d[3, 2] = f
        d[4, 3] = 1.0
        d[5, 4] = 1.0
        return ka, 0.0, p[1], f, p[3], p[4]
    if kind == 1:  # sphere: ln_r, ln_f, x0, y0
        k, f = math.exp(-p[0]), math.exp(p[1])
        d[0, 0] = -k
        d[1, 0] = -k
        d[3, 1] = f
        d[4, 2] = 1.0
        d[5, 3] = 1.0
        return k, k, 0.0, f, p[2], p[3]
    # general: ln_ra, beta, psi, ln_f, x0, y0
    ka, beta, f = math.exp(-p[0]), p[1], math.exp(p[3])
    kb = beta * beta * ka
    d[0, 0] = -ka
    d[1, 0] = -kb
    d[1, 1] = 2.0 * beta * ka
    d[2, 2] = 1.0
    d[3, 3] = f
    d[4, 4] = 1.0
    d[5, 5] = 1.0
    return ka, kb, p[2], f, p[4], p[5]


#: the Python body (the reference); ``physical_map`` runs the compiled core's when it is loaded
REFERENCE = native.bind(globals(), ("physical_map",))


class Cylinder(Model):
    def __init__(self) -> None:
        super().__init__("cylinder", ("ln_r", "psi", "ln_f", "x0", "y0"))

    def physical(self, p):
        d = np.zeros((6, 5))
        return physical_map(0, p, d), d

    def from_values(self, r1, r2, psi_deg, force, x0, y0):
        return np.array([math.log(r1), math.radians(psi_deg), math.log(force), x0, y0])

    def report(self, p):
        return report(self.name, p)


class Sphere(Model):
    def __init__(self) -> None:
        super().__init__("sphere", ("ln_r", "ln_f", "x0", "y0"))

    def physical(self, p):
        d = np.zeros((6, 4))
        return physical_map(1, p, d), d

    def from_values(self, r1, r2, psi_deg, force, x0, y0):
        return np.array([math.log(r1), math.log(force), x0, y0])

    def report(self, p):
        return report(self.name, p)


class General(Model):
    def __init__(self) -> None:
        super().__init__("general", ("ln_ra", "beta", "psi", "ln_f", "x0", "y0"))

    def physical(self, p):
        d = np.zeros((6, 6))
        return physical_map(2, p, d), d

    def from_values(self, r1, r2, psi_deg, force, x0, y0):
        beta = 0.0 if math.isinf(r2) else math.sqrt(r1 / r2)
        return np.array([math.log(r1), beta, math.radians(psi_deg), math.log(force), x0, y0])

    def report(self, p):
        return report(self.name, p)


MODELS: dict[str, Model] = {m.name: m for m in (Cylinder(), Sphere(), General())}


def get_model(name: str) -> Model:
    """Model by name; ``ValueError`` naming the choices otherwise."""
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(f"unknown model {name!r}; choose one of {sorted(MODELS)}") from None

"""The contact parameters tactiled estimates, in user units (mm, N, degrees)."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Contact:
    """A paraboloid indentor pressed on the finger.

    ``r1 <= r2`` are the principal radii in mm (``r2 = inf`` for a cylinder, ``r1 == r2`` for
    a sphere); ``psi_deg`` is the direction of the R2 axis (a cylinder's axis) from +x toward +y
    in degrees; ``force`` is the normal force in N; ``(x0, y0)`` the contact centre in mm in
    array coordinates (tactel ``[0, 0]`` at the origin).
    """

    r1: float
    r2: float = math.inf
    psi_deg: float = 90.0
    force: float = 1.0
    x0: float = 0.0
    y0: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.r1) and self.r1 > 0):
            raise ValueError(f"r1 must be a positive finite radius in mm, got {self.r1!r}")
        if not (self.r2 > 0) or math.isnan(self.r2):
            raise ValueError(f"r2 must be a positive radius in mm or inf, got {self.r2!r}")
        if not (math.isfinite(self.force) and self.force > 0):
            raise ValueError(f"force must be positive and finite in N, got {self.force!r}")
        for name in ("psi_deg", "x0", "y0"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)!r}")

    @property
    def kappa_a(self) -> float:
        """Curvature across the R2 axis, ``1/r1``, in 1/mm."""
        return 1.0 / self.r1

    @property
    def kappa_b(self) -> float:
        """Curvature along the R2 axis, ``1/r2`` (0 for a cylinder), in 1/mm."""
        return 0.0 if math.isinf(self.r2) else 1.0 / self.r2

    @property
    def psi(self) -> float:
        """``psi_deg`` in radians."""
        return math.radians(self.psi_deg)


@dataclass(frozen=True)
class LineContact:
    """A cylinder pressed on a flat array: a line contact (docs/concepts/model.md, "Other arrays").

    ``r1`` is the cylinder's radius in mm; ``psi_deg`` the direction of its axis (the line)
    from +x toward +y; ``load`` the load per unit length in N/mm; ``(x0, y0)`` any point of
    the line in array coordinates (mm).  Neither the total force nor the position along the
    line exists for a line longer than the array.
    """

    r1: float
    psi_deg: float = 90.0
    load: float = 0.1
    x0: float = 0.0
    y0: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.r1) and self.r1 > 0):
            raise ValueError(f"r1 must be a positive finite radius in mm, got {self.r1!r}")
        if not (math.isfinite(self.load) and self.load > 0):
            raise ValueError(f"load must be positive and finite in N/mm, got {self.load!r}")
        for name in ("psi_deg", "x0", "y0"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)!r}")

    @property
    def psi(self) -> float:
        """``psi_deg`` in radians."""
        return math.radians(self.psi_deg)

    def offset_from(self, x: float, y: float) -> float:
        """Signed distance (mm) of the line from the point ``(x, y)``, along the normal
        ``n = (-sin psi, cos psi)``."""
        return -math.sin(self.psi) * (self.x0 - x) + math.cos(self.psi) * (self.y0 - y)

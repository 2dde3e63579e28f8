"""Ways of estimating a contact, compared by ``tactiled bench``.

Every estimator takes a zeroed strain frame and returns user-unit values (``VALUE_KEYS``); it is
told when a new scene starts so warm-starting ones can forget the previous contact.
"""

from __future__ import annotations

import math

import numpy as np

from tactiled.sensors.model import SensorModel
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.start import features, force_estimate, start_table
from tactiled.fit.window import interpolated_peak

Values = dict[str, float | None]


class Estimator:
    name: str = ""
    #: one line for the table's legend
    description: str = ""

    def reset(self) -> None:
        """A new scene starts (forget any warm state)."""

    def estimate(self, strain: np.ndarray) -> Values:
        raise NotImplementedError


class FitEstimator(Estimator):
    """The full fit with given options; ``warm`` starts each frame from the previous frame's
    solution within a scene (the daemon's behaviour on a persisting contact)."""

    def __init__(self, name: str, description: str, sensor: SensorModel,
                 options: FitOptions | None = None, model: str = "cylinder", warm: bool = False) -> None:
        self.name, self.description, self.model, self.warm = name, description, model, warm
        self.fitter = Fitter(sensor, options or FitOptions())
        self._prev: tuple[float, ...] | None = None

    def reset(self) -> None:
        self._prev = None

    def estimate(self, strain: np.ndarray) -> Values:
        start = np.array(self._prev) if (self.warm and self._prev is not None) else None
        res = self.fitter.fit(strain, self.model, start=start)
        self._prev = res.params if res.model == self.model else None
        return dict(res.values)


class TableEstimator(Estimator):
    """Nearest pattern in the fitter's start table: (R, psi) from the 3x3 neighbourhood of the
    peak, centre from the interpolated peak, force from the summed strain.  No iteration."""

    name = "start table only"
    description = "nearest 3x3 pattern in the precomputed table; interpolated peak; summed force"

    def __init__(self, sensor: SensorModel) -> None:
        self.sensor = sensor
        self.table = start_table(sensor)

    def estimate(self, strain: np.ndarray) -> Values:
        g = self.sensor.geometry
        pk = np.unravel_index(int(np.argmax(strain)), strain.shape)
        x, y = interpolated_peak(strain, pk, g.dx, g.dy)
        f = force_estimate(strain, self.sensor, x, y)
        c = self.table.candidates(features(strain, pk, f), count=1)[0]
        return {"x_mm": x, "y_mm": y, "force_n": f, "r1_mm": c.radius, "r2_mm": None, "angle_deg": c.psi_deg}


class MomentsEstimator(Estimator):
    """The classical cheap estimators: centroid (position), summed strain (force), second
    moments of the peak's neighbourhood (orientation) and second differences of the strain
    profile across the contact (radius; Speeter 1987, Gurfinkel 1974), the last mapped to a
    radius by a log-linear law fitted once on separately seeded simulated cylinders."""

    name = "centroid + moments + 2nd differences"
    description = "centroid, summed force, second-moment orientation, second-difference radius"

    def __init__(self, sensor: SensorModel) -> None:
        self.sensor = sensor
        self._coef = np.zeros(3)
        self._train()

    def _raw(self, strain: np.ndarray) -> tuple[Values, float]:
        g = self.sensor.geometry
        rows, cols = strain.shape
        m, n = np.unravel_index(int(np.argmax(strain)), strain.shape)
        m0, m1 = max(m - 1, 0), min(m + 2, rows)
        n0, n1 = max(n - 1, 0), min(n + 2, cols)
        patch = np.clip(strain[m0:m1, n0:n1], 0.0, None)
        xs = np.arange(m0, m1)[:, None] * g.dx
        ys = np.arange(n0, n1)[None, :] * g.dy
        w = patch.sum() or 1.0
        x = float((patch * xs).sum() / w)
        y = float((patch * ys).sum() / w)
        sxx = float((patch * (xs - x) ** 2).sum() / w)
        syy = float((patch * (ys - y) ** 2).sum() / w)
        sxy = float((patch * (xs - x) * (ys - y)).sum() / w)
        # the strain pattern is elongated along the contact's major axis ~ a cylinder's axis;
        # the kernel's own spread (wider in y) is removed by normalising each axis by its pitch
        theta = 0.5 * math.atan2(2 * sxy / (g.dx * g.dy), sxx / g.dx**2 - syy / g.dy**2)
        psi = math.degrees(theta) % 180.0
        peak = float(strain[m, n])

        def d2(i: int, j: int, di: int, dj: int, h: float) -> float:
            if not (0 <= i - di < rows and 0 <= i + di < rows and 0 <= j - dj < cols and 0 <= j + dj < cols):
                return float("nan")
            return (strain[i - di, j - dj] - 2 * strain[i, j] + strain[i + di, j + dj]) / h**2

        dxx, dyy = d2(m, n, 1, 0, g.dx), d2(m, n, 0, 1, g.dy)
        # curvature of the profile across the cylinder (perpendicular to its axis)
        phi = math.radians(psi + 90.0)
        across = dxx * math.cos(phi) ** 2 + dyy * math.sin(phi) ** 2
        f = force_estimate(strain, self.sensor, x, y)
        feature = -across / peak if peak > 0 else float("nan")
        return {"x_mm": x, "y_mm": y, "force_n": f, "r1_mm": None, "r2_mm": None, "angle_deg": psi}, feature

    def _train(self) -> None:
        from tactiled_bench.suite import build_suite

        rows, targets = [], []
        for bf in build_suite(120, 1, kinds=("cylinder",), seed=987654):
            vals, feat = self._raw(bf.strain)
            if feat > 0 and math.isfinite(feat):
                rows.append([1.0, math.log(feat), math.log(vals["force_n"])])
                targets.append(math.log(bf.contact.r1))
        self._coef, *_ = np.linalg.lstsq(np.array(rows), np.array(targets), rcond=None)

    def estimate(self, strain: np.ndarray) -> Values:
        vals, feat = self._raw(strain)
        if feat > 0 and math.isfinite(feat):
            vals["r1_mm"] = float(math.exp(self._coef @ [1.0, math.log(feat), math.log(vals["force_n"])]))
        return vals


def default_configurations(sensor: SensorModel, quick: bool = False) -> list[Estimator]:
    """The benchmark's rows.  The first is the daemon's default."""
    base = FitOptions()
    rows: list[Estimator] = [
        FitEstimator("fit 4x4, warm (default)", "daemon default: cylinder, 4x4 window, quadrature tol 1e-9, warm start", sensor, base, warm=True),
        FitEstimator("fit 4x4, cold", "same, every frame from the start table", sensor, base),
        FitEstimator("fit 6x6, warm", "6x6 window", sensor, FitOptions(window=6), warm=True),
        FitEstimator("fit 8x8 (whole), warm", "whole array", sensor, FitOptions(window=8), warm=True),
        FitEstimator("fit 4x4, warm, FD Jacobian", "forward-difference Jacobian instead of the exact one", sensor, FitOptions(jacobian="fd"), warm=True),
        FitEstimator("fit 4x4, warm, quadrature tol 1e-3", "coarse forward model (fewer Gauss nodes)", sensor, FitOptions(tol=1e-3), warm=True),
        FitEstimator("fit 4x4, warm, quadrature tol 1e-4", "coarser forward model", sensor, FitOptions(tol=1e-4), warm=True),
        FitEstimator("fit 4x4, warm, quadrature tol 1e-6", "coarser forward model", sensor, FitOptions(tol=1e-6), warm=True),
        TableEstimator(sensor),
        MomentsEstimator(sensor),
    ]
    return rows

"""Cold-start estimates: centre, force, and candidate (radius, orientation) pairs.

Position comes from the interpolated peak and force from the total strain over the impulse
response summed on the array (see :func:`force_estimate`).  Radius and orientation have no
closed form, so the starts are the nearest entries of a table of predicted patterns built once
per sensor.
"""

# Radius and orientation are blurred by the rubber's low-pass (the paper's Fig. 10).  The table
# holds the 3x3 neighbourhood of the peak, normalised by the peak, plus the peak-to-force ratio,
# for a grid of cylinders (radius x orientation x force x sub-tactel offset).  The fitter tries
# a second start only where the first fit is poor or the two nearest orientations fit the
# features about equally.

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from tactiled import native

from tactiled.sensors.model import SensorModel
from tactiled.physics.contact import Contact, LineContact
from tactiled.fit.window import interpolated_peak, peak_centre
from tactiled.physics.strain import StrainModel

_RADII = np.geomspace(0.3, 150.0, 12)
_ANGLES = np.arange(7.5, 180.0, 15.0)  # psi = 0 is an infinite line for a cylinder
_FORCES = (0.15, 0.6, 2.0)
_OFFSETS = (-0.3, 0.0, 0.3)
_PEAK_WEIGHT = 1.0
#: Table entries read per lookup, nearest first, among which the starts' orientations are picked.
_NEAREST = 48


def force_estimate(strain: np.ndarray, sensor: SensorModel, x0: float | None = None, y0: float | None = None) -> float:
    """Force in N from the summed strain, treating the contact as a point load at
    ``(x0, y0)`` (mm; default: the interpolated peak).

    A point load F gives ``strain[m, n] = (F/E) h_x(X_m - x0) h_y(Y_n - y0)``, so
    ``F = E sum(strain) / (sum_m h_x(X_m - x0) sum_n h_y(Y_n - y0))``.  Summing the kernels over
    the actual tactels (not their infinite integrals ``1 - nu``) matters: their ``-nu/u^2``
    tails make an 8x8 array's sums 1.5-2.3x the integrals, and an edge contact loses part of
    its response.  A contact wider than the rubber depth reads a few per cent low.
    """
    g = sensor.geometry
    if x0 is None or y0 is None:
        pk = np.unravel_index(int(np.argmax(strain)), strain.shape)
        x0, y0 = interpolated_peak(strain, pk, g.dx, g.dy)
    return _force(float(strain.sum()), *force_constants(sensor), float(x0), float(y0))


def force_constants(sensor: SensorModel) -> tuple:
    """The sensor's constants :func:`_force` takes after the summed strain."""
    g, imp = sensor.geometry, sensor.impulse
    return (sensor.material.modulus, g.rows, g.dx, imp.depth_x, imp.nu_x, g.cols, g.dy,
            imp.depth_y, imp.nu_y)


def _force(total: float, modulus: float, rows: int, dx: float, depth_x: float, nu_x: float,
           cols: int, dy: float, depth_y: float, nu_y: float, x0: float, y0: float) -> float:
    """:func:`force_estimate` from the summed strain ``total`` (summed by numpy, whose
    pairwise sum the callers share)."""
    sx = line_sum(rows, dx, x0, depth_x, nu_x)
    sy = line_sum(cols, dy, y0, depth_y, nu_y)
    est = total * modulus / max(sx * sy, 1e-12)
    return min(max(est, 1e-3), 50.0)


def features(strain: np.ndarray, peak: tuple[int, int], force: float) -> np.ndarray:
    """The 3x3 neighbourhood of the peak / the peak (NaN where off the array), and
    ``log(peak / force)``; 9 numbers."""
    return _features(np.asarray(strain, dtype=float), int(peak[0]), int(peak[1]), float(force))


def _features(strain: np.ndarray, m: int, n: int, force: float) -> np.ndarray:
    rows, cols = strain.shape
    c = strain[m, n]
    out = np.full(9, np.nan)
    k = 0
    for i in (-1, 0, 1):
        for j in (-1, 0, 1):
            if i == 0 and j == 0:
                continue
            if 0 <= m + i < rows and 0 <= n + j < cols:
                out[k] = strain[m + i, n + j] / c
            k += 1
    out[8] = _PEAK_WEIGHT * math.log(max(c, 1e-12) / force)
    return out


def start_point(strain: np.ndarray, m: int, n: int, total: float, modulus: float, rows: int, dx: float,
                depth_x: float, nu_x: float, cols: int, dy: float, depth_y: float, nu_y: float):
    """A cold start's ``(x0, y0, force, features)`` for the peak at ``(m, n)`` in one compiled
    call: :func:`interpolated_peak`, :func:`force_estimate` (``total`` the summed strain, as
    numpy sums it) and :func:`features`."""
    x0, y0 = peak_centre(strain, m, n, dx, dy)
    f0 = _force(total, modulus, rows, dx, depth_x, nu_x, cols, dy, depth_y, nu_y, x0, y0)
    return x0, y0, f0, _features(strain, m, n, f0)


@dataclass(frozen=True)
class Candidate:
    radius: float
    psi_deg: float
    distance: float


class StartTable:
    """Nearest-pattern lookup of (radius, psi) for a sensor."""

    def __init__(self, sensor: SensorModel) -> None:
        self.sensor = sensor
        model = StrainModel(sensor, tol=1e-6)
        g = sensor.geometry
        cm, cn = g.rows // 2 - 1, g.cols // 2 - 1
        feats, params = [], []
        for r in _RADII:
            for psi in _ANGLES:
                for f in _FORCES:
                    for ox in _OFFSETS:
                        for oy in _OFFSETS:
                            x0, y0 = (cm + ox) * g.dx, (cn + oy) * g.dy
                            # on a flat array a cylinder is a line: its load per length
                            # about a tenth of the force per mm
                            c = (LineContact(float(r), float(psi), 0.1 * f, x0, y0) if g.flat
                                 else Contact(float(r), math.inf, float(psi), f, x0, y0))
                            s = model.predict(c)
                            pk = np.unravel_index(int(np.argmax(s)), s.shape)
                            feats.append(features(s, pk, force_estimate(s, sensor)))
                            params.append((float(r), float(psi)))
        # A neighbour off the array reads as zero strain, in the table and in queries alike.
        self.features = np.nan_to_num(np.array(feats), nan=0.0)
        self.params = np.array(params)

    def candidates(self, feat: np.ndarray, count: int = 2, min_separation: float = 35.0) -> list[Candidate]:
        """The best ``count`` candidates whose orientations differ by ``min_separation`` deg."""
        dist, near = nearest(self.features, np.asarray(feat, dtype=float), _NEAREST)
        chosen = pick_separated(self.params[near, 1], count, min_separation)
        return [Candidate(float(self.params[near[i], 0]), float(self.params[near[i], 1]), float(dist[i]))
                for i in chosen]


def nearest(table: np.ndarray, feat: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` rows of ``table`` nearest to ``feat`` (Euclidean), nearest first (ties: the
    lower index first): ``(distances, indices)``.  A NaN in ``feat`` (a neighbour off the array)
    reads as 0, as in the table; infinities are clipped to +-1e6.

    An exhaustive pass, the squares summed as scipy's k-d tree sums them (four lanes, then the
    rest), so the same distances in the same order as its query, at a fraction of its cost on
    a table this small.  A row whose first four squares already reach the k-th distance so far
    is passed over: a sum of non-negative terms only grows, rounding included."""
    n, m = table.shape
    q = np.clip(np.nan_to_num(np.asarray(feat, dtype=float), nan=0.0, posinf=1e6, neginf=-1e6),
                -1e6, 1e6)
    k = min(k, n)
    sq = (table - q) ** 2
    lanes = m // 4 * 4
    # four lanes summed in order (column j into lane j % 4), then the lanes, then the rest
    a = np.zeros((n, 4)) if lanes == 0 else np.cumsum(
        sq[:, :lanes].reshape(n, lanes // 4, 4), axis=1)[:, -1, :]
    d = a[:, 0] + a[:, 1] + a[:, 2] + a[:, 3]
    for j in range(lanes, m):
        d = d + sq[:, j]
    order = np.argsort(d, kind="stable")[:k]  # ties: the lower index first
    best_d, best_i = d[order], order.astype(np.int64)
    unfilled = ~(best_d < np.inf)  # never nearer than nothing (the core's empty slots)
    best_d[unfilled], best_i[unfilled] = np.inf, -1
    return np.sqrt(best_d), best_i


def pick_separated(angles: np.ndarray, count: int, min_separation: float) -> list[int]:
    """Indices into ``angles`` (deg, best first): the first, then each next one whose
    orientation differs from every one chosen by ``min_separation`` (orientations modulo 180)."""
    chosen = [0]
    n = angles.shape[0]
    sep = np.full(n, 180.0)
    while len(chosen) < count:
        last = angles[chosen[-1]]
        nxt = -1
        for i in range(n):
            d = abs((angles[i] - last + 90.0) % 180.0 - 90.0)
            if d < sep[i]:
                sep[i] = d
            if nxt < 0 and sep[i] >= min_separation:
                nxt = i
        if nxt < 0:
            break
        chosen.append(nxt)
    return chosen


def line_sum(n: int, pitch: float, x0: float, depth: float, nu: float) -> float:
    """``sum_m h(m * pitch - x0)`` over ``n`` tactels (the line response, 1/mm)."""
    d2 = depth * depth
    c = 2.0 * depth / math.pi
    total = 0.0
    for m in range(n):
        u = m * pitch - x0
        u2 = u * u
        s = u2 + d2
        total += c * (d2 - nu * u2) / (s * s)
    return total


#: the Python bodies (the reference); the module's names run the compiled core's when it is loaded
REFERENCE = native.bind(globals(), {"_force": "force_from_total", "_features": "features",
                                    "start_point": "start_point", "nearest": "nearest",
                                    "pick_separated": "pick_separated", "line_sum": "line_sum"})


@lru_cache(maxsize=8)
def start_table(sensor: SensorModel) -> StartTable:
    """The table for ``sensor``, built once per process (~0.1 s)."""
    return StartTable(sensor)

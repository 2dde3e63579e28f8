"""Contact detection on zeroed strain frames: a matched-filter bank, a noise-calibrated threshold
and hysteresis.
"""

# Statistic
# ---------
# The rubber spreads even a point contact over 3x3 to 4x4 tactels (impulse response depth 4-6 mm
# against 3.3-3.9 mm pitch), so the detector correlates the frame with the point-load response
# ``w_u(i, j) = h_x((i - u_x) dx) h_y((j - u_y) dy)`` for template centres ``u`` on a grid of half
# a tactel pitch (15 x 15 centres on 8x8; ``subdivide``), keeping tactels within ``reach`` = 1.5
# pitches of the centre, and normalises each output by its template's norm:
#
#     T[u] = sum_ij w_u(i, j) z[i, j] / sqrt(sum_ij w_u(i, j)^2)
#
# On noise-only frames (i.i.d. ``N(0, sigma^2)``) every ``T[u]`` is exactly ``N(0, sigma^2)``,
# at the array edge too.  For a point contact at ``u`` its mean is the frame's full matched-filter
# SNR there (about 1.2 times the peak strain for a contact over a tactel); the half-pitch centres
# matter for contacts between tactels, where a tactel-centred template loses a quarter of the
# signal (at 0.05 N between four tactels: miss 9 % with tactel centres, 3 % with the bank).  The
# statistic is ``max T``.  ``w`` is separable, so the map is ``Ax @ z @ Ay.T`` with banded
# ``Ax``, ``Ay`` (normalisation folded into their rows): two tiny BLAS calls per frame.
#
# Threshold
# ---------
# ``P(max T > t) <= P * Q(t / sigma)`` over the ``P`` centres (union bound; ``Q`` the normal
# tail), so ``t = sigma * Q^-1(false_rate / P)`` guarantees at most ``false_rate`` false contacts
# per noise-only frame: 4.92 sigma for 1e-4 with 225 centres.  Neighbouring centres are strongly
# correlated, so the true rate is lower (about 0.6e-4; ``method="montecarlo"`` measures the
# quantile on simulated noise instead, 4.85 sigma).
#
# Non-finite entries
# ------------------
# NaN or inf in the frame are treated as 0 (no evidence either way), the frame is decided on the
# rest, and :attr:`ContactDetector.nonfinite_frames` counts such frames.

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
from numpy.typing import ArrayLike

from tactiled.calibration.fused import average_maps, filter_bands
from tactiled.sensors.model import DEFAULT_SENSOR, SensorModel
from tactiled.physics.impulse import line_response

DEFAULT_FALSE_RATE = 1e-4
#: Frames a false entry is held by hysteresis, as budgeted (measured mean: 1.6 at exit 0.6).
HYSTERESIS_DWELL = 2.0
DEFAULT_EXIT_FRACTION = 0.6
DEFAULT_SUBDIVIDE = 2  # template centres every half pitch
DEFAULT_REACH = 1.5  # pitches: 3 tactels around an on-tactel centre, 4 around a half-way one


def filter_matrices(
    sensor: SensorModel = DEFAULT_SENSOR, subdivide: int = DEFAULT_SUBDIVIDE,
    reach: float = DEFAULT_REACH,
) -> tuple[np.ndarray, np.ndarray]:
    """``(Ax, Ay)`` so that ``Ax @ z @ Ay.T`` is the normalised matched-filter map ``T``.

    Template centres run over the array in steps of ``1/subdivide`` tactel pitch:
    ``Ax`` is ``((rows-1)*subdivide + 1, rows)``, its row for centre ``u`` (in pitches) holding
    ``h_x((i - u) dx)`` for tactels ``i`` with ``|i - u| <= reach``, divided by the norm of the
    row (likewise ``Ay`` with ``cols``, ``h_y``, ``dy``).
    """
    if not (isinstance(subdivide, int) and subdivide >= 1):
        raise ValueError(f"subdivide must be a positive integer, got {subdivide!r}")
    if not (math.isfinite(reach) and reach >= 0.5):
        raise ValueError(f"reach must be at least 0.5 tactel pitch, got {reach!r}")
    g, imp = sensor.geometry, sensor.impulse

    def band(size: int, pitch: float, depth: float, nu: float) -> np.ndarray:
        centres = np.arange((size - 1) * subdivide + 1) / subdivide
        offset = np.arange(size)[None, :] - centres[:, None]  # in pitches
        a = np.where(np.abs(offset) <= reach + 1e-9,
                     line_response(offset * pitch, depth, nu), 0.0)
        return a / np.sqrt(np.sum(a * a, axis=1, keepdims=True))

    return (band(g.rows, g.dx, imp.depth_x, imp.nu_x), band(g.cols, g.dy, imp.depth_y, imp.nu_y))


def detection_threshold(
    sigma: float,
    false_rate: float = DEFAULT_FALSE_RATE,
    *,
    sensor: SensorModel = DEFAULT_SENSOR,
    subdivide: int = DEFAULT_SUBDIVIDE,
    reach: float = DEFAULT_REACH,
    method: str = "bound",
    n_frames: int = 200_000,
    seed: int = 0,
) -> float:
    """Enter threshold on the matched-filter statistic (strain) for ``false_rate`` false contacts
    per noise-only frame with i.i.d. Gaussian strain noise of standard deviation ``sigma``.

    ``method="bound"`` (default): the union bound of the module docstring, analytic and
    conservative.  ``method="montecarlo"``: the ``1 - false_rate`` quantile of the statistic over
    ``n_frames`` simulated frames (needs ``n_frames * false_rate`` >> 1 to be meaningful).
    """
    if not (math.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma must be a positive strain, got {sigma!r}")
    if not 0.0 < false_rate < 1.0:
        raise ValueError(f"false_rate must lie in (0, 1), got {false_rate!r}")
    g = sensor.geometry
    positions = ((g.rows - 1) * subdivide + 1) * ((g.cols - 1) * subdivide + 1)
    if method == "bound":
        return sigma * NormalDist().inv_cdf(1.0 - false_rate / positions)
    if method == "montecarlo":
        ax, ay = filter_matrices(sensor, subdivide, reach)
        rng = np.random.default_rng(seed)
        stats = []
        kernel_t = np.kron(ax, ay).T
        for start in range(0, n_frames, 10_000):  # chunks keep memory to ~25 MB
            z = rng.standard_normal((min(10_000, n_frames - start), kernel_t.shape[0]))
            stats.append((z @ kernel_t).max(axis=1))
        return sigma * float(np.quantile(np.concatenate(stats), 1.0 - false_rate))
    raise ValueError(f"method must be 'bound' or 'montecarlo', got {method!r}")


class ContactDetector:
    """Decides contact per zeroed strain frame, with hysteresis.

    Contact starts when the statistic exceeds ``enter_threshold`` and ends when it falls below
    ``exit_threshold`` (``exit_fraction`` of enter, default 0.6), so a contact hovering near the
    threshold does not flicker.  ``sigma`` (strain) defaults to the sensor's
    ``noise.effective_sigma``; thresholds can also be given directly (strain).
    """

    def __init__(
        self,
        sigma: float | None = None,
        *,
        sensor: SensorModel = DEFAULT_SENSOR,
        false_rate: float = DEFAULT_FALSE_RATE,
        exit_fraction: float = DEFAULT_EXIT_FRACTION,
        subdivide: int = DEFAULT_SUBDIVIDE,
        reach: float = DEFAULT_REACH,
        enter_threshold: float | None = None,
        exit_threshold: float | None = None,
        average: int = 1,
    ) -> None:
        if not (isinstance(average, int) and 1 <= average <= 64):
            raise ValueError(f"average must be an integer from 1 to 64 frames, got {average!r}")
        if not 0.0 < exit_fraction <= 1.0:
            raise ValueError(f"exit_fraction must lie in (0, 1], got {exit_fraction!r}")
        self.average = average
        self._sensor, self._subdivide, self._reach = sensor, subdivide, reach
        self._exit_fraction = exit_fraction
        self.configure(sigma=float(sensor.noise.effective_sigma if sigma is None else sigma),
                       false_rate=false_rate, enter_threshold=enter_threshold,
                       exit_threshold=exit_threshold)
        self.shape = (sensor.geometry.rows, sensor.geometry.cols)
        ax, ay = filter_matrices(sensor, subdivide, reach)
        self._ax, self._ay_t = ax, np.ascontiguousarray(ay.T)
        # For batches, T = Ax z Ay^T on the row-major flattened frame is one product with
        # kron(Ax, Ay) ((15*15, 64) by default); for one frame two tiny dots are cheaper.
        self._kernel_t = np.ascontiguousarray(np.kron(ax, ay).T)
        self._bands = filter_bands(self._ax, self._ay_t)  # (the compiled stage's)
        self.in_contact = False
        self.last_statistic = 0.0
        self.nonfinite_frames = 0
        # the last `average` filter maps (a ring, the oldest at _head once full) and their sum
        self._ring = np.zeros((average, self._kernel_t.shape[1]))
        self._total = np.zeros(self._kernel_t.shape[1])
        self._count = 0
        self._head = 0

    def configure(self, *, sigma: float | None = None, false_rate: float = DEFAULT_FALSE_RATE,
                  enter_threshold: float | None = None, exit_threshold: float | None = None) -> None:
        """Set the thresholds (at run time too): from the noise ``sigma`` (strain) and the
        false-contact budget, or given directly (strain)."""
        if sigma is not None:
            self.sigma = float(sigma)
        if enter_threshold is None:
            # The mean of `average` frames has noise sigma / sqrt(average).  With hysteresis a
            # false entry is held until the noise falls below the exit threshold: measured, it
            # lasts 1.6 frames on average at exit_fraction 0.6, so entries are set for half the
            # false-contact budget to keep false contact *frames* within it.
            dwell = HYSTERESIS_DWELL if self._exit_fraction < 1.0 else 1.0
            enter_threshold = detection_threshold(
                self.sigma / math.sqrt(self.average), false_rate / dwell,
                sensor=self._sensor, subdivide=self._subdivide, reach=self._reach)
        if exit_threshold is None:
            exit_threshold = self._exit_fraction * enter_threshold
        if not (math.isfinite(enter_threshold) and 0 < exit_threshold <= enter_threshold):
            raise ValueError(
                f"need 0 < exit_threshold <= enter_threshold, got {exit_threshold!r}, "
                f"{enter_threshold!r}"
            )
        self.enter_threshold = float(enter_threshold)
        self.exit_threshold = float(exit_threshold)

    def _filter(self, zeroed: ArrayLike) -> tuple[np.ndarray, bool]:
        """(filter map T of one frame, whether it had non-finite entries)."""
        z = np.asarray(zeroed, dtype=np.float64)
        if z.shape != self.shape:
            raise ValueError(f"zeroed frame must have shape {self.shape}, got {z.shape}")
        flat = z.reshape(-1)
        # argmax/argmin return a NaN if there is one, and (unlike arithmetic on inf) never warn.
        bad = not (math.isfinite(flat[flat.argmax()]) and math.isfinite(flat[flat.argmin()]))
        if bad:
            z = np.where(np.isfinite(z), z, 0.0)
        return np.dot(np.dot(self._ax, z), self._ay_t).reshape(-1), bad

    def _map(self, zeroed: ArrayLike) -> tuple[float, bool]:
        """(max T, whether the frame had non-finite entries) for one frame."""
        t, bad = self._filter(zeroed)
        return float(t[t.argmax()]), bad

    def statistic(self, zeroed: ArrayLike) -> float:
        """``max T`` of one ``(rows, cols)`` zeroed frame, in strain (non-finite entries as 0)."""
        return self._map(zeroed)[0]

    def statistic_batch(self, zeroed: ArrayLike) -> np.ndarray:
        """``max T`` for each frame of ``(N, rows, cols)`` (vectorised; non-finite as 0)."""
        z = np.asarray(zeroed, dtype=np.float64)
        z = z.reshape(z.shape[:-2] + (-1,))
        if not np.all(np.isfinite(z)):
            z = np.where(np.isfinite(z), z, 0.0)
        return (z @ self._kernel_t).max(axis=-1)

    def update(self, zeroed: ArrayLike) -> bool:
        """Decide one frame; returns (and stores in :attr:`in_contact`) the contact state.

        Frames with NaN/inf entries are decided with those entries as 0 and counted in
        :attr:`nonfinite_frames`.  With ``average > 1`` the statistic is taken on the mean of
        the last ``average`` frames (the filter is linear, so on the mean of their maps): at
        1 kHz, ``average=2`` costs 1 ms of latency and gains sqrt(2) in signal to noise.
        """
        t, bad = self._filter(zeroed)
        if bad:
            self.nonfinite_frames += 1
        if self.average > 1:
            return self.decide(self.average_map(t))
        return self.decide(float(t[t.argmax()]))

    def average_map(self, t: np.ndarray) -> float:
        """Take the filter map ``t`` (flat) of the newest frame into the running mean of the
        last ``average`` maps (:func:`~tactiled.calibration.fused.average_maps`); returns the
        statistic of the mean."""
        self._count, self._head, stat = average_maps(self._ring, self._total, t, self._count,
                                                     self._head)
        return stat

    def decide(self, stat: float) -> bool:
        """Decide one frame whose statistic (``max T``, strain) is ``stat``: the thresholds'
        hysteresis; returns (and stores in :attr:`in_contact`) the contact state."""
        self.last_statistic = stat
        if self.in_contact:
            self.in_contact = stat >= self.exit_threshold
        else:
            self.in_contact = stat > self.enter_threshold
        return self.in_contact

    def reset(self) -> None:
        """Forget the contact state and the averaging history (after a tare)."""
        self.in_contact = False
        self.last_statistic = 0.0
        self._count = self._head = 0

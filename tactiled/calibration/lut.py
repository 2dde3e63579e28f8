"""Per-tactel lookup tables: raw counts -> strain (linearisation), and strain -> counts."""

# Conventions
# -----------
# * Raw counts are the sensor's ``uint16`` capacitance readings; they rise with compression.
# * Strain is dimensionless and positive under compression (``docs/concepts/model.md``).  The table gives strain
#   *before zeroing*: the calibration's zero-load strain is 0, but drift and rubber hysteresis are
#   removed later by :class:`~tactiled.calibration.zeroing.Zeroer`.
# * Tactel ``[m, n]`` has knots ``counts`` (strictly increasing) and ``strain`` (non-decreasing);
#   between knots the map is linear.  Beyond the end knots it is **linearly extrapolated** with the
#   end segment's slope, not clamped: counts a little below the zero-load knot (baseline drift) must
#   give small negative strains for the zeroer to average, and presses harder than the calibration
#   reached must still rise (a clamp would flatten the peak the fitter needs).  The result stays
#   monotone because every slope is ``>= 0``.
#
# The counts domain is ``0 .. 65535``; float inputs outside ``[-65536, 131071]`` (or NaN) give an
# unspecified (but non-raising) result.

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from tactiled.calibration.segments import Segments
from tactiled.errors import CalibrationError

COUNTS_MAX = 65535
#: Flags a tactel may carry (set by the builder, stored in the file, informational for the loader).
KNOWN_FLAGS = ("dead", "non-monotone", "unexercised")
#: Knot counts must lie in this range (one counts-domain beyond each end of 0..65535).
KNOT_COUNTS_RANGE = (-65536.0, 131071.0)
#: A table may not reach |strain| above this anywhere in 0..65535 counts (strain 1 is already
#: 100 % compression): bigger means knots too close together or wrong units.
STRAIN_LIMIT = 1e4
# Float queries this far outside 0..65535 still land in the right tactel (see segments.py).
_COUNTS_DOMAIN = (-65536.0, 2.0 * COUNTS_MAX + 1.0)


def tactel_label(index: int, cols: int) -> str:
    """``"tactel [m, n] (index k)"``: how every message names a tactel (row-major index)."""
    return f"tactel [{index // cols}, {index % cols}] (index {index})"


class LookupTable:
    """Monotone piecewise-linear counts -> strain maps, one per tactel, for one sensor.

    ``counts_knots[k]`` and ``strain_knots[k]`` belong to tactel ``k`` in row-major order
    (``k = m * cols + n``); knot counts may differ between tactels.  Invalid knots raise
    :class:`CalibrationError` naming the tactel.  ``flags[k]`` lists builder flags
    (:data:`KNOWN_FLAGS`); ``rms_residual[k]`` the calibration residual in strain (NaN if unknown).
    """

    def __init__(
        self,
        rows: int,
        cols: int,
        counts_knots: Sequence[ArrayLike],
        strain_knots: Sequence[ArrayLike],
        *,
        sensor_id: int = 0,
        created: str | None = None,
        flags: Sequence[Iterable[str]] | None = None,
        rms_residual: ArrayLike | None = None,
    ) -> None:
        if not (isinstance(rows, int) and isinstance(cols, int) and rows >= 1 and cols >= 1):
            raise CalibrationError(
                f"rows and cols must be positive integers, got {rows!r}, {cols!r}"
            )
        if not (isinstance(sensor_id, int) and not isinstance(sensor_id, bool)
                and 0 <= sensor_id <= 0xFFFF):
            raise CalibrationError(f"sensor_id must be an integer 0..65535, got {sensor_id!r}")
        n = rows * cols
        if len(counts_knots) != n or len(strain_knots) != n:
            raise CalibrationError(
                f"need {n} tactels (rows*cols = {rows}*{cols}), got {len(counts_knots)} counts "
                f"and {len(strain_knots)} strain knot lists"
            )
        self.rows, self.cols = rows, cols
        self._shape, self._size = (rows, cols), n
        self.sensor_id = sensor_id
        self.created = created
        self._counts = [_checked_knots(c, k, cols, "counts") for k, c in enumerate(counts_knots)]
        self._strain = [_checked_knots(s, k, cols, "strain") for k, s in enumerate(strain_knots)]
        for k, (c, s) in enumerate(zip(self._counts, self._strain)):
            _check_pair(c, s, k, cols)
        self.flags: list[tuple[str, ...]] = _checked_flags(flags, n, cols)
        if rms_residual is None:
            self.rms_residual = np.full((rows, cols), np.nan)
        else:
            self.rms_residual = np.asarray(rms_residual, dtype=np.float64).reshape(rows, cols)
        self._forward = _forward_segments(self._counts, self._strain)
        # The inverse's domain is the strain the forward table reaches over 0..65535 counts;
        # clipping queries to it makes every to_counts result land in 0..65535 before rounding.
        ends = self._forward(np.array([[0.0] * n, [float(COUNTS_MAX)] * n])).reshape(2, n)
        reach = np.abs(ends).max(axis=0)
        bad = np.flatnonzero(~(reach <= STRAIN_LIMIT))
        if bad.size:
            k = int(bad[0])
            raise CalibrationError(
                f"{tactel_label(k, cols)}: the table reaches strain {reach[k]:.3g} within counts "
                f"0..{COUNTS_MAX} (limit {STRAIN_LIMIT:g}): knots too close together or mis-scaled"
            )
        self._strain_lo, self._strain_hi = ends[0].copy(), ends[1].copy()
        self._inverse = _inverse_segments(self._counts, self._strain, self._strain_lo,
                                          self._strain_hi)

    # ----------------------------------------------------------------------------------------
    @classmethod
    def linear(
        cls,
        rows: int = 8,
        cols: int = 8,
        counts_per_strain: ArrayLike = 20000.0,
        offset: ArrayLike = 10000.0,
        *,
        sensor_id: int = 0,
    ) -> LookupTable:
        """The identity-like table ``strain = (counts - offset) / counts_per_strain``.

        ``counts_per_strain`` (counts per unit strain, > 0) and ``offset`` (counts at zero
        strain) are scalars or ``(rows, cols)`` arrays.  The defaults put zero load at 10000
        counts and give 10 counts per 0.0005 strain (the default noise sigma), so quantisation
        is far below the noise and 0 .. 2.8 strain fits in 16 bits.  Two knots, at counts 0 and
        65535, so the whole counts domain is inside the table.
        """
        g = np.broadcast_to(np.asarray(counts_per_strain, dtype=np.float64), (rows, cols)).ravel()
        c0 = np.broadcast_to(np.asarray(offset, dtype=np.float64), (rows, cols)).ravel()
        if not (np.all(np.isfinite(g)) and np.all(g > 0)):
            raise ValueError(
                f"counts_per_strain must be positive and finite, got {counts_per_strain!r}"
            )
        if not np.all(np.isfinite(c0)):
            raise ValueError(f"offset must be finite, got {offset!r}")
        ends = np.array([0.0, float(COUNTS_MAX)])
        counts = [ends.copy() for _ in range(rows * cols)]
        strain = [(ends - c0[k]) / g[k] for k in range(rows * cols)]
        return cls(rows, cols, counts, strain, sensor_id=sensor_id)

    # ----------------------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        return self._shape

    def knots(self, m: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Copies of tactel ``[m, n]``'s ``(counts, strain)`` knots."""
        k = m * self.cols + n
        return self._counts[k].copy(), self._strain[k].copy()

    @property
    def dead_mask(self) -> np.ndarray:
        """``(rows, cols)`` bool: tactels flagged dead or unexercised (treat as missing)."""
        bad = [("dead" in f) or ("unexercised" in f) for f in self.flags]
        return np.array(bad, dtype=bool).reshape(self.rows, self.cols)

    def _check_shape(self, a: np.ndarray, what: str) -> None:
        if a.ndim < 2 or a.shape[-2:] != (self.rows, self.cols):
            raise ValueError(
                f"{what} must have shape (..., {self.rows}, {self.cols}), got {a.shape}"
            )

    def to_strain(self, raw: ArrayLike) -> np.ndarray:
        """Linearise raw counts of shape ``(rows, cols)`` or ``(N, rows, cols)`` -> float64 strain.

        Any real dtype; the domain is 0..65535 (see the module docstring).  NaN or inf in -> NaN
        out (never an exception).
        """
        a = raw if isinstance(raw, np.ndarray) else np.asarray(raw)
        if a.shape == self._shape and a.dtype.kind in "ui":  # one frame of counts: the hot path
            return self._forward(a.reshape(self._size).astype(np.float64)).reshape(self._shape)
        self._check_shape(a, "raw counts")
        # (N, T) so every frame of a batch gets the per-tactel offsets by broadcasting.
        x = a.reshape(-1, self._size).astype(np.float64)
        with np.errstate(invalid="ignore"):  # inf/NaN floats become NaN quietly
            return self._forward(x).reshape(a.shape)

    __call__ = to_strain

    def to_counts(self, strain: ArrayLike) -> np.ndarray:
        """Inverse map: strain ``(..., rows, cols)`` -> ``uint16`` counts, rounded and clipped.

        Exact inverse wherever the table is strictly increasing; a strain on a flat run of the
        table maps to the run's upper end in counts.  Strains beyond what 0..65535 counts reach
        give 0 or 65535.  Non-finite strain raises ``ValueError`` (a simulator bug, not data).
        """
        s = np.asarray(strain, dtype=np.float64)
        self._check_shape(s, "strain")
        flat = s.reshape(-1)
        # argmax/argmin find a NaN if there is one: cheaper than isfinite().all() per frame.
        if not (np.isfinite(flat[flat.argmax()]) and np.isfinite(flat[flat.argmin()])):
            raise ValueError("strain must be finite to convert to counts")
        x = np.maximum(s.reshape(-1, self._size), self._strain_lo)
        np.minimum(x, self._strain_hi, out=x)
        c = self._inverse(x)  # flat
        np.rint(c, out=c)
        np.minimum(c, COUNTS_MAX, out=c)  # (the clamps above keep c >= 0 up to rounding)
        np.maximum(c, 0, out=c)
        return c.astype(np.uint16).reshape(s.shape)

    def __repr__(self) -> str:
        knots = sorted({len(c) for c in self._counts})
        return (f"LookupTable(sensor_id={self.sensor_id}, shape={self.shape}, "
                f"knots per tactel={knots[0]}..{knots[-1]})")


# --------------------------------------------------------------------------------------------
# Validation (shared with the file loader, so its messages name the tactel and key)


def _checked_knots(values: ArrayLike, k: int, cols: int, key: str) -> np.ndarray:
    try:
        a = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise CalibrationError(
            f"{tactel_label(k, cols)}: {key!r} is not a list of numbers"
        ) from err
    if a.ndim != 1:
        raise CalibrationError(
            f"{tactel_label(k, cols)}: {key!r} must be a flat list, got shape {a.shape}"
        )
    if a.size < 2:
        raise CalibrationError(
            f"{tactel_label(k, cols)}: {key!r} needs at least 2 knots, got {a.size}"
        )
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise CalibrationError(
            f"{tactel_label(k, cols)}: {key!r} knot {bad[0]} is not finite ({float(a[bad[0]])!r})"
        )
    return a


def _check_pair(c: np.ndarray, s: np.ndarray, k: int, cols: int) -> None:
    if c.size != s.size:
        raise CalibrationError(
            f"{tactel_label(k, cols)}: 'counts' has {c.size} knots but 'strain' has {s.size}"
        )
    bad = np.flatnonzero(np.diff(c) <= 0)
    if bad.size:
        j = int(bad[0])
        raise CalibrationError(
            f"{tactel_label(k, cols)}: 'counts' knots must be strictly increasing, but "
            f"knot {j + 1} ({float(c[j + 1])!r}) <= knot {j} ({float(c[j])!r})"
        )
    lo, hi = KNOT_COUNTS_RANGE
    bad = np.flatnonzero((c < lo) | (c > hi))
    if bad.size:
        j = int(bad[0])
        raise CalibrationError(
            f"{tactel_label(k, cols)}: 'counts' knot {j} ({float(c[j])!r}) outside {lo:g}..{hi:g}"
        )
    bad = np.flatnonzero(np.diff(s) < 0)
    if bad.size:
        j = int(bad[0])
        raise CalibrationError(
            f"{tactel_label(k, cols)}: 'strain' knots must be non-decreasing (monotone table), but "
            f"knot {j + 1} ({float(s[j + 1])!r}) < knot {j} ({float(s[j])!r})"
        )


def _checked_flags(
    flags: Sequence[Iterable[str]] | None, n: int, cols: int
) -> list[tuple[str, ...]]:
    if flags is None:
        return [()] * n
    if len(flags) != n:
        raise CalibrationError(f"flags: need {n} entries, got {len(flags)}")
    out = []
    for k, f in enumerate(flags):
        f = tuple(f)
        unknown = [x for x in f if x not in KNOWN_FLAGS]
        if unknown:
            raise CalibrationError(f"{tactel_label(k, cols)}: unknown flag {unknown[0]!r} "
                                   f"(known: {', '.join(KNOWN_FLAGS)})")
        out.append(f)
    return out


# --------------------------------------------------------------------------------------------
# Segment tables


def _forward_segments(counts: list[np.ndarray], strain: list[np.ndarray]) -> Segments:
    # Overflowing slopes (knots a hair apart) become inf here and are refused by the reach check.
    with np.errstate(over="ignore"):
        slopes = [np.diff(s) / np.diff(c) for c, s in zip(counts, strain)]
    # Segment j starts at knot j; its output is capped at knot j+1's strain (the last: none).
    return Segments(
        starts=[c[:-1] for c in counts],
        y0=[s[:-1] for s in strain],
        slope=slopes,
        cap=[np.append(s[1:-1], np.inf) for s in strain],
        domain=_COUNTS_DOMAIN,
    )


def _inverse_segments(
    counts: list[np.ndarray], strain: list[np.ndarray], lo: np.ndarray, hi: np.ndarray
) -> Segments:
    starts, y0, slope, cap = [], [], [], []
    for c, s in zip(counts, strain):
        with np.errstate(over="ignore", divide="ignore"):
            inv_slope = np.diff(c) / np.diff(s)
        # A strain step too small to invert (slope overflows) is a vertical jump: treat as flat.
        rising = np.flatnonzero((np.diff(s) > 0) & np.isfinite(inv_slope))
        if rising.size == 0:
            # A flat table (a dead tactel): every strain maps back to the middle of its knots.
            starts.append(s[:1])
            y0.append(np.array([0.5 * (c[0] + c[-1])]))
            slope.append(np.zeros(1))
            cap.append(np.array([np.inf]))
            continue
        # Flat forward segments have no inverse; the rising ones tile the strain axis.
        starts.append(s[rising])
        y0.append(c[rising])
        slope.append(inv_slope[rising])
        cap.append(np.append(c[rising[1:]], np.inf))
    return Segments(starts, y0, slope, cap, domain=(float(lo.min()), float(hi.max())))

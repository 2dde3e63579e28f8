"""Build lookup tables from recorded presses with known loads (``tactiled calibrate``)."""

# Per tactel, from the ``N`` pairs (reference strain ``s_i``, raw counts ``c_i``):
#
# 1. **Fit the response counts = f(strain)**, not strain = f(counts): the noise is in the counts
#    while the reference strain is exact by assumption, so regressing counts on strain has no
#    errors-in-variables bias.  ``f`` is continuous piecewise linear (a least-squares fit in the
#    hat-function basis) on knots in strain: the distinct reference levels if there are at most
#    ``knots`` of them, else ``knots`` evenly spaced from the smallest to the largest reference;
#    an interior knot with no data on either side is dropped.
# 2. **Measure**: ``gain`` = total variation of the fitted counts / strain span (counts per unit
#    strain, the tactel's response); ``violation`` = the share of that variation running
#    *backwards* (counts falling as strain rises).
# 3. **Make it monotone** by weighted pool-adjacent-violators on the knot values (weights: the data
#    mass each knot carries), then **invert**: table knots are (fitted counts, strain); knots the
#    PAV pooled to equal counts merge into one, at their mean strain.
# 4. **Flag** (after all tactels are fitted): *unexercised* if the tactel's reference strain spans
#    less than ``min_strain_span``; *dead* if its gain is below ``dead_fraction`` of the median
#    gain of the exercised tactels; *non-monotone* if ``violation > nonmonotone_fraction``.
#    Dead and unexercised tactels get a flat table at strain 0 (they read 0 after zeroing and can
#    never raise a contact); non-monotone ones keep their best monotone fit.  All flags go into the
#    file so the pipeline can mask those tactels.
# 5. **Residuals**: the finished table applied to the recorded counts minus the reference, RMS and
#    max per tactel, in strain.  With good data the RMS is about ``noise_counts / gain``.

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactiled.calibration.isotonic import isotonic_increasing
from tactiled.calibration.lut import LookupTable
from tactiled.calibration.presses import PressSet
from tactiled.errors import CalibrationError

DEFAULT_KNOTS = 8
DEFAULT_DEAD_FRACTION = 0.1
DEFAULT_NONMONOTONE_FRACTION = 0.1
DEFAULT_MIN_STRAIN_SPAN = 0.005  # 0.5 % strain: 10 sigma of the default noise model


@dataclass
class CalibrationReport:
    """Result of :func:`build_table`: the table and per-tactel diagnostics, all ``(rows, cols)``.

    ``rms_residual``, ``max_residual``: strain.  ``gain``: counts per unit strain.
    ``violation``: share of the response running backwards (0..1).  ``knots``: knots used.
    """

    table: LookupTable
    rms_residual: np.ndarray
    max_residual: np.ndarray
    gain: np.ndarray
    violation: np.ndarray
    knots: np.ndarray
    dead: np.ndarray
    non_monotone: np.ndarray
    unexercised: np.ndarray
    presses: int
    options: dict[str, Any] = field(default_factory=dict)

    @property
    def flagged(self) -> np.ndarray:
        """Tactels with any flag."""
        return self.dead | self.non_monotone | self.unexercised

    def format(self) -> str:
        """The residual grid and a summary, as ``tactiled calibrate`` prints them."""
        return format_report(self)


def build_table(
    presses: PressSet,
    *,
    knots: int = DEFAULT_KNOTS,
    sensor_id: int | None = None,
    dead_fraction: float = DEFAULT_DEAD_FRACTION,
    nonmonotone_fraction: float = DEFAULT_NONMONOTONE_FRACTION,
    min_strain_span: float = DEFAULT_MIN_STRAIN_SPAN,
    created: str | None = None,
) -> CalibrationReport:
    """Fit one monotone counts -> strain table per tactel from ``presses`` (see module doc).

    ``sensor_id`` overrides ``presses.sensor_id``; one of them must be given, and if both are
    they must agree.  Bad options raise ``ValueError``; unusable data ``CalibrationError``.
    """
    if not (isinstance(knots, int) and knots >= 2):
        raise ValueError(f"knots must be an integer >= 2, got {knots!r}")
    for name, value in (("dead_fraction", dead_fraction),
                        ("nonmonotone_fraction", nonmonotone_fraction)):
        if not 0.0 <= value <= 1.0:
            raise ValueError(f"{name} must lie in [0, 1], got {value!r}")
    if not min_strain_span >= 0.0:
        raise ValueError(f"min_strain_span must be >= 0, got {min_strain_span!r}")
    sid = _resolve_sensor_id(presses.sensor_id, sensor_id)

    rows, cols = presses.shape
    n_tactels = rows * cols
    s_all = presses.strain_ref.reshape(len(presses), n_tactels)
    c_all = presses.counts.reshape(len(presses), n_tactels).astype(np.float64)

    gain = np.zeros(n_tactels)
    violation = np.zeros(n_tactels)
    span = np.ptp(s_all, axis=0)
    fits: list[tuple[np.ndarray, np.ndarray]] = []
    for k in range(n_tactels):
        s, c = s_all[:, k], c_all[:, k]
        if span[k] <= 0.0:
            fits.append((np.array([s[0]]), np.array([c.mean()])))
            continue
        kn, coef, weight = _fit_response(s, c, knots)
        steps = np.diff(coef)
        variation = float(np.abs(steps).sum())
        gain[k] = variation / float(kn[-1] - kn[0])
        violation[k] = float(np.clip(-steps, 0.0, None).sum()) / variation if variation > 0 else 0.0
        fits.append((kn, isotonic_increasing(coef, weight)))

    unexercised = span < max(min_strain_span, np.finfo(float).tiny)
    exercised_gain = gain[~unexercised]
    if exercised_gain.size == 0:
        raise CalibrationError(
            f"no tactel's reference strain spans min_strain_span = {min_strain_span}: the presses "
            f"do not exercise the sensor (largest span {float(span.max()):.3g})"
        )
    dead = (gain < dead_fraction * float(np.median(exercised_gain))) & ~unexercised
    non_monotone = (violation > nonmonotone_fraction) & ~dead & ~unexercised

    counts_knots, strain_knots, flags = [], [], []
    for k in range(n_tactels):
        tags: list[str] = []
        if unexercised[k]:
            tags.append("unexercised")
        if dead[k]:
            tags.append("dead")
        if non_monotone[k]:
            tags.append("non-monotone")
        table_knots = None if (dead[k] or unexercised[k]) else _invert(*fits[k])
        if table_knots is None:
            # Flat at strain 0 around the tactel's typical counts: it reads 0 and never touches.
            centre = float(np.rint(np.median(c_all[:, k])))
            table_knots = (np.array([centre - 1.0, centre + 1.0]), np.zeros(2))
            if not (dead[k] or unexercised[k]):
                tags.append("dead")  # responded to nothing the fit could resolve
        counts_knots.append(table_knots[0])
        strain_knots.append(table_knots[1])
        flags.append(tags)

    provisional = LookupTable(rows, cols, counts_knots, strain_knots, sensor_id=sid,
                              created=created, flags=flags)
    resid = provisional.to_strain(presses.counts).reshape(len(presses), n_tactels) - s_all
    rms = np.sqrt(np.mean(resid**2, axis=0))
    table = LookupTable(rows, cols, counts_knots, strain_knots, sensor_id=sid, created=created,
                        flags=flags, rms_residual=rms.reshape(rows, cols))
    dead_final = np.array(["dead" in f for f in flags])
    grid = (rows, cols)
    return CalibrationReport(
        table=table,
        rms_residual=rms.reshape(grid),
        max_residual=np.abs(resid).max(axis=0).reshape(grid),
        gain=gain.reshape(grid),
        violation=violation.reshape(grid),
        knots=np.array([len(c) for c in counts_knots]).reshape(grid),
        dead=dead_final.reshape(grid),
        non_monotone=non_monotone.reshape(grid),
        unexercised=unexercised.reshape(grid),
        presses=len(presses),
        options={"knots": knots, "dead_fraction": dead_fraction,
                 "nonmonotone_fraction": nonmonotone_fraction,
                 "min_strain_span": min_strain_span},
    )


def _resolve_sensor_id(from_file: int | None, given: int | None) -> int:
    if given is not None and not (isinstance(given, int) and 0 <= given <= 0xFFFF):
        raise ValueError(f"sensor_id must be an integer 0..65535, got {given!r}")
    if from_file is None and given is None:
        raise CalibrationError("the press file has no 'sensor_id'; give one with --sensor-id")
    if from_file is not None and given is not None and from_file != given:
        raise CalibrationError(
            f"the press file was recorded from sensor {from_file}, not {given} (--sensor-id)"
        )
    return int(given if given is not None else from_file)  # type: ignore[arg-type]


def _hat_basis(s: np.ndarray, kn: np.ndarray) -> np.ndarray:
    """``(N, K)`` continuous piecewise-linear basis on knots ``kn`` (data lie in their range)."""
    j = np.clip(np.searchsorted(kn, s, side="right") - 1, 0, kn.size - 2)
    t = (s - kn[j]) / (kn[j + 1] - kn[j])
    basis = np.zeros((s.size, kn.size))
    rows = np.arange(s.size)
    basis[rows, j] = 1.0 - t
    basis[rows, j + 1] += t
    return basis


def _fit_response(
    s: np.ndarray, c: np.ndarray, knots: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares piecewise-linear counts(strain): knots, knot values, knot weights."""
    levels = np.unique(s)
    kn = levels if levels.size <= knots else np.linspace(levels[0], levels[-1], knots)
    while True:
        basis = _hat_basis(s, kn)
        weight = basis.sum(axis=0)
        empty = np.flatnonzero(weight[1:-1] <= 0.0) + 1
        if empty.size == 0:
            break
        kn = np.delete(kn, empty[0])  # one at a time: a removal changes its neighbours' support
    coef = np.linalg.lstsq(basis, c, rcond=None)[0]
    return kn, coef, weight


def _invert(kn: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Table knots (strictly increasing counts, non-decreasing strain) from a monotone fit,
    or ``None`` if the fit is flat (no two distinct counts)."""
    uniq, start = np.unique(counts, return_index=True)
    if uniq.size < 2:
        return None
    # np.unique sorts; counts is non-decreasing, so runs of equal values are contiguous.
    ends = np.append(start[1:], counts.size)
    strain = np.array([kn[a:b].mean() for a, b in zip(start, ends)])
    return uniq, strain


# --------------------------------------------------------------------------------------------
# Report text


def _names(mask: np.ndarray) -> str:
    idx = [f"[{m}, {n}]" for m, n in np.argwhere(mask)]
    if not idx:
        return "0"
    shown = ", ".join(idx[:8]) + (", ..." if len(idx) > 8 else "")
    return f"{len(idx)} ({shown})"


def format_report(report: CalibrationReport) -> str:
    """Residual grid (units of 1e-4 strain, i.e. 0.01 %) with flag letters, then a summary."""
    rms = report.rms_residual
    rows, cols = rms.shape
    lines = [
        "RMS residual per tactel, in 1e-4 strain (rows m along x, columns n around y);",
        "flags: D dead, N non-monotone, U unexercised",
        "      " + "".join(f"{'n=' + str(n):>8}" for n in range(cols)),
    ]
    for m in range(rows):
        cells = []
        for n in range(cols):
            flag = ("U" if report.unexercised[m, n] else "D" if report.dead[m, n]
                    else "N" if report.non_monotone[m, n] else " ")
            cells.append(f"{rms[m, n] * 1e4:7.1f}{flag}")
        lines.append(f"m={m:<4}" + "".join(cells))
    ok = ~report.flagged
    table = report.table
    lines.append("")
    lines.append(f"sensor {table.sensor_id}: {report.presses} presses, {rows}x{cols} tactels, "
                 f"{int(report.knots.min())}..{int(report.knots.max())} knots per tactel")
    if ok.any():
        worst = np.unravel_index(np.argmax(np.where(ok, rms, -1.0)), rms.shape)
        lines.append(
            f"good tactels: {int(ok.sum())}; RMS residual median {np.median(rms[ok]):.2e}, "
            f"worst {rms[worst]:.2e} at [{worst[0]}, {worst[1]}]; max |residual| "
            f"{report.max_residual[ok].max():.2e} (strain)"
        )
        lines.append(f"gain median {np.median(report.gain[ok]):.0f} counts per unit strain")
    else:
        lines.append("good tactels: 0")
    lines.append(f"dead: {_names(report.dead)}; non-monotone: {_names(report.non_monotone)}; "
                 f"unexercised: {_names(report.unexercised)}")
    return "\n".join(lines)

"""Is a radius's linearised sigma valid?  One point of its profile likelihood says."""

# The Cramer-Rao sigma is the curvature of chi^2 at the solution: it is the error bar only
# where chi^2 stays quadratic over the interval it spans.  A radius under a cover that is
# thick beside the contact is not: below some size every contact is a point (a line: a knife
# edge) to the tactels, and chi^2 is flat from there down to zero (measured on a 4x6 pad of
# 4.7 mm pitch under a 2.5-3 mm cover: a 10 mm cylinder at 1 N fits anywhere from 1 to 30 mm
# within a chi^2 of 1, and sometimes lands at 120-450 mm with a linearised sigma of 15 %, 25
# of its sigmas above the truth).  So where the radius's relative sigma is large enough for
# the question to matter (``TEST_RELATIVE_SIGMA``), chi^2 is minimised again with the log
# radius held at two of its sigmas below the solution.  Were chi^2 quadratic it would rise by
# 4 there; if it rises by less than ``FLAT_CHI2`` (1: the likelihood's own 1-sigma interval
# reaches past the linearised 2-sigma point, so the sigma understates that side over two-fold)
# the value is not a measurement and is withheld, with the reason and the profile's figure;
# between that and 4 its sigma is widened so the tested point lies ``sqrt(rise)`` sigmas away,
# as the profile says.
# The test costs one search, started at the solution, within the fit's budget; a search the
# budget cuts short is not used (its chi^2 only overstates the rise: never a withholding).

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tactiled.fit.params import TOO_LIGHT

#: The radius's relative 1-sigma (of its log) above which its lower side is tested.
TEST_RELATIVE_SIGMA = 0.1
#: How far below the solution the profile is evaluated, in the radius's linearised sigmas.
PROFILE_SIGMAS = 2.0
#: A rise of chi^2 below this there (a quadratic rises by PROFILE_SIGMAS^2 = 4): flat.
FLAT_CHI2 = 1.0
#: A contact of this radius (mm) is an edge (the paper's Table 2 label: r1 < 1 mm): a radius
#: that an edge explains as well, within two sigmas, is not resolved.
EDGE_MM = 1.0
#: The words of the reason (the tracker keeps such a radius withheld until the frames it
#: pools give it a relative sigma of at most ``TEST_RELATIVE_SIGMA``, where it is not tested).
FLAT = "the likelihood is flat below it"
#: ... and of a line's orientation found flat (the one rule withholds the line's place with it)
FLAT_ACROSS = "the likelihood is flat across it"
#: A line's orientation whose linearised 1-sigma exceeds this (deg) has its profile tested
#: on both sides (two more searches; below it the test is not worth its cost: a line whose
#: angle is that sharp lies well above the noise along a window of several tactels).
ANGLE_TEST_SIGMA = 2.0
#: Where a tested line's angle profile is also evaluated: these many degrees from the
#: solution (the half-turn round).  A weak line seen by a few tactels can have a second valley
#: of its likelihood far from the solution's (measured: 15-70 deg off on the 12x32 mat at 1 N),
#: which the two points PROFILE_SIGMAS sigmas either side cannot see.
ANGLE_SCAN_DEG = (30.0, 60.0, 90.0, 120.0, 150.0)


def flat_below(fitter: Any, fr: Any, kind: int, p: np.ndarray, steps: np.ndarray,
               bounds: tuple[np.ndarray, np.ndarray], python_residual: Any, chi2: float,
               r: float | None, sd_r: float | None) -> str | float | None:
    """The radius ``r`` (mm; 1-sigma ``sd_r``) at the solution ``p`` (its first entry the log
    radius, chi^2 ``chi2``) on its profile likelihood: the reason to withhold it (flat
    below it), or its honest sigma where the profile rises more slowly than the linearised
    sigma says but by at least ``FLAT_CHI2`` (the distance to the tested point over the
    square root of the rise: that point lies ``sqrt(rise)`` sigmas away), or None to keep it
    as it is.  ``fitter`` searches (``Fitter._search``) the window ``fr`` of the model
    ``kind`` with the log radius pinned by ``bounds``."""
    if r is None or sd_r is None or not (r > 0.0 and sd_r > 0.0):
        return None
    s = sd_r / r  # the log radius's sigma
    if s <= TEST_RELATIVE_SIGMA:
        return None
    lo, hi = np.array(bounds[0], dtype=float), np.array(bounds[1], dtype=float)
    at = float(p[0]) - PROFILE_SIGMAS * s
    if not at > lo[0]:
        return None
    rise = _rise(fitter, fr, kind, p, steps, (lo, hi), python_residual, chi2, at)
    if rise is None:
        return None
    if rise >= PROFILE_SIGMAS ** 2:
        # quadratic where it was tested; but a likelihood with a second valley at a point
        # contact (a line's radius on a coarse pad: 700 mm fitted, 10 mm true) rises there
        # and falls again below: a point contact within two sigmas is no resolved radius
        edge = math.log(EDGE_MM)
        if r > 2.0 * EDGE_MM and edge > lo[0]:
            rise_edge = _rise(fitter, fr, kind, p, steps, (lo, hi), python_residual, chi2, edge)
            if rise_edge is not None and rise_edge < PROFILE_SIGMAS ** 2:
                return (f"{TOO_LIGHT}: {FLAT} (an edge, {EDGE_MM:g} mm, explains the frame "
                        f"within two sigmas: chi^2 {max(rise_edge, 0.0):.2g} above): its sigma "
                        "does not hold")
        return None
    if rise >= FLAT_CHI2:
        return r * (1.0 - math.exp(at - float(p[0]))) / math.sqrt(rise)
    return (f"{TOO_LIGHT}: {FLAT} (chi^2 rises by {max(rise, 0.0):.2g}, "
            f"not {PROFILE_SIGMAS ** 2:g}, at a radius {PROFILE_SIGMAS:g} sigmas smaller, "
            f"{r * math.exp(-PROFILE_SIGMAS * s):.3g} mm): its sigma does not hold")


def angle_profile(fitter: Any, fr: Any, kind: int, p: np.ndarray, steps: np.ndarray,
                  bounds: tuple[np.ndarray, np.ndarray], python_residual: Any, chi2: float,
                  index: int, sd_deg: float | None,
                  scan: tuple[float, ...] = ANGLE_SCAN_DEG) -> str | float | None:
    """A line's orientation (the parameter ``index`` of ``p``, rad; its linearised 1-sigma
    ``sd_deg``, deg) on its profile likelihood, as :func:`flat_below` tests a radius but on
    both sides (a line turned either way leaves the window alike): chi^2 minimised again with
    the angle held ``PROFILE_SIGMAS`` sigmas either side.  The smaller rise decides: below
    ``FLAT_CHI2`` the reason to withhold it, below ``PROFILE_SIGMAS^2`` its honest sigma (that
    point lies ``sqrt(rise)`` sigmas away), else None.  A weak line in a small window (4-5
    noise sigmas over 4x4 tactels of a 12x32 mat) has a likelihood far from quadratic in its
    angle: its linearised sigma said 3 deg where it was 15-20 deg off.  ``scan``: the offsets
    (deg) round the half-turn also evaluated; none for an ellipse, which turned 90 deg with its
    radii swapped is the same one (:meth:`tactiled.fit.point.PointFit.fit`)."""
    if sd_deg is None or not sd_deg > ANGLE_TEST_SIGMA:
        return None
    # (distance in deg, rise of chi^2 there): the two near points, then the scan round the turn
    away = [PROFILE_SIGMAS * sd_deg] * 2 + [min(d, 180.0 - d) for d in scan]
    offsets = [-PROFILE_SIGMAS * sd_deg, PROFILE_SIGMAS * sd_deg, *scan]
    points = []
    for dist, off in zip(away, offsets):
        rise = _rise(fitter, fr, kind, p, steps, bounds, python_residual, chi2,
                     float(p[index]) + math.radians(off), index)
        if rise is not None and rise < PROFILE_SIGMAS ** 2 and dist > 0.0:
            points.append((dist, rise))
    if not points:
        return None
    flat = [(d, r) for d, r in points if r < FLAT_CHI2]
    if flat:
        dist, rise = max(flat)
        return (f"orientation not observable: {FLAT_ACROSS} (chi^2 rises by "
                f"{max(rise, 0.0):.2g}, not {(dist / sd_deg) ** 2:.3g}, {dist:.3g} deg to one "
                "side): its sigma does not hold")
    # each point lies sqrt(rise) sigmas away: the widest sigma that says so
    return max(dist / math.sqrt(rise) for dist, rise in points)


def _rise(fitter: Any, fr: Any, kind: int, p: np.ndarray, steps: np.ndarray,
          bounds: tuple[np.ndarray, np.ndarray], python_residual: Any, chi2: float,
          at: float, index: int = 0) -> float | None:
    """chi^2 minimised with the parameter ``index`` (default the log radius) held at ``at``,
    less ``chi2``; None where the search did not converge."""
    lo, hi = bounds[0].copy(), bounds[1].copy()
    lo[index] = hi[index] = at
    start = np.array(p, dtype=float)
    start[index] = at
    sol, _ = fitter._search(fr, kind, [start], steps, (lo, hi), fitter.options.max_iter,
                            1e-2, python_residual)
    if not sol.converged or not math.isfinite(sol.cost):
        return None
    return sol.cost * (fr.peak / fitter.sigma) ** 2 - chi2


def withhold_flat(values: dict, std: dict, reasons: dict[str, str], why: str | float | None,
                  key: str = "r1_mm") -> None:
    """Apply :func:`flat_below`'s (or :func:`angle_profile`'s) answer ``why`` to ``key``:
    withhold it for a reason, widen its sigma to a figure, leave it for None."""
    if why is None or values.get(key) is None:
        return
    if isinstance(why, float):
        if why > (std.get(key) or 0.0):
            std[key] = why
            reasons.setdefault(key, "poorly determined: its sigma widened to its profile "
                               "likelihood, which rises more slowly than its curvature says")
        return
    values[key] = None
    std[key] = None
    reasons[key] = why

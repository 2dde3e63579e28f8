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
# The test costs one search, started at the solution, within the fit's budget; a search its
# iterations or the budget cut short still bounds the profile from above (its chi^2 only
# overstates the rise: never a withholding or a widening the profile would not make).
# A line's orientation is tested the same way at several points (``angle_scan``): every
# point is one more constrained search, and every point within ``REACH_CHI2`` widens the
# angle's sigma, and those of the values that trade with it, to put it ``sqrt(rise)``
# sigmas away.  An ellipse's orientation is tested at its near points too, but its profile is bounded
# (a circle caps the rise anywhere) and often one-sided: a near point below ``FLAT_CHI2``
# widens its sigma as any point does, and it is withheld only where the widest sigma the
# points imply is over ``MAX_ANGLE_SIGMA`` (``angle_scan``'s ``bounded``).

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactiled.fit.params import MAX_ANGLE_SIGMA, TOO_LIGHT

#: The radius's relative 1-sigma (of its log) above which its lower side is tested.
TEST_RELATIVE_SIGMA = 0.1
#: How far below the solution the profile is evaluated, in the radius's linearised sigmas.
PROFILE_SIGMAS = 2.0
#: A rise of chi^2 below this there (a quadratic rises by PROFILE_SIGMAS^2 = 4): flat.
FLAT_CHI2 = 1.0
#: A contact of this radius (mm) is an edge (the paper's Table 2 label: r1 < 1 mm): a radius
#: that an edge explains as well, within two sigmas, is not resolved.
EDGE_MM = 1.0
#: An ellipse's larger radius whose likelihood rises slowly above it (under ``PROFILE_SIGMAS^2``
#: at ``PROFILE_SIGMAS`` sigmas) and whose sigma, so widened, is at least this many times it
#: is withheld: its curvature lies within half a sigma of zero (a cylinder's).  Measured on
#: the paper's finger's light ellipsoids (the frames of ``tactiled bench --suite sensors
#: --sensor fearing1988 --seed N``, seeds 1-3, fitted one by one): such values lay 5-16
#: Cramer-Rao bounds from the truth; at 1 instead of 2, 13-19 % of the values the bound at
#: the truth resolves were withheld, at 2, 4-9 %.
CYLINDER_RELATIVE_SIGMA = 2.0
#: An ellipse whose sphere (its radii held equal) raises chi^2 by less than this is not told
#: from a circle: its orientation is withheld (:func:`round_test`); by less than
#: ``ROUND_SCAN_CHI2`` (radii told apart by under five sigmas) its orientation's profile is
#: evaluated at ``ROUND_SCAN_DEG`` from the solution.
ROUND_CHI2 = FLAT_CHI2
ROUND_SCAN_CHI2 = 25.0
ROUND_SCAN_DEG = (-30.0, -15.0, 15.0, 30.0, 45.0)
#: The words of the reason (the tracker keeps such a radius withheld until the frames it
#: pools give it a relative sigma of at most ``TEST_RELATIVE_SIGMA``, where it is not tested).
FLAT = "the likelihood is flat below it"
#: ... and of a line's orientation found flat (the one rule withholds the line's place with it)
FLAT_ACROSS = "the likelihood is flat across it"
#: A line's orientation whose linearised 1-sigma exceeds this (deg) has its profile tested
#: on both sides (two more searches; below it the test is not worth its cost: a line whose
#: angle is that sharp lies well above the noise along a window of several tactels).
ANGLE_TEST_SIGMA = 2.0
#: The near points of an angle's profile, in PROFILE_SIGMAS linearised sigmas to either side:
#: at 2 sigmas (a quadratic rises by 4 there) and, for a line, at 4 (by 16: a likelihood
#: whose shoulder is flatter there puts the value beyond the 4 sigmas it claims; below a rise
#: of FLAT_CHI2 there it is flat).
NEAR_STEPS = (1.0,)
LINE_NEAR_STEPS = (2.0, 4.0)
#: A line's orientation is tested at its near points wherever its linearised 1-sigma exceeds
#: this (deg; the scan round the half-turn where it exceeds ANGLE_TEST_SIGMA): on the 12x32
#: mat a 1 N line's single-frame fits with sigmas of 1.1-1.9 deg were 6-20 deg off (the band
#: of a line at 4 noise sigmas holds a piece of it; the likelihood's shoulders are flat).
LINE_TEST_SIGMA = 0.5
#: Where a tested line's angle profile is also evaluated: these many degrees from the
#: solution (the half-turn round).  A weak line seen by a few tactels can have a second valley
#: of its likelihood far from the solution's (measured: 15-70 deg off on the 12x32 mat at 1 N),
#: which the two points PROFILE_SIGMAS sigmas either side cannot see.
ANGLE_SCAN_DEG = (30.0, 60.0, 90.0, 120.0, 150.0)
#: A profile point whose chi^2 rises by less than this (a quadratic's rise 4 sigmas away) lies
#: within 4 sigmas of the solution: every tested point below it widens the sigma to put it
#: ``sqrt(rise)`` sigmas away, so the reported 2- and 4-sigma intervals reach every point the
#: profile puts within them (a weak line's likelihood has long flat shoulders: on the 12x32 mat
#: at 1 N a point 50 deg off rose by 5.5 where the linearised sigma, 6 deg, said 70).
REACH_CHI2 = 16.0
#: Iterations of a profile point's search: one stopped short still bounds the profile from
#: above (a line held far from its angle can crawl its load towards zero for the whole cap).
PROFILE_ITERATIONS = 10
#: A profile point whose chi^2 lies this far below the solution's shows the search stopped in
#: a valley that is not the deepest (a weak line's fit locked 40-85 deg off): the fit is
#: searched again from there (:class:`AngleProfile` ``deeper``).
DEEPER_CHI2 = 0.5


@dataclass
class AngleProfile:
    """What :func:`angle_scan` found on a line's (or ellipse's) orientation profile.

    ``why``: :func:`withhold_flat`'s answer for the angle (a reason, a widened sigma in deg, or
    None); ``points``: ``(rise, solution)`` of each converged point within ``REACH_CHI2`` (the
    solution vector with the angle held there, for the other values' widening:
    :func:`widen_by_points`); ``deeper``: the solution vector of the lowest point below the
    fit's chi^2 by over ``DEEPER_CHI2`` (the fit is in the wrong valley), else None."""

    why: str | float | None = None
    points: list[tuple[float, np.ndarray]] = field(default_factory=list)
    deeper: np.ndarray | None = None


def flat_below(fitter: Any, fr: Any, kind: int, p: np.ndarray, steps: np.ndarray,
               bounds: tuple[np.ndarray, np.ndarray], python_residual: Any, chi2: float,
               r: float | None, sd_r: float | None,
               seen: list[tuple[float, np.ndarray]] | None = None) -> str | float | None:
    """The radius ``r`` (mm; 1-sigma ``sd_r``) at the solution ``p`` (its first entry the log
    radius, chi^2 ``chi2``) on its profile likelihood: the reason to withhold it (flat
    below it), or its honest sigma where the profile rises more slowly than the linearised
    sigma says but by at least ``FLAT_CHI2`` (the distance to the tested point over the
    square root of the rise: that point lies ``sqrt(rise)`` sigmas away), or None to keep it
    as it is.  ``fitter`` searches (``Fitter._search``) the window ``fr`` of the model
    ``kind`` with the log radius pinned by ``bounds``.  ``seen``: where given, the tested
    point's ``(rise, solution)`` is appended to it if it rises by under ``REACH_CHI2`` (for
    :func:`widen_by_points`)."""
    if r is None or sd_r is None or not (r > 0.0 and sd_r > 0.0):
        return None
    s = sd_r / r  # the log radius's sigma
    if s <= TEST_RELATIVE_SIGMA:
        return None
    lo, hi = np.array(bounds[0], dtype=float), np.array(bounds[1], dtype=float)
    at = float(p[0]) - PROFILE_SIGMAS * s
    if not at > lo[0]:
        return None
    got = _held(fitter, fr, kind, p, steps, (lo, hi), python_residual, chi2, at)
    if got is None:
        return None
    rise = got[0]
    if seen is not None and rise < REACH_CHI2:
        seen.append(got)
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
                  scan: tuple[float, ...] = ANGLE_SCAN_DEG,
                  bounded: bool = False) -> str | float | None:
    """The answer of :func:`angle_scan` for the angle alone (``AngleProfile.why``)."""
    return angle_scan(fitter, fr, kind, p, steps, bounds, python_residual, chi2, index,
                      sd_deg, scan, bounded=bounded).why


def angle_scan(fitter: Any, fr: Any, kind: int, p: np.ndarray, steps: np.ndarray,
               bounds: tuple[np.ndarray, np.ndarray], python_residual: Any, chi2: float,
               index: int, sd_deg: float | None, scan: tuple[float, ...] = ANGLE_SCAN_DEG,
               starts_at: Callable[[np.ndarray], list[np.ndarray]] | None = None,
               known: list[tuple[float, np.ndarray]] = (),
               test_sigma: float = ANGLE_TEST_SIGMA,
               near_steps: tuple[float, ...] = NEAR_STEPS,
               cap: int | None = None, bounded: bool = False) -> AngleProfile:
    """A line's orientation (the parameter ``index`` of ``p``, rad; its linearised 1-sigma
    ``sd_deg``, deg) on its profile likelihood, as :func:`flat_below` tests a radius but on
    both sides (a line turned either way leaves the window alike): chi^2 minimised again with
    the angle held ``PROFILE_SIGMAS`` sigmas either side, and at the offsets ``scan`` (deg)
    round the half-turn (none for an ellipse, which turned 90 deg with its radii swapped is
    the same one: :meth:`tactiled.fit.point.PointFit.fit`).  A point below ``FLAT_CHI2``
    withholds the angle; else every point below ``REACH_CHI2`` widens its sigma so that point
    lies ``sqrt(rise)`` sigmas away (the widest such sigma); else it stays.  A weak line in a
    small window (4-5 noise sigmas over 4x4 tactels of a 12x32 mat) has a likelihood far
    from quadratic in its angle: its linearised sigma said 3 deg where it was 15-20 deg off.
    ``starts_at(start)``: the starts of a scan point's search in place of ``start`` (``p``
    with the angle held; a line turned about its window's centre can miss the tactels that
    see it), the lowest search kept.  ``known``: points of the same profile already searched, ``(chi^2,
    solution)`` (a scan made from another valley's solution), taken as they are.  Tested
    where ``sd_deg`` exceeds ``test_sigma``; the near points at ``near_steps`` times
    ``PROFILE_SIGMAS`` sigmas to either side; ``cap``: each point's search within that many
    iterations, one stopped short kept as a bound (:func:`_held`'s ``bounded``), else the
    fit's own cap, converged searches only.  ``bounded``: the profile of an ellipse's
    orientation, which a circle bounds (it rises by at most the circle's chi^2 anywhere, and
    one side can rise steeply where the other stays low): a point below ``FLAT_CHI2`` widens
    the sigma as any other does (``sqrt(rise)`` sigmas away, the profile's honest interval),
    and the angle is withheld only where that sigma is over ``MAX_ANGLE_SIGMA``."""
    out = AngleProfile()
    if sd_deg is None or not sd_deg > test_sigma:
        return out
    # (distance in deg, rise of chi^2 there): the two near points, then the scan round the turn
    if not sd_deg > ANGLE_TEST_SIGMA:
        scan = ()  # a sharper angle's far valleys lie beyond reach: its near points only
    near = [k * PROFILE_SIGMAS * sd_deg for k in near_steps]
    away = [d for d in near for _ in (0, 1)] + [min(d, 180.0 - d) for d in scan]
    offsets = [o for d in near for o in (-d, d)] + list(scan)
    points = []
    lowest = -DEEPER_CHI2
    # (the near points' searches start at the solution; the scan's also where starts_at says)
    tried = [(dist, _held(fitter, fr, kind, p, steps, bounds, python_residual, chi2,
                          float(p[index]) + math.radians(off), index,
                          starts_at if i >= 2 * len(near) else None, cap,
                          bounded=cap is not None))
             for i, (dist, off) in enumerate(zip(away, offsets))]
    for c2, q in known:
        d = abs(math.degrees(float(q[index]) - float(p[index]))) % 180.0
        tried.append((min(d, 180.0 - d), (c2 - chi2, q)))
    for dist, got in tried:
        if got is None:
            continue
        rise, sol = got
        if rise < lowest:
            lowest, out.deeper = rise, sol
        if rise < REACH_CHI2 and dist > 0.0:
            points.append((dist, rise))
            out.points.append((rise, sol))
    if not points:
        return out
    # flat: a point at least PROFILE_SIGMAS sigmas away (where a quadratic rises by 4) that
    # rises by less than FLAT_CHI2 (a known point nearer says nothing of the kind)
    flat = [(d, r) for d, r in points if r < FLAT_CHI2 and d >= PROFILE_SIGMAS * sd_deg * 0.999]
    if bounded:
        out.why = _bounded_sigma(points, sd_deg)
        return out
    if flat:
        dist, rise = max(flat)
        out.why = (f"orientation not observable: {FLAT_ACROSS} (chi^2 rises by "
                   f"{max(rise, 0.0):.2g}, not {(dist / sd_deg) ** 2:.3g}, {dist:.3g} deg to "
                   "one side): its sigma does not hold")
        return out
    # each point lies sqrt(rise) sigmas away: the widest sigma that says so
    widest = max(dist / math.sqrt(max(rise, FLAT_CHI2)) for dist, rise in points)
    out.why = widest if widest > sd_deg else None
    return out


def _bounded_sigma(points: list[tuple[float, float]], sd_deg: float) -> str | float | None:
    """The sigma (deg) of a bounded orientation profile whose tested points ``(distance deg,
    rise)`` each lie ``sqrt(rise)`` sigmas away: the widest they imply, None where that is
    not over ``sd_deg``, the reason to withhold it where it is over ``MAX_ANGLE_SIGMA``."""
    dist, rise = max(points, key=lambda pt: pt[0] / math.sqrt(max(pt[1], 1e-12)))
    wide = dist / math.sqrt(max(rise, 1e-12))
    if wide > MAX_ANGLE_SIGMA:
        return (f"orientation not observable: {FLAT_ACROSS} (the ellipse turned {dist:.3g} "
                f"deg explains the frame within a chi^2 of {max(rise, 0.0):.2g}: a sigma over "
                f"{MAX_ANGLE_SIGMA:g} deg): its sigma does not hold")
    return wide if wide > sd_deg else None


#: A sphere's radius profile (:func:`radius_points`) is evaluated on either side of the
#: solution at steps of ``PROFILE_SIGMAS`` of the log radius's linearised sigmas, at most
#: ``RADIUS_STEP_LN`` (a factor of 2) each, up to ``RADIUS_STEPS`` per side and, below,
#: down to ``POINT_MM`` (a contact that small is a point to any pitch of 1 mm or more: the
#: profile is flat from there down and the place no longer moves).  A light ball's
#: fit on a coarse pad (a 6x4 pad of 4 mm pitch under a 2 mm cover) can land at a radius
#: several times too small or too large (0.7 or 19 mm for 5.2), the likelihood flat toward
#: the truth, and the linearised sigmas of the place and the radius there a quarter of the
#: bound at the truth.
RADIUS_STEP_LN = math.log(2.0)
RADIUS_STEPS = 8
POINT_MM = 0.25 * EDGE_MM
#: The reason a value widened by a radius's profile points gives.
WIDENED_BY_RADIUS = ("poorly determined: its sigma widened to the profile likelihood of the "
                     "radius it trades with")


def radius_points(fitter: Any, fr: Any, kind: int, p: np.ndarray, steps: np.ndarray,
                  bounds: tuple[np.ndarray, np.ndarray], python_residual: Any, chi2: float,
                  r: float | None, sd_r: float | None) -> list[tuple[float, np.ndarray]]:
    """``(rise, solution)`` of the radius's profile points on either side of the solution
    ``p`` (its first entry the log radius ``ln r``, 1-sigma ``sd_r`` mm; chi^2 ``chi2``) that
    lie within ``REACH_CHI2``: chi^2 minimised again with ``ln r`` held a step further out each
    time (``RADIUS_STEP_LN``, ``RADIUS_STEPS``), each search started at the one before it and
    capped at ``PROFILE_ITERATIONS`` (one stopped short kept: it bounds the profile there from
    above, so it only understates how far the likelihood reaches); a
    side ends at a point rising by ``REACH_CHI2`` or more, at the bounds, or below
    ``POINT_MM``.  Tested where the
    radius's relative sigma exceeds ``TEST_RELATIVE_SIGMA``, as :func:`flat_below` tests one
    point below.  The points widen the sigmas of the radius and of the values that trade with
    it (:func:`widen_by_points`): where the likelihood is flat toward the truth from a radius
    fitted too small or too large, the place and the force it gives are as uncertain."""
    if r is None or sd_r is None or not (r > 0.0 and sd_r > 0.0):
        return []
    s = sd_r / r
    if s <= TEST_RELATIVE_SIGMA:
        return []
    step = min(PROFILE_SIGMAS * s, RADIUS_STEP_LN)
    lo, hi = max(float(bounds[0][0]), math.log(POINT_MM)), float(bounds[1][0])
    out = []
    for side in (1.0, -1.0):
        q = np.array(p, dtype=float)
        for j in range(1, RADIUS_STEPS + 1):
            at = float(p[0]) + side * j * step
            if not lo < at < hi:
                break
            got = _held(fitter, fr, kind, q, steps, bounds, python_residual, chi2, at,
                        cap=PROFILE_ITERATIONS, bounded=True)
            if got is None:
                continue
            if got[0] >= REACH_CHI2:
                break
            out.append(got)
            q = got[1]
    return out


def widen_by_points(values: dict, std: dict, reasons: dict[str, str],
                    points: list[tuple[float, dict]], keys: tuple[str, ...],
                    why: str | None = None) -> None:
    """Each value of ``keys`` kept in ``values`` with a sigma in ``std``: widened so that
    every profile point ``(rise, values there)`` lies at most ``sqrt(rise)`` of its sigmas
    away (at most one sigma for a point below ``FLAT_CHI2``).  A point of the angle's profile
    moves the values that trade with the angle (a line's place swings round the window it
    is seen in): where the angle's likelihood is not quadratic, neither is theirs."""
    for key in keys:
        v, sd = values.get(key), std.get(key)
        if v is None or sd is None:
            continue
        wide = max((abs(at[key] - v) / math.sqrt(max(rise, FLAT_CHI2))
                    for rise, at in points if at.get(key) is not None), default=0.0)
        if wide > sd:
            std[key] = wide
            reasons.setdefault(key, why or "poorly determined: its sigma widened to the "
                               "profile likelihood of the orientation it trades with")


def place_sigma(fitter: Any, fr: Any, kind: int, p: np.ndarray, steps: np.ndarray,
                bounds: tuple[np.ndarray, np.ndarray], python_residual: Any, chi2: float,
                index: int, sd: float | None,
                near_steps: tuple[float, ...] = LINE_NEAR_STEPS) -> float | None:
    """The place's coordinate ``index`` of ``p`` (mm; linearised 1-sigma ``sd``) on its
    profile likelihood: chi^2 minimised again with it held ``near_steps`` times
    ``PROFILE_SIGMAS`` sigmas to either side (each search capped at ``PROFILE_ITERATIONS``,
    one stopped short kept as the bound on the profile it is), and its sigma widened so that
    every point that rises by less than a quadratic's there lies ``sqrt(rise)`` sigmas away
    (one sigma below a rise of ``FLAT_CHI2``); None where no point says it is wider.  A light
    ellipsoid on a coarse pad (a 6x4 pad of 4 mm pitch under 2 mm) fitted near a point has a
    sharper place than the truth's: its linearised sigma put 80 % of the places within 2
    sigmas and 5.7 % beyond 4, though the profile at the true place rose by 1-3.5 on most of
    those beyond 2."""
    if sd is None or not sd > 0.0:
        return None
    wide = sd
    for k in near_steps:
        dist = k * PROFILE_SIGMAS * sd
        for side in (-1.0, 1.0):
            got = _held(fitter, fr, kind, p, steps, bounds, python_residual, chi2,
                        float(p[index]) + side * dist, index, cap=PROFILE_ITERATIONS,
                        bounded=True)
            if got is not None and got[0] < (k * PROFILE_SIGMAS) ** 2:
                wide = max(wide, dist / math.sqrt(max(got[0], FLAT_CHI2)))
    return wide if wide > sd else None


def swapped(p: np.ndarray) -> np.ndarray | None:
    """The general model's vector ``p`` (``[ln R_a, beta, psi, ...]``) written with its first
    entry the log of r2, the larger radius (the same contact: ``kappa_b = beta^2 kappa_a``, so
    ``R_a' = R_a / beta^2``, ``beta' = 1 / beta``, ``psi' = psi + 90 deg``); None for a
    cylinder (``beta = 0``: r2 infinite)."""
    q = np.array(p, dtype=float)
    b2 = q[1] * q[1]
    if b2 <= 0.0:
        return None
    if b2 < 1.0:
        q[0] -= math.log(b2)
        q[1] = 1.0 / q[1]
        q[2] += 0.5 * math.pi
    return q


def r2_profile(fitter: Any, fr: Any, kind: int, p: np.ndarray, steps: np.ndarray,
               bounds: tuple[np.ndarray, np.ndarray], python_residual: Any, chi2: float,
               r2: float | None, sd_r2: float | None) -> str | float | None:
    """An ellipse's larger radius ``r2`` (mm; 1-sigma ``sd_r2``) on its profile likelihood,
    tested on both sides: chi^2 minimised again with ``ln r2`` held ``PROFILE_SIGMAS`` of its
    sigmas above and below (the general model's vector :func:`swapped` so that its first
    entry is ``ln r2``, then held as :func:`flat_below` holds a radius).  A light ellipsoid
    on the paper's finger lies in a curved valley where both radii shrink together: its fit
    lands at radii 3-4 times too small with a linearised sigma of 20-25 % (up to 15 sigmas
    off) though a radius twice as large explains the frame within a chi^2 of 1.  The smaller
    rise decides, as for a line's orientation (:func:`angle_profile`): below ``FLAT_CHI2``
    the reason to withhold it, below ``PROFILE_SIGMAS^2`` its widened sigma, else None."""
    if r2 is None or sd_r2 is None or not (r2 > 0.0 and sd_r2 > 0.0):
        return None
    s = sd_r2 / r2
    q = swapped(p)
    if s <= TEST_RELATIVE_SIGMA or q is None:
        return None
    lo, hi = np.array(bounds[0], dtype=float), np.array(bounds[1], dtype=float)
    # beta' >= 1: the radius held is the larger one (held below r1 otherwise, the other
    # radius would take r2's place and the profile be r1's)
    lo[1] = max(lo[1], 1.0)
    q[1] = abs(q[1])
    points = []
    above = False  # the likelihood rises by under PROFILE_SIGMAS^2 at the upper point
    for side in (-1.0, 1.0):
        at = float(q[0]) + side * PROFILE_SIGMAS * s
        if not lo[0] < at < hi[0]:
            above |= side > 0.0  # two sigmas reach beyond the box (200 m): a cylinder's test
            continue
        # started with r1 where the solution has it (r1 = R_a' / beta'^2), or a sphere
        start = q.copy()
        start[1] = max(1.0, math.sqrt(math.exp(at - float(q[0]))) * q[1])
        rise = _rise(fitter, fr, kind, start, steps, (lo, hi), python_residual, chi2, at)
        if rise is not None and rise < PROFILE_SIGMAS ** 2:
            points.append((r2 * abs(math.exp(at - float(q[0])) - 1.0), rise, side))
            above |= side > 0.0
    flat = [pt for pt in points if pt[1] < FLAT_CHI2]
    if flat:
        dist, rise, side = max(flat)
        return (f"{TOO_LIGHT}: the likelihood is flat {'above' if side > 0 else 'below'} it "
                f"(chi^2 rises by {max(rise, 0.0):.2g}, not {PROFILE_SIGMAS ** 2:g}, at "
                f"{r2 + side * dist:.3g} mm, {PROFILE_SIGMAS:g} sigmas "
                f"{'larger' if side > 0 else 'smaller'}): its sigma does not hold")
    wide = max((dist / math.sqrt(rise) for dist, rise, _ in points), default=None)
    if above and (wide is None or wide >= CYLINDER_RELATIVE_SIGMA * r2):
        # slow to rise above, and so wide that its curvature 1/r2 (in which the likelihood
        # is nearer quadratic) lies within half a sigma of zero, a cylinder's
        return (f"{TOO_LIGHT}: not told from a cylinder: the likelihood is flat above it "
                f"(its sigma {'reaches past 200 m' if wide is None else f'is {100 * wide / r2:.0f} % of it'}"
                ": its curvature within half a sigma of zero)")
    return wide


def round_test(fitter: Any, fr: Any, p: np.ndarray, steps: np.ndarray,
               bounds: tuple[np.ndarray, np.ndarray], residual: Any, sphere_residual: Any,
               chi2: float, values: dict, std: dict) -> str | float | None:
    """An ellipse's orientation (the general model at ``p``, chi^2 ``chi2``; ``values`` and
    ``std`` its report) where its two radii may not be told apart: the reason to withhold it,
    its honest sigma (deg) where its profile is wider than its linearised sigma, or None.

    Near a circle the orientation lives in the difference of the curvatures, whose fitted size
    the noise biases up (a Rice distribution), so the linearised sigma, taken at that size,
    is too small, and the profile likelihood is no parabola: a narrow well at the fit, flat at
    a few units of chi^2 beyond.  On the XELA 4x6 pad, near-spheres (radii 1.0-1.4 times
    apart) at 1-2 N published 13 of 64 angles beyond 4 sigmas (60 deg off with a sigma of 2).
    So chi^2 is minimised again as a sphere (one search, ``sphere_residual``): under
    ``ROUND_CHI2`` above, the radii are not told apart and the orientation is withheld; under
    ``ROUND_SCAN_CHI2`` the profile of the orientation is evaluated at ``ROUND_SCAN_DEG``
    (turned 90 deg with its radii swapped an ellipse is the same one, so 45 deg is the
    farthest): its sigma is widened to the widest the points imply (each ``sqrt(rise)``
    sigmas away: far points too, where the well is narrow and the profile beyond it flat),
    and withheld where that is over ``MAX_ANGLE_SIGMA`` (the one rule's bound).
    A circle's orientation is ``undefined`` (as a sphere's is), which the daemon's tracker
    does not lift while it tracks from that fit: a pooled linearised sigma has the same bias.
    (Not told from a point, with neither radius resolved, is no reason: a rod fitted as an
    ellipse has its radius unresolved and r2 unbounded, and its orientation sharp.)"""
    b2 = float(p[1]) ** 2
    if not b2 > 0.0:
        return None  # a cylinder: no circle near
    from tactiled.fit.models import get_model
    from tactiled.fit.search import bounds_of, steps_of
    sphere = get_model("sphere")
    # the geometric mean of the two radii, the force and the place
    start = np.array([float(p[0]) - 0.5 * math.log(b2), float(p[3]), float(p[4]), float(p[5])])
    sol, _ = fitter._search(fr, 1, [start], steps_of(sphere), bounds_of(sphere),
                            fitter.options.max_iter, 1e-2, sphere_residual)
    if not sol.converged or not math.isfinite(sol.cost):
        return None
    rise = sol.cost * (fr.peak / fitter.sigma) ** 2 - chi2
    if rise < ROUND_CHI2:
        return (f"undefined: the two radii are not told apart (a sphere explains the frame "
                f"within a chi^2 of {max(rise, 0.0):.2g}, under {ROUND_CHI2:g})")
    if rise >= ROUND_SCAN_CHI2 and all(
            values.get(k) is not None and (std.get(k) or math.inf) <= TEST_RELATIVE_SIGMA * values[k]
            for k in ("r1_mm", "r2_mm")):
        return None
    points = []
    for off in ROUND_SCAN_DEG:
        r = _rise(fitter, fr, 2, p, steps, bounds, residual, chi2,
                  float(p[2]) + math.radians(off), 2)
        if r is not None:
            points.append((abs(off), max(r, 1e-12)))
    # every point, however far, lies sqrt(rise) sigmas away: the widest sigma that says so
    return _bounded_sigma(points, 0.0) if points else None


def _rise(fitter: Any, fr: Any, kind: int, p: np.ndarray, steps: np.ndarray,
          bounds: tuple[np.ndarray, np.ndarray], python_residual: Any, chi2: float,
          at: float, index: int = 0, cap: int | None = None) -> float | None:
    """chi^2 minimised with the parameter ``index`` (default the log radius) held at ``at``,
    less ``chi2``; None where the search did not converge (within ``cap`` iterations: by
    default the fit's own cap)."""
    got = _held(fitter, fr, kind, p, steps, bounds, python_residual, chi2, at, index, cap=cap)
    return None if got is None else got[0]


def _held(fitter: Any, fr: Any, kind: int, p: np.ndarray, steps: np.ndarray,
          bounds: tuple[np.ndarray, np.ndarray], python_residual: Any, chi2: float,
          at: float, index: int = 0,
          starts_at: Callable[[np.ndarray], list[np.ndarray]] | None = None,
          cap: int | None = None, bounded: bool = False) -> tuple[float, np.ndarray] | None:
    """``(rise, solution)``: chi^2 minimised with the parameter ``index`` held at ``at``, less
    ``chi2``, from ``p`` so changed (or from each of the starts ``starts_at`` gives for it, the
    lowest search kept), within ``cap`` iterations (default the fit's own cap): converged
    searches only (None where none converged), or ``bounded``, a search stopped short kept
    too (None where none evaluated): it still bounds the profile there from above, so it only
    understates how far the likelihood reaches (never a withholding or a widening the
    profile would not make)."""
    lo, hi = bounds[0].copy(), bounds[1].copy()
    lo[index] = hi[index] = at
    start = np.array(p, dtype=float)
    start[index] = at
    best = None
    for s0 in ([start] if starts_at is None else starts_at(start)):
        sol, _ = fitter._search(fr, kind, [s0], steps, (lo, hi), cap or fitter.options.max_iter,
                                1e-2, python_residual)
        ok = sol.jacobian.size > 0 if bounded else sol.converged
        if ok and math.isfinite(sol.cost) and (best is None or sol.cost < best.cost):
            best = sol
    if best is None:
        return None
    return best.cost * (fr.peak / fitter.sigma) ** 2 - chi2, best.p


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

"""mu's resolution decided by its bound at the estimate, and the selective lower end of lam's
interval (tactiled/fit/shear_profile.py), against independent computations."""

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.stats import norm

from tactiled.fit.shear import MU_RESOLVED, ShearEstimate, ShearFitter
from tactiled.fit.shear_profile import GRID, SELECT_CAP, TAIL, LamInterval
from tactiled.physics.threeaxis import ShearContact, ThreeAxisModel, three_axis
from tactiled.sensors import load_description

S = 0.1  # a bound of lam, the same at every lam (for the closed forms below)


def _interval(best: float, lo: float) -> LamInterval:
    return LamInterval(lo, min(1.0, best + 2 * S), best, bound=tuple(S for _ in GRID))


def _rel(lam: float) -> float:
    """mu's relative sigma at ``lam`` with bound S (and Q/P known): a quarter of the width in
    ln mu of ``[Q/P / min(1, lam + 2S), Q/P / (lam - 2S)]``."""
    return math.log(min(1.0, lam + 2 * S) / (lam - 2 * S)) / 4.0


def test_threshold_is_where_the_bound_resolves_mu():
    cut = brentq(lambda lam: _rel(lam) - MU_RESOLVED, 2 * S + 1e-9, 0.99)
    prof = _interval(0.9, 0.7)
    assert prof.threshold(0.0, MU_RESOLVED) == pytest.approx(cut, abs=0.9 / 100 + 1e-9)
    assert prof.relative(0.9, 0.0) == pytest.approx(_rel(0.9))
    # below the threshold at the estimate: no threshold under it, mu not resolved there
    assert math.isinf(_interval(cut - 0.05, 0.3).threshold(0.0, MU_RESOLVED))


@pytest.mark.parametrize("above", [0.02, 0.1, 0.2])
def test_selective_end_inverts_the_truncated_normal(above):
    """Just above the threshold the lower end is the least lam whose Gaussian law, truncated
    to estimates over the threshold, puts the estimate in its upper 2.5 % (capped at
    SELECT_CAP bounds below it); the profile's own end where that is lower."""
    cut = brentq(lambda lam: _rel(lam) - MU_RESOLVED, 2 * S + 1e-9, 0.99)
    x = cut + above
    def inside(t: float) -> float:  # >= 0 where lam = t is kept
        return norm.sf((x - t) / S) / norm.sf((cut - t) / S) - TAIL

    floor = x - SELECT_CAP * S
    want = floor if inside(floor) >= 0 else brentq(inside, floor, x)
    got = _interval(x, x - 2 * S).selective_lo(0.0, MU_RESOLVED)
    assert got == pytest.approx(min(want, x - 2 * S), abs=0.01)
    assert got < x - 2 * S  # near the threshold it widens the ordinary interval
    assert _interval(x, x - 5 * S).selective_lo(0.0, MU_RESOLVED) == x - 5 * S


def test_far_above_the_threshold_the_interval_is_the_profiles():
    """Four bounds above the threshold the selection widens lam's interval by under a tenth
    of a bound; the profile's end is kept where it is lower."""
    prof = _interval(0.95, 0.95 - 2 * S)
    assert prof.threshold(0.0, MU_RESOLVED) < 0.95 - 4 * S
    assert 0.95 - 2.1 * S <= prof.selective_lo(0.0, MU_RESOLVED) <= 0.95 - 2 * S
    assert _interval(0.95, 0.6).selective_lo(0.0, MU_RESOLVED) == 0.6


def test_bound_of_lam_equals_the_fits_covariance():
    """The bound of lam on the grid, at the fit's lam, equals the one of the full covariance
    (the other seven parameters profiled out either way)."""
    desc = three_axis(load_description("fearing1988"))
    m = ThreeAxisModel(desc)
    cx, cy = m.centre()
    est = ShearFitter(desc).fit(m.frame(ShearContact(15.0, 1.5, cx + 0.2, cy - 0.1, 0.5, 0.4, 0.1, 0.6)))
    k = int(np.argmin(np.abs(GRID - est.params[7])))
    assert abs(GRID[k] - est.params[7]) < 0.01
    assert est.lam_profile.bound[k] == pytest.approx(est.sigma[7], rel=0.05)


def test_a_profile_far_wider_than_its_bound_is_withheld():
    """At the bound 1 the bound of lam says mu is resolved; a profile that runs down to full
    stick says otherwise, and mu is withheld with the reason; a profile as narrow as the bound
    publishes mu = (Q/P) / lam."""
    params = np.array((math.log(10.0), 0.0, 0.0, 0.0, 0.3, 0.4, 0.0, 1.0))
    cov = np.diag([1e-6] * 7 + [0.05 ** 2])
    bound = tuple(0.05 for _ in GRID)
    wide = ShearEstimate(params, cov, 1.0, True, lam_profile=LamInterval(0.02, 1.0, 1.0, bound=bound))
    mu, _, why = wide.mu()
    assert mu is None and "far wider than its bound" in why
    narrow = ShearEstimate(params, cov, 1.0, True, lam_profile=LamInterval(0.88, 1.0, 1.0, bound=bound))
    mu, s_mu, why = narrow.mu()
    assert why is None and mu == pytest.approx(0.5, rel=1e-6)
    assert mu + 2 * s_mu >= 0.5 / 0.88  # the interval's long arm, up to full stick's side


@pytest.mark.parametrize("far", [2.5, 4.0, 6.0])
def test_the_selective_end_reaches_the_profiles_own_far_end(far):
    """Where the profile's SELECT_CAP-sigma end lies further down than SELECT_CAP bounds at the
    estimate (a profile flat toward full stick, a bound that shrinks toward slip), the
    selective end may reach it: the truncated normal's inversion, floored at the farther of
    the two."""
    cut = brentq(lambda lam: _rel(lam) - MU_RESOLVED, 2 * S + 1e-9, 0.99)
    x = cut + 0.02
    def inside(t: float) -> float:
        return norm.sf((x - t) / S) / norm.sf((cut - t) / S) - TAIL

    floor = max(0.0, min(x - SELECT_CAP * S, x - far * S))
    want = floor if inside(floor) >= 0 else brentq(inside, floor, x)
    prof = replace(_interval(x, x - 2 * S), far_lo=max(0.0, x - far * S))
    assert prof.selective_lo(0.0, MU_RESOLVED) == pytest.approx(min(want, x - 2 * S), abs=0.01)
    if far > SELECT_CAP:  # further than the bound's cap: strictly lower than before
        assert prof.selective_lo(0.0, MU_RESOLVED) < _interval(x, x - 2 * S).selective_lo(0.0, MU_RESOLVED) - 0.05


def test_the_paxini_frame_whose_truth_lay_down_its_profile_is_covered():
    """The PaXini frame (bench seed 1, frame 5) whose lam sits at its bound 1 with the truth
    0.31 some 2.5 sigma down the profile: three bounds at the estimate stop short of the
    truth; the profile's own 3-sigma end does not, and the published mu covers its truth."""
    from tactiled.sim.shear import random_frames

    desc = load_description("paxini_px6ax")
    frames, truth = random_frames(desc, 6, np.random.default_rng(1))
    est = ShearFitter(desc).fit(frames[5])
    prof, lam_true, mu_true = est.lam_profile, truth["true_lam"][5], truth["true_mu"][5]
    assert prof.best > 0.95 and lam_true < 0.35
    assert prof.best - SELECT_CAP * prof.sigma_at(prof.best) > lam_true  # the bound's cap misses it
    assert prof.far_lo < lam_true
    mu, s_mu, why = est.mu()
    assert why is None and mu is not None  # published (its estimate clears the threshold) ...
    assert abs(mu - mu_true) <= 2 * s_mu, (mu, s_mu, mu_true)  # ... with the truth inside

"""Zeroing: held contacts survive, idle drift is tracked, release residual decays, tare."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled.calibration import ContactDetector, Zeroer
from tactiled.calibration.zeroing import (
    DEFAULT_HOLDOFF,
    DEFAULT_TAU_DRIFT,
    DEFAULT_TAU_RELEASE,
    DRIFT_STEP_S,
)

SIGMA = 0.0005
RATE = 100.0  # Hz


def bump(amplitude: float, m0: float = 3.4, n0: float = 4.2, width: float = 0.9) -> np.ndarray:
    """A smooth contact-like strain blob peaking at ``amplitude`` (strain) near ``[m0, n0]``."""
    m, n = np.mgrid[0:8, 0:8]
    return amplitude * np.exp(-((m - m0) ** 2 + (n - n0) ** 2) / (2 * width**2))


def test_a_contact_held_for_five_minutes_is_not_erased():
    rng = np.random.default_rng(0)
    zeroer = Zeroer()
    offset = rng.uniform(-0.01, 0.01, (8, 8))  # the table's zero need not be the sensor's
    contact = bump(0.01)
    start, end = 2.0, 302.0
    peaks, states = [], []
    for k in range(int(304 * RATE)):
        t = k / RATE
        x = offset + rng.normal(0.0, SIGMA, (8, 8))
        if start <= t < end:
            x = x + contact
        z = zeroer.update(x, t)
        if start + 0.05 <= t < end:
            states.append(zeroer.in_contact)
        if end - 5.0 <= t < end:
            peaks.append(z[3, 4])
    assert all(states), "the contact must be seen for the whole hold, not decay away"
    # after 5 minutes the zeroed peak still equals the applied strain (mean of the last 5 s)
    assert np.mean(peaks) == pytest.approx(contact[3, 4], abs=3 * SIGMA / math.sqrt(len(peaks)) +
                                           1e-4)
    assert not zeroer.in_contact  # and the release was seen


def _idle_run(rate: float, drift_per_s: float, seconds: float, detect: bool, seed: int = 1):
    rng = np.random.default_rng(seed)
    zeroer = Zeroer()
    out, contacts = [], 0
    for k in range(int(seconds * rate)):
        t = k / rate
        x = drift_per_s * t + rng.normal(0.0, SIGMA, (8, 8))
        out.append(zeroer.update(x, t, contact=None if detect else False))
        contacts += zeroer.in_contact
    return np.array(out), contacts


def test_idle_drift_is_tracked_with_lag_rate_times_tau_at_any_frame_rate():
    drift = 2e-5  # strain per second: lag 1e-4 = 0.2 sigma
    lags = []
    for rate in (100.0, 400.0):
        # The tracking itself, with contact decisions pinned to "none": an EMA following a ramp
        # lags by drift * tau once settled (5 s of running mean, then > 4 tau_drift).
        z, _ = _idle_run(rate, drift, 40.0, detect=False)
        late = z[int(30 * rate):]
        lags.append(late.mean())
        assert late.mean() == pytest.approx(drift * DEFAULT_TAU_DRIFT, rel=0.05)
    assert lags[0] == pytest.approx(lags[1], rel=0.05)  # rate independent
    # With the detector deciding: the uniform lag lifts the matched filter's mean by ~0.44 sigma,
    # so false contacts rise from 1e-4 to ~1e-3 per frame (docs/concepts/calibration.md), no more.
    z, contacts = _idle_run(400.0, drift, 40.0, detect=True)
    assert contacts <= 3e-3 * len(z)


def test_start_up_averages_the_baseline_instead_of_trusting_one_frame():
    rng = np.random.default_rng(5)
    zeroer = Zeroer()
    frames = rng.normal(0.0, SIGMA, (200, 8, 8))
    for k, x in enumerate(frames):
        zeroer.update(x, k / RATE)
        if k / RATE < zeroer.settle:
            assert zeroer.settling and not zeroer.in_contact
    assert not zeroer.settling
    # the running mean: after 200 frames the baseline noise is sigma / sqrt(200), not sigma
    assert np.std(zeroer.baseline) < 2.0 * SIGMA / math.sqrt(200)


def test_release_residual_decays_with_tau_release_then_drift_tracking_resumes():
    zeroer = Zeroer()
    residual = bump(0.0005)  # 5 % of the press stays in the rubber after release
    dt = 1.0 / RATE
    t, k = 0.0, 0
    outputs = []
    release_t = None
    # Press at 6 s: by then the start-up running mean (n < tau_drift * rate frames) is over.
    while t < 11.0:
        t = k * dt
        if 6.0 <= t < 8.0:
            x = bump(0.01)
        elif t >= 8.0:
            x = residual
        else:
            x = np.zeros((8, 8))
        was = zeroer.in_contact
        z = zeroer.update(x, t)
        if was and not zeroer.in_contact:
            release_t = t
        outputs.append((t, z[3, 4]))
        k += 1
    assert release_t == pytest.approx(8.0)
    times = np.array([o[0] for o in outputs])
    peak = np.array([o[1] for o in outputs])
    after = (times >= release_t) & (times < release_t + DEFAULT_HOLDOFF)
    expected = residual[3, 4] * np.exp(-(times[after] - release_t) / DEFAULT_TAU_RELEASE)
    np.testing.assert_allclose(peak[after], expected, rtol=1e-9, atol=1e-15)
    # one tau after release: 1/e of the residual is left
    i = np.argmin(np.abs(times - (release_t + DEFAULT_TAU_RELEASE)))
    assert peak[i] / residual[3, 4] == pytest.approx(math.exp(-1), rel=1e-6)
    # after the hold-off the slow time constant applies again
    j = np.searchsorted(times, release_t + DEFAULT_HOLDOFF + 1e-9)
    assert peak[j + 1] / peak[j] == pytest.approx(math.exp(-dt / DEFAULT_TAU_DRIFT), rel=1e-9)


def test_one_implausible_frame_pulls_the_baseline_at_most_ten_sigma_times_the_weight():
    """A glitch (every tactel at -0.5 strain, e.g. an ADC returning zero counts) is no contact,
    so the baseline learns from it, but only up to MAX_STEP_SIGMAS noise sigmas of pull: the
    shift is exactly weight x 10 sigma (independently: weight = 1 - exp(-dt/tau)), where the
    whole deviation would have moved it by 0.5 x weight = 5 sigma here."""
    from tactiled.calibration.zeroing import MAX_STEP_SIGMAS

    zeroer = Zeroer(detector=ContactDetector(SIGMA))
    dt = 1.0 / RATE
    k = 0
    for k in range(1000):  # 10 s: well past the running-mean start-up (n > tau_drift * rate)
        zeroer.update(np.zeros((8, 8)), k * dt)
    before = zeroer.baseline.copy()
    zeroer.update(np.full((8, 8), -0.5), (k + 1) * dt)
    assert not zeroer.in_contact
    weight = 1.0 - math.exp(-dt / DEFAULT_TAU_DRIFT)
    np.testing.assert_allclose(before - zeroer.baseline, weight * MAX_STEP_SIGMAS * SIGMA,
                               rtol=1e-12)
    # a step of the unloaded strain beyond 10 sigma, told "no contact", is still absorbed:
    # linearly at 10 sigma per time constant while clipped, then exponentially
    step = 0.02  # 40 sigma
    t0 = (k + 2) * dt
    for j in range(int(60 * RATE)):
        z = zeroer.update(np.full((8, 8), step), t0 + j * dt, contact=False)
    assert abs(z).max() < 0.05 * SIGMA


def test_baseline_is_frozen_during_contact_and_caller_can_decide_contact():
    zeroer = Zeroer()
    zeroer.update(np.zeros((8, 8)), 0.0)
    zeroer.update(np.full((8, 8), 0.001), 1.0, contact=True)
    np.testing.assert_array_equal(zeroer.baseline, 0.0)
    z = zeroer.update(np.full((8, 8), 0.001), 2.0, contact=False)
    np.testing.assert_allclose(z, 0.001)
    assert np.all(zeroer.baseline > 0.0)  # released: now absorbing, fast (tau_release)
    np.testing.assert_allclose(zeroer.baseline, 0.001 * -math.expm1(-1.0 / DEFAULT_TAU_RELEASE))


def _drifting_hold(follow: bool, seconds: float = 60.0, seed: int = 2):
    """A 20-sigma contact held ``seconds`` on a finger whose tactels drift at 2e-5 strain/s
    times a gain of 0.5-1 each (the simulator's fastest drift), then released; with
    ``follow``, the contact's prediction (the bump itself) and a 4x4 window are given to
    ``follow_drift`` every frame.  Returns (the RMS over the window's tactels of their zeroed
    strain's mean error over the hold's last 5 s, in sigma; seconds from the release to the detector's exit, or None; drift steps)."""
    rng = np.random.default_rng(seed)
    gains = rng.uniform(0.5, 1.0, (8, 8))
    contact = bump(0.01)
    window = np.zeros((8, 8), dtype=bool)
    window[2:6, 2:6] = True
    zeroer = Zeroer()
    start, end = 2.0, 2.0 + seconds
    peak, exit_after, steps = [], None, 0
    for k in range(int((end + 10.0) * RATE)):
        t = k / RATE
        x = 2e-5 * t * gains + rng.normal(0.0, SIGMA, (8, 8))
        if start <= t < end:
            x = x + contact
        z = zeroer.update(x, t)
        if start <= t < end:
            assert zeroer.in_contact, t  # never erased
            if follow:
                steps += zeroer.follow_drift(z, t, contact, window)
            if t >= end - 5.0:
                peak.append((z - contact)[window])
        if t >= end and exit_after is None and not zeroer.in_contact:
            exit_after = t - end
    return float(np.sqrt(np.mean(np.mean(peak, axis=0) ** 2))) / SIGMA, exit_after, steps


def test_drift_is_followed_around_a_held_contact_and_its_release_is_seen():
    """Frozen whole, the baseline let 60 s of drift (1.2e-3 strain x gain, 1.2-2.4 sigma) pile
    up under the contact: the contact's tactels read that much high, and after the release the drift alone kept
    the detector above its exit threshold for good.  Followed around the contact (outside the
    window each tactel, inside the outside's mean), both go."""
    error, exit_after, steps = _drifting_hold(follow=True)
    assert error < 0.6, error  # what is left: each tactel's gain against the mean's
    assert exit_after is not None and exit_after < 1.0, exit_after
    assert steps == pytest.approx(60.0 / DRIFT_STEP_S, rel=0.05)  # every 10 ms, no more
    frozen_error, frozen_exit, _ = _drifting_hold(follow=False)
    # (gains of 0.5-1: 1.2-2.4 sigma of drift since the press)
    assert frozen_error > max(1.2, 3.0 * error), (frozen_error, error)
    assert frozen_exit is None


def test_follow_drift_moves_nothing_unless_the_prediction_explains_the_window():
    zeroer = Zeroer()
    for k in range(100):  # settle an idle baseline
        zeroer.update(np.zeros((8, 8)), k / RATE)
    contact = bump(0.01)
    window = np.zeros((8, 8), dtype=bool)
    window[2:6, 2:6] = True
    t = 1.0
    z = zeroer.update(contact + 0.0003, t)  # a uniform drift of 0.6 sigma besides the contact
    assert zeroer.in_contact
    before = zeroer.baseline.copy()
    assert not zeroer.follow_drift(z, t, contact, window)  # the first call starts the clock
    t += DRIFT_STEP_S / 2
    assert not zeroer.follow_drift(zeroer.update(contact + 0.0003, t), t, contact, window)
    t += DRIFT_STEP_S
    z = zeroer.update(contact + 0.0003, t)
    # a contact that has moved (the prediction a stale one): nothing moves
    assert not zeroer.follow_drift(z, t, bump(0.01, 3.9, 4.2), window)
    assert not zeroer.follow_drift(z, t, contact, np.zeros((8, 8), dtype=bool))
    np.testing.assert_array_equal(zeroer.baseline, before)
    assert zeroer.follow_drift(z, t, contact, window)
    moved = zeroer.baseline - before
    weight = -math.expm1(-1.5 * DRIFT_STEP_S / DEFAULT_TAU_DRIFT)
    np.testing.assert_allclose(moved[~window], 0.0003 * weight)  # each its own pull
    np.testing.assert_allclose(moved[window], 0.0003 * weight)  # the outside's mean
    # a fit of this very frame is the best the model explains it by: no test
    t += DRIFT_STEP_S
    z = zeroer.update(contact + 0.0003, t)
    assert zeroer.follow_drift(z, t, bump(0.01, 3.9, 4.2), window, fitted=True)
    zeroer.update(np.zeros((8, 8)), t + 0.01)  # released
    assert not zeroer.in_contact
    assert not zeroer.follow_drift(z, t + 0.05, contact, window)  # only in contact


def test_tare_rezeroes_now_or_on_the_next_frame():
    zeroer = Zeroer()
    zeroer.update(np.zeros((8, 8)), 0.0)
    loaded = bump(0.01)
    zeroer.update(loaded, 1.0)
    assert zeroer.in_contact
    zeroer.tare()  # e.g. a tool now mounted on the finger: the next frame is the new zero
    assert not zeroer.in_contact
    np.testing.assert_array_equal(zeroer.update(loaded, 1.01), 0.0)
    assert zeroer.settling and not zeroer.in_contact
    np.testing.assert_array_equal(zeroer.update(loaded, 2.0), 0.0)
    assert not zeroer.settling and not zeroer.in_contact
    # pressing on top of the new zero is a contact again
    assert zeroer.update(loaded + bump(0.01, 1.0, 1.0), 2.01) [1, 1] == pytest.approx(0.01)
    assert zeroer.in_contact
    zeroer.tare(np.full((8, 8), 0.002))
    np.testing.assert_allclose(zeroer.update(np.full((8, 8), 0.002), 3.0), 0.0)
    with pytest.raises(ValueError, match="shape"):
        zeroer.tare(np.zeros((4, 4)))


def test_first_frame_is_the_zero_and_backwards_time_does_not_move_the_baseline():
    zeroer = Zeroer()
    first = np.full((8, 8), 0.003)
    np.testing.assert_array_equal(zeroer.update(first, 10.0), 0.0)
    before = zeroer.baseline.copy()
    zeroer.update(first + 0.0001, 9.0)  # clock went backwards: no update
    zeroer.update(first + 0.0001, 9.0)  # duplicate timestamp: no update
    np.testing.assert_array_equal(zeroer.baseline, before)


def test_non_finite_entries_are_zeroed_and_counted():
    zeroer = Zeroer()
    zeroer.update(np.zeros((8, 8)), 0.0)
    x = np.full((8, 8), 0.0002)
    x[1, 1], x[2, 2], x[3, 3] = np.nan, np.inf, -np.inf
    z = zeroer.update(x, 0.01)
    assert np.all(np.isfinite(z)) and z[1, 1] == z[2, 2] == z[3, 3] == 0.0
    assert z[0, 0] == pytest.approx(0.0002)
    assert np.all(np.isfinite(zeroer.baseline)) and zeroer.baseline[1, 1] == 0.0
    assert zeroer.nonfinite_frames == 1 and not zeroer.in_contact
    # a first frame with NaN still starts a usable baseline
    fresh = Zeroer()
    assert np.all(np.isfinite(fresh.update(x, 0.0)))


def test_bad_arguments():
    with pytest.raises(ValueError, match="tau_drift"):
        Zeroer(tau_drift=0.0)
    with pytest.raises(ValueError, match="holdoff"):
        Zeroer(holdoff=-1.0)
    with pytest.raises(ValueError, match="shape"):
        Zeroer((4, 4))  # the default detector is 8x8
    with pytest.raises(ValueError, match="shape"):
        Zeroer().update(np.zeros((4, 4)), 0.0)
    assert Zeroer(detector=ContactDetector()).tau_release == DEFAULT_TAU_RELEASE

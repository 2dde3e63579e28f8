"""The hysteresis learner's step (tactiled.calibration.fused.learn_hysteresis) against the
numpy arithmetic it replaces, written out here."""

import numpy as np
import pytest

from tactiled.calibration.hysteresis import (FORGET, MIN_PEAK_SIGMAS, TAUS_S,
                                             HysteresisLearner)


def _numpy_step(peaks, normal, moment, t_prev, t, unexplained, predicted, outside, sigma):
    load = np.maximum(predicted.reshape(-1), 0.0)
    if t_prev is not None and t > t_prev:
        peaks *= np.exp(-(t - t_prev) / TAUS_S)[:, None]
    np.maximum(peaks, load, out=peaks)
    out = outside.reshape(-1)
    held = peaks[:, out]
    q = np.where(held > MIN_PEAK_SIGMAS * sigma, held - load[out], 0.0)
    if not q.any():
        return False
    e = unexplained.reshape(-1)[out]
    lo = load[out]
    step = np.empty((TAUS_S.size, 3, 3))
    step[:, 0, 0] = np.einsum("kn,kn->k", q, q)
    step[:, 0, 1] = step[:, 1, 0] = q @ lo
    step[:, 0, 2] = step[:, 2, 0] = q.sum(axis=1)
    step[:, 1, 1] = lo @ lo
    step[:, 1, 2] = step[:, 2, 1] = lo.sum()
    step[:, 2, 2] = e.size
    normal *= FORGET
    normal += step
    moment *= FORGET
    moment[:, 0] += q @ e
    moment[:, 1] += lo @ e
    moment[:, 2] += e.sum()
    return True


def test_a_step_matches_the_numpy_arithmetic_over_a_rolling_contact() -> None:
    rng = np.random.default_rng(21)
    shape, sigma = (8, 8), 1e-4
    learner = HysteresisLearner(shape)
    peaks = np.zeros_like(learner._peaks)
    normal, moment = np.zeros_like(learner._normal), np.zeros_like(learner._moment)
    t_prev = None
    learnt = 0
    yy, xx = np.mgrid[0:8, 0:8]
    for step in range(40):
        t = 0.01 * step
        cx = 1.0 + 0.15 * step  # a contact rolling across the array leaves a trail
        predicted = 3e-3 * np.exp(-((xx - cx) ** 2 + (yy - 4.0) ** 2) / 2.0) - 2e-5
        predicted.flags.writeable = False  # (the pipeline's predictions are read-only)
        outside = np.abs(xx - cx) > 1.5
        unexplained = rng.normal(0.0, sigma, shape)
        want = _numpy_step(peaks, normal, moment, t_prev, t, unexplained, predicted, outside,
                           sigma)
        steps = learner.steps
        learner.learn(unexplained, predicted, outside, t, sigma)
        t_prev = t
        assert (learner.steps == steps + 1) == want
        learnt += want
        np.testing.assert_allclose(learner._peaks, peaks, rtol=1e-13, atol=0.0)
        np.testing.assert_allclose(learner._normal, normal, rtol=1e-10, atol=1e-300)
        np.testing.assert_allclose(learner._moment, moment, rtol=1e-9, atol=1e-22)
    assert 20 < learnt < 40  # the first steps have no trail yet; later ones do


def test_no_trail_changes_no_sums() -> None:
    learner = HysteresisLearner((4, 4))
    predicted = np.full((4, 4), -1e-5)  # nothing compressed anywhere
    learner.learn(np.zeros((4, 4)), predicted, np.ones((4, 4), bool), 0.0, 1e-4)
    assert learner.steps == 0 and not learner._normal.any() and not learner._moment.any()
    assert learner.estimate is None


@pytest.mark.parametrize("dt", [0.0, -0.5])
def test_time_standing_still_or_going_back_decays_nothing(dt: float) -> None:
    learner = HysteresisLearner((2, 2))
    load = np.array([[1e-3, 0.0], [0.0, 0.0]])
    learner.learn(np.zeros((2, 2)), load, np.zeros((2, 2), bool), 1.0, 1e-5)
    learner.learn(np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2), bool), 1.0 + dt, 1e-5)
    assert (learner._peaks[:, 0] == 1e-3).all()

"""The rubber's hysteresis: the compensator inverts the simulator's model, the learner finds its
constants from a rolling contact's trail (and nothing on a finger without hysteresis)."""

from __future__ import annotations

import numpy as np
import pytest

from tactiled.calibration.hysteresis import (
    MIN_PEAK_SIGMAS,
    MIN_STEPS,
    NOISE_MARGIN,
    TAUS_S,
    HysteresisCompensator,
    HysteresisLearner,
)
from tactiled.sim import FingerSimulator, HysteresisModel

SIGMA = 5e-4  # the default finger's noise sigma (strain)
STEP = 10  # the learner steps every 10 ms of 1 kHz frames, as at the zeroer's drift steps


def simulated(hysteresis: HysteresisModel | None, seed: int = 1, noise: float = 0.0):
    """The moving scene (rolling, rotating, lifting off) on the default finger, no drift."""
    return FingerSimulator(scene="moving", seed=seed, noise=noise, drift=None,
                           hysteresis=hysteresis)


@pytest.mark.parametrize("fraction, tau", [(0.05, 0.5), (0.12, 1.5)])
def test_the_compensator_takes_out_the_simulators_residual(fraction, tau):
    sim = simulated(HysteresisModel(fraction, tau))
    comp = HysteresisCompensator(sim.shape)
    comp.set(fraction, tau)
    worst = largest = 0.0
    last = None
    for _ in range(sim.ticks_per_pass):
        tick = sim.step()
        dt = 0.0 if last is None else tick.time_s - last
        last = tick.time_s
        frame = tick.physics + tick.residual  # what the tactels feel, noise and drift aside
        taken = comp.residual(frame, dt, SIGMA)
        taken = np.zeros(sim.shape) if taken is None else taken
        worst = max(worst, float(np.abs(taken - tick.residual).max()))
        largest = max(largest, float(tick.residual.max()))
    # The peak-hold forgets NOISE_MARGIN sigmas and counts from MIN_PEAK_SIGMAS: the residual
    # is under-taken by f x those at most (a third of a sigma at f = 0.05).
    bound = (MIN_PEAK_SIGMAS + NOISE_MARGIN) * SIGMA * fraction / (1.0 - fraction) + 2e-6
    assert worst <= bound, (worst, bound)
    assert largest > 8 * bound  # the residual left alone is many times that


def test_the_compensator_does_nothing_until_set():
    comp = HysteresisCompensator((8, 8))
    assert comp.residual(np.full((8, 8), 0.01), 0.001, SIGMA) is None
    with pytest.raises(ValueError, match="fraction"):
        comp.set(1.0, 0.5)
    with pytest.raises(ValueError, match="tau_s"):
        comp.set(0.05, 0.0)


def learn(hysteresis: HysteresisModel | None, seconds: float, seed: int = 1) -> HysteresisLearner:
    """The learner at 10 ms steps as the zeroer drives it, given the true contact's strain as
    the prediction (a fit that matches the finger), the fit's 4x4 window around its peak left
    out, and noise."""
    sim = simulated(hysteresis, seed=seed, noise=SIGMA)
    learner = HysteresisLearner(sim.shape)
    for k in range(round(seconds * sim.rate_hz)):
        tick = sim.step()
        if k % STEP or tick.contact is None:
            continue
        m, n = np.unravel_index(int(np.argmax(tick.physics)), sim.shape)
        m, n = min(max(m - 1, 0), sim.shape[0] - 4), min(max(n - 1, 0), sim.shape[1] - 4)
        outside = np.ones(sim.shape, dtype=bool)
        outside[m:m + 4, n:n + 4] = False
        learner.learn(tick.strain - tick.physics, tick.physics, outside, tick.time_s, SIGMA)
    return learner


@pytest.mark.parametrize("fraction, tau", [(0.05, 0.5), (0.1, 1.0), (0.04, 0.25)])
def test_the_learner_finds_the_fingers_constants(fraction, tau):
    learner = learn(HysteresisModel(fraction, tau), 12.0)
    assert learner.steps >= MIN_STEPS
    f, t, z = learner.estimate
    grid = float(TAUS_S[1] / TAUS_S[0])
    assert tau / grid < t < tau * grid, learner.estimate  # within one grid step
    assert f == pytest.approx(fraction, rel=0.2), learner.estimate
    assert learner.usable(on=False) == (f, t)


def test_without_hysteresis_the_learner_finds_none():
    learner = learn(None, 12.0)
    assert learner.steps >= MIN_STEPS
    f, t, z = learner.estimate
    assert z < 4.0 and abs(f) < 0.01, learner.estimate
    assert learner.usable(on=False) is None

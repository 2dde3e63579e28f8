"""The rubber's hysteresis, learnt in use and taken out: on the moving scene (rolling, rotating,
lift-offs) the zeroer learns the simulated finger's constants from the trail the tracked contact
leaves, and once it compensates, the phantom contact after each lift-off and the fits the trail
caused are gone; on a finger without hysteresis it never compensates.

Driven synchronously through the pipeline's own entry points with the worker's work (real fits
and linearisations) done in this process, as in test_held_drift.py."""

from __future__ import annotations

import time

import pytest
from pipeline_helpers import InProcessPool, answer

from tactiled.calibration.hysteresis import FRACTION_RANGE, TAUS_S
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.pipeline.hub import Hub
from tactiled.pipeline.sensor import SensorPipeline
from tactiled.settings import SensorSettings
from tactiled.sim import DEFAULT_HYSTERESIS, FingerSimulator, HysteresisModel

PASSES = 2  # of the moving scene's 5.45 s


def _moving(hysteresis: HysteresisModel | None, learn: bool = True, seed: int = 1,
            setting: bool = True, passes: int = PASSES):
    """(pipeline, frames the detector called contact with nothing touching, fits, frames
    compensated) over ``passes`` of the moving scene, the first two counted over the last
    pass (the first is where the learning is)."""
    sim = FingerSimulator(scene="moving", seed=seed, sensor_id=seed, hysteresis=hysteresis)
    pool = InProcessPool()
    p = SensorPipeline(SensorSettings(name="f", url="sim://", hysteresis=setting), pool=pool,
                       hub=Hub())
    fitter = Fitter(pool.sensor, FitOptions(**dict(pool.options)))
    phantom = compensated = fits = 0
    last_pass = (passes - 1) * sim.ticks_per_pass
    for _ in range(passes * sim.ticks_per_pass):
        tick = sim.step()
        frame = tick.frame()
        frame.host_time = time.monotonic()
        p.on_frame(frame)
        zeroer = p.stage.zeroer
        if not learn:  # the control: the code before, nothing learnt, nothing taken out
            zeroer.hysteresis_learner.usable = lambda on: None
        while p._waiting is not None and p._in_flight is None:
            answer(p, fitter, p.take_job())
        if tick.index == last_pass:
            fits = -p.fitted
        phantom += zeroer.in_contact and tick.contact is None and tick.index >= last_pass
        compensated += zeroer.hysteresis.fraction > 0.0
    return p, phantom, fits + p.fitted, compensated


@pytest.fixture(scope="module")
def control():
    return _moving(DEFAULT_HYSTERESIS, learn=False)


def test_the_simulated_fingers_hysteresis_is_learnt_and_taken_out(control):
    p, phantom, fits, compensated = _moving(DEFAULT_HYSTERESIS)
    h = p.stats().hysteresis
    assert h["compensating"], h
    grid = float(TAUS_S[1] / TAUS_S[0])
    assert DEFAULT_HYSTERESIS.tau_s / grid < h["tau_s"] < DEFAULT_HYSTERESIS.tau_s * grid, h
    assert h["fraction"] == pytest.approx(DEFAULT_HYSTERESIS.fraction, rel=0.3), h
    assert h["significance"] > 20, h
    # on from the first pass's middle on
    assert compensated > 0.7 * PASSES * 5450, compensated
    _, phantom_before, fits_before, compensated_before = control
    assert compensated_before == 0
    # Measured over the second pass: 7 phantom frames against 347 before, 28 fits against 55.
    assert phantom_before > 100
    assert phantom * 10 < phantom_before, (phantom, phantom_before)
    assert fits < 0.75 * fits_before, (fits, fits_before)


def test_a_finger_without_hysteresis_is_left_alone():
    p, phantom, fits, compensated = _moving(None)
    h = p.stats().hysteresis
    assert h["steps"] > 500, h  # it looked: the trail was there to learn from
    assert compensated == 0 and not h["compensating"], h
    assert abs(h["fraction"]) < 0.01, h


def test_the_sensor_setting_turns_it_off_and_on_while_running():
    # one pass: with the setting off nothing is learnt, so the first pass is as the last
    p, phantom, fits, compensated = _moving(DEFAULT_HYSTERESIS, setting=False, passes=1)
    h = p.stats().hysteresis
    assert compensated == 0 and h["steps"] == 0 and h["fraction"] is None, h
    assert phantom > 100  # as the control: the residual is left in
    zeroer = p.stage.zeroer
    p.configure({"hysteresis": True})
    assert zeroer.learns_hysteresis
    zeroer.hysteresis.set(0.05, 0.5)
    p.configure({"hysteresis": False})  # off: the compensator stops at once
    assert not zeroer.learns_hysteresis and zeroer.hysteresis.fraction == 0.0


# -- a contact held still, pressed and lifted off: its release is what the learner learns from

#: Frames (1 kHz) the published contact may outlast the truth's last touch once the recovery is
#: taken out.  What the compensator leaves of the residual is at most f x 7 sigma (a third of
#: a sigma at f = 0.05: well below the detector's exit threshold, about 2.1 single-frame
#: sigmas of the 2-frame mean's statistic); what holds the contact on then is the detector
#: itself: the 2-frame mean and a noise excursion above exit, which lasts 1.6 frames on
#: average (HYSTERESIS_DWELL).  10 frames is 2 % of the rubber's 0.5 s time constant; the
#: residual left in (5 % of the 1.5 N ball's 130-sigma peak, decayed through the 0.3 s
#: release to 3-4 sigma at the last touch) holds it 70-260 frames.
RELEASE_FRAMES = 10


def _lifts(learn: bool, hysteresis: HysteresisModel | None = DEFAULT_HYSTERESIS,
           seed: int = 3) -> tuple[list[int], SensorPipeline]:
    """Three presses of an 8 mm ball at 1.5 N, held still and lifted off, on the simulated
    finger at 1 kHz through the pipeline (real fits): for each lift-off, the frames after the
    truth's last touch until the published estimate says no contact."""
    from tactiled.sim import Pose, SceneBuilder

    b = SceneBuilder(Pose(r1=8.0, r2=8.0, x0=10.5, y0=12.0)).idle(0.4)
    for _ in range(3):
        b.press(0.3, force=1.5).hold(0.4).release(0.3).idle(1.0)
    sim = FingerSimulator(scene=b.build("lifts"), seed=seed, sensor_id=seed, hysteresis=hysteresis,
                          loop=False)
    pool = InProcessPool()
    hub = Hub()
    p = SensorPipeline(SensorSettings(name="f", url="sim://"), pool=pool, hub=hub)
    published: dict[int, bool] = {}
    hub.add_listener(lambda it: published.__setitem__(it.seq, bool(it.contact))
                     if it.kind == "estimate" else None)
    fitter = Fitter(pool.sensor, FitOptions(**dict(pool.options)))
    touching = []
    for _ in range(sim.ticks_per_pass):
        tick = sim.step()
        frame = tick.frame()
        frame.host_time = time.monotonic()
        p.on_frame(frame)
        if not learn:  # the control: nothing learnt is used
            p.stage.zeroer.hysteresis_learner.usable = lambda on: None
        while p._waiting is not None and p._in_flight is None:
            answer(p, fitter, p.take_job())
        touching.append(tick.contact is not None)
    tails = []
    for k in range(1, len(touching)):
        if touching[k - 1] and not touching[k]:
            end = k
            while published.get(end, False):
                end += 1
            tails.append(end - k)
    return tails, p


def test_a_contact_held_still_lets_go_when_it_is_lifted_off():
    # Held still, a ball leaves no trail beside it to learn the rubber from; its first
    # lift-off shows the recovery whole, and from the next one on the residual is taken out:
    # the contact ends with the touch.
    tails, p = _lifts(learn=True)
    h = p.stats().hysteresis
    assert len(tails) == 3, tails
    assert h["compensating"], h
    grid = float(TAUS_S[1] / TAUS_S[0])
    assert DEFAULT_HYSTERESIS.tau_s / grid < h["tau_s"] < DEFAULT_HYSTERESIS.tau_s * grid, h
    assert 0.5 * DEFAULT_HYSTERESIS.fraction < h["fraction"] < 1.5 * DEFAULT_HYSTERESIS.fraction, h
    assert tails[0] > 3 * RELEASE_FRAMES, tails  # nothing learnt yet: the residual holds it
    assert max(tails[1:]) <= RELEASE_FRAMES, tails
    # the control: the residual left in holds the contact after every lift-off
    control, _ = _lifts(learn=False)
    assert min(control) > 3 * RELEASE_FRAMES, control


def test_a_release_on_a_rubber_without_hysteresis_teaches_nothing():
    tails, p = _lifts(learn=True, hysteresis=None)
    h = p.stats().hysteresis
    assert not h["compensating"], h
    assert h["fraction"] is None or abs(h["fraction"]) < FRACTION_RANGE[0], h
    assert max(tails) <= RELEASE_FRAMES, tails

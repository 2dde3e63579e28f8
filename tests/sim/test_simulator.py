"""The simulated finger: truth, determinism, drift, hysteresis, counts and frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled.calibration.lut import LookupTable
from tactiled.calibration.zeroing import Zeroer
from tactiled.frames import FrameDecoder, encode_frame
from tactiled.physics.strain import StrainModel
from tactiled.sensors.finger import COUNTS_PER_STRAIN, ZERO_STRAIN_COUNTS
from tactiled.sim import (
    DriftModel,
    FingerSimulator,
    FrameSchedule,
    HysteresisModel,
    Pose,
    SceneBuilder,
    add_noise,
    render,
    simulate_frames,
)
from tactiled.sensors.model import NoiseModel
from tactiled.physics.contact import Contact

COUNT = 1.0 / COUNTS_PER_STRAIN  # strain per count


def run(sim: FingerSimulator, n: int):
    return [sim.step() for _ in range(n)]


def test_same_seed_same_frames_other_seed_differs() -> None:
    a = run(FingerSimulator(scene="demo", seed=7, rate_hz=200), 400)
    b = run(FingerSimulator(scene="demo", seed=7, rate_hz=200), 400)
    c = run(FingerSimulator(scene="demo", seed=8, rate_hz=200), 400)
    assert all(np.array_equal(x.counts, y.counts) for x, y in zip(a, b))
    assert b"".join(encode_frame(t.frame()) for t in a) == b"".join(encode_frame(t.frame()) for t in b)
    assert not all(np.array_equal(x.counts, y.counts) for x, y in zip(a, c))
    # The truth does not depend on the seed.
    assert [t.contact for t in a] == [t.contact for t in c]


def test_noise_free_strain_is_the_model_prediction() -> None:
    sim = FingerSimulator(scene="demo", seed=1, rate_hz=50)
    model = StrainModel(sim.sensor)
    touching = 0
    for tick in run(sim, sim.ticks_per_pass):
        assert tick.contact == sim.scene.contact_at(tick.scene_time_s)
        if tick.contact is None:
            assert not tick.physics.any()
        else:
            touching += 1
            np.testing.assert_allclose(tick.physics, model.predict(tick.contact), rtol=1e-12, atol=0)
    assert touching > 0.5 * sim.ticks_per_pass


def test_strain_is_the_sum_of_its_parts() -> None:
    sim = FingerSimulator(scene="press", seed=2, rate_hz=500, noise=0.0)
    for tick in run(sim, 1500):
        np.testing.assert_allclose(tick.strain, tick.physics + tick.drift + tick.residual,
                                   rtol=0, atol=1e-15)
    noisy = FingerSimulator(scene="empty", seed=2, rate_hz=500, drift=None)
    sd = np.std([t.strain for t in run(noisy, 300)])
    assert sd == pytest.approx(0.0005, rel=0.05)  # the sensor's default sigma


def test_prediction_cache_during_hold_and_idle() -> None:
    sim = FingerSimulator(scene="hold", seed=0, rate_hz=1000)
    ticks = run(sim, 3000)  # 1 s idle, 0.5 s press, 1.5 s of hold
    assert sim.predictions <= 501  # one per tick of the press, none in idle or hold
    assert ticks[-1].physics is ticks[-2].physics


def test_counts_round_trip_through_the_lookup_table() -> None:
    sim = FingerSimulator(scene="demo", seed=4, rate_hz=100)
    table = LookupTable.linear()  # what a daemon without a calibration file uses
    for tick in run(sim, sim.ticks_per_pass):
        assert tick.counts.dtype == np.uint16
        back = table.to_strain(tick.counts)
        assert np.max(np.abs(back - tick.strain)) <= 0.5 * COUNT + 1e-12
    # The closed-form default agrees with the table's own inverse.
    strain = np.random.default_rng(0).normal(0.01, 0.02, (500, 8, 8))
    assert np.array_equal(np.stack([sim.to_counts(s) for s in strain]), table.to_counts(strain))
    assert sim.to_counts(np.zeros((8, 8)))[0, 0] == ZERO_STRAIN_COUNTS


def test_custom_calibration_is_inverted() -> None:
    # A non-linear table: counts rise fast at first, then slowly.
    knots_c = [np.array([0.0, 12000.0, 30000.0, 65535.0])] * 64
    knots_s = [np.array([-0.5, 0.0, 0.02, 0.5])] * 64
    table = LookupTable(8, 8, knots_c, knots_s)
    sim = FingerSimulator(scene="press", seed=1, rate_hz=100, calibration=table)
    for tick in run(sim, sim.ticks_per_pass):
        back = table.to_strain(tick.counts)
        # strain per count on each piece of the table
        step = np.select([tick.strain < 0.0, tick.strain < 0.02], [0.5 / 12000, 0.02 / 18000],
                         0.48 / 35535)
        assert np.all(np.abs(back - tick.strain) <= 0.5 * step + 1e-12)
    with pytest.raises(ValueError, match="shape"):
        FingerSimulator(calibration=LookupTable.linear(4, 4))


def test_drift_magnitude_and_shape() -> None:
    model = DriftModel()
    documented = (0.002, 300.0, 0.0003, 60.0)
    assert (model.amplitude, model.period_s, model.walk_sigma, model.walk_tau_s) == documented
    sim = FingerSimulator(scene="empty", seed=5, rate_hz=10, noise=0.0, hysteresis=None)
    d = np.array([t.drift for t in run(sim, 6000)])  # 10 minutes, two periods
    assert not d[0].any()  # starts at zero
    assert np.abs(d).max() <= 0.002 + 5 * 0.0003
    assert np.abs(d).max() >= 0.002
    # Without the walk: the documented wave exactly, per-tactel gains in [0.5, 1].
    wave = FingerSimulator(scene="empty", seed=5, rate_hz=10, noise=0.0, hysteresis=None,
                           drift=DriftModel(walk_sigma=0.0))
    q = np.array([t.drift for t in run(wave, 751)])
    gains = q[750] / 0.002  # a quarter period in: sin = 1
    assert gains.min() >= 0.5 and gains.max() <= 1.0 and np.ptp(gains) > 0.2
    t = np.arange(751) / 10.0
    np.testing.assert_allclose(q, 0.002 * np.sin(2 * np.pi * t / 300.0)[:, None, None] * gains,
                               atol=1e-15)
    # The walk alone: long-run spread about walk_sigma.
    walk = FingerSimulator(scene="empty", seed=5, rate_hz=10, noise=0.0, hysteresis=None,
                           drift=DriftModel(amplitude=0.0))
    w = np.array([t.drift for t in run(walk, 6000)])[3000:]
    assert np.std(w) == pytest.approx(0.0003, rel=0.35)
    off = FingerSimulator(scene="empty", seed=5, rate_hz=10, noise=0.0, drift=None)
    assert not any(t.drift.any() for t in run(off, 100))


def _quick_release_scene():
    return (SceneBuilder(Pose(r1=10.0, x0=11.55, y0=13.65))
            .idle(0.1).press(0.2, force=1.0).hold(0.5).release(0.002, ease="linear").idle(4.0)
            .build("quick"))


def test_hysteresis_residual_after_release_decays_with_tau() -> None:
    sim = FingerSimulator(scene=_quick_release_scene(), seed=0, rate_hz=1000, noise=0.0,
                          drift=None, loop=False)
    ticks = run(sim, sim.ticks_per_pass)
    held = ticks[700]
    assert held.contact is not None and not held.residual.any()  # none while holding
    released = next(k for k, t in enumerate(ticks) if k > 300 and t.contact is None)
    peak = held.physics.max()
    i = int(np.argmax(held.physics))
    for delay in (0.0, 0.25, 0.5, 1.0, 1.5):
        k = released + round(delay * 1000)
        # 5 % of the released strain, decaying with tau = 0.5 s (the release itself took 2 ms).
        expected = 0.05 * peak * math.exp(-(delay + 0.002) / 0.5)
        assert ticks[k].residual.flat[i] == pytest.approx(expected, rel=0.02)
    assert not ticks[-1].residual.any()  # settled well within 4 s
    assert np.all(ticks[released].residual >= 0)


def test_hysteresis_can_be_tuned_or_switched_off() -> None:
    tuned = FingerSimulator(scene=_quick_release_scene(), seed=0, rate_hz=1000, noise=0.0,
                            drift=None, hysteresis=HysteresisModel(fraction=0.1, tau_s=0.2))
    ticks = run(tuned, 1500)
    after = [t for t in ticks if t.contact is None and t.index > 300]
    r0 = after[0].residual.max()
    r1 = after[200].residual.max()  # 0.2 s later
    assert r1 / r0 == pytest.approx(math.exp(-1.0), rel=0.02)
    off = FingerSimulator(scene=_quick_release_scene(), seed=0, rate_hz=1000, noise=0.0,
                          drift=None, hysteresis=None)
    assert not any(t.residual.any() for t in run(off, 1500))


def test_frames_carry_seq_time_and_sensor_id() -> None:
    sim = FingerSimulator(scene="press", seed=0, rate_hz=800, sensor_id=9)
    frames = sim.frames(20)
    assert [f.seq for f in frames] == list(range(20))
    assert [f.device_time_us for f in frames] == [round(k * 1250) for k in range(20)]
    assert {f.sensor_id for f in frames} == {9}
    decoder = FrameDecoder()
    got = decoder.feed(b"".join(encode_frame(f) for f in frames))
    assert [g.seq for g in got] == list(range(20))
    assert all(np.array_equal(g.raw, f.raw) for g, f in zip(got, frames))
    # seq wraps at 2^32.
    sim.skip(2**32 - 20 - 1)
    assert sim.next_frame().seq == 2**32 - 1 and sim.next_frame().seq == 0


def test_looping_and_single_pass() -> None:
    sim = FingerSimulator(scene="press", seed=0, rate_hz=100)
    n = sim.ticks_per_pass
    assert n == 300
    ticks = run(sim, 2 * n)
    assert [t.contact for t in ticks[:n]] == [t.contact for t in ticks[n:]]
    assert ticks[n].scene_time_s == 0.0 and ticks[n].time_s == pytest.approx(3.0)
    once = FingerSimulator(scene="press", seed=0, rate_hz=100, loop=False)
    late = run(once, 2 * n)[n:]
    assert all(t.contact is None for t in late)  # past the end: the last pose, untouched


def test_skip_integrates_state_over_the_gap() -> None:
    sim = FingerSimulator(scene=_quick_release_scene(), seed=0, rate_hz=1000, noise=0.0,
                          drift=None, loop=False)
    run(sim, 805)  # just after the release
    r0 = sim.step().residual.max()
    sim.skip(499)
    tick = sim.step()
    assert tick.index == 806 + 499
    assert tick.residual.max() / r0 == pytest.approx(math.exp(-1.0), rel=0.02)


def test_a_long_hold_survives_zeroing() -> None:
    # The point of the 'hold' scene: with drift, the zeroer must keep a held contact.
    sim = FingerSimulator(scene="hold", seed=3, rate_hz=100)
    table = LookupTable.linear()
    zeroer = Zeroer()
    peaks = []
    for tick in run(sim, 6000):  # 60 s: 12 zeroing time constants
        z = zeroer.update(table.to_strain(tick.counts), tick.time_s)
        peaks.append(z.max())
    held = sim.physics(sim.scene.contact_at(10.0)).max()
    assert zeroer.in_contact
    assert peaks[-1] == pytest.approx(held, abs=0.003)


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="rate_hz"):
        FingerSimulator(rate_hz=0)
    with pytest.raises(ValueError, match="noise"):
        FingerSimulator(noise=-1.0)
    with pytest.raises(ValueError, match="sensor_id"):
        FingerSimulator(sensor_id=70000)
    with pytest.raises(ValueError, match="unknown scene"):
        FingerSimulator(scene="nope")
    with pytest.raises(ValueError, match="fraction"):
        HysteresisModel(fraction=2.0)
    with pytest.raises(ValueError, match="period_s"):
        DriftModel(period_s=0.0)


def test_frame_schedule_never_drifts_and_skips_when_far_behind() -> None:
    s = FrameSchedule(1000.0, start=10.0, max_lag_s=0.5)
    assert s.take(10.0, 8) == (0, 1)  # frame 0 is due at the start
    assert s.take(10.0005, 8) == (0, 0)
    assert s.next_due() == pytest.approx(10.001)
    assert s.take(10.0105, 8) == (0, 8)  # behind by 10 frames: a batch of 8 ...
    assert s.take(10.0105, 8) == (0, 2)  # ... then the rest; no time is lost
    assert s.sent == 11
    skip, send = s.take(12.0, 8)  # starved for 2 s: stale frames are skipped, not burst
    assert (skip, send) == (2000 - 11, 1) and s.sent == 2001 and s.skipped == skip
    assert s.next_due() == pytest.approx(12.001)


def test_file_mode_helpers_still_work() -> None:
    model = StrainModel()
    c = Contact(10.0, math.inf, 90.0, 1.0, 11.55, 13.65)
    assert np.array_equal(render(c, model), model.predict(c))
    assert not render(None, model).any()
    frames = simulate_frames([c, None], noise=NoiseModel(sigma=0.0003, quantum=0.001), seed=1)
    assert frames.shape == (2, 8, 8)
    assert np.allclose(frames / 0.001, np.round(frames / 0.001))
    noisy = add_noise(np.zeros((8, 8)), NoiseModel(sigma=0.001), np.random.default_rng(0))
    assert noisy.std() > 0

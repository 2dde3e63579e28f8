"""The calibration stage's compiled path against its reference path (the objects' own numpy
methods): the same zeroed frames, contact decisions, statistics and state, frame after frame,
on simulated fingers (contacts, drift, the rubber's hysteresis compensated), glitch frames and
a tare in the middle; and on a damaged stream (frames lost, repeated, a device restart) with
drift followed around the held contact between frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled.calibration.detection import ContactDetector
from tactiled.calibration.lut import LookupTable
from tactiled.calibration.stage import CalibrationStage
from tactiled.calibration.zeroing import Zeroer
from tactiled.frames import Frame
from tactiled.sensors import load_description
from tactiled.sim import FingerSimulator


def _table(rows: int, cols: int, rng: np.random.Generator) -> LookupTable:
    """A gently non-linear table per tactel around the simulator's 10000 counts of zero."""
    counts, strain = [], []
    for _ in range(rows * cols):
        c = np.array([0.0, 8000.0, 10000.0, 14000.0, 30000.0, 65535.0]) + rng.uniform(-50, 50, 6)
        gain = rng.uniform(0.9, 1.1) * (1.0 + np.array([0.0, 0.02, 0.0, -0.03, -0.08, -0.1]))
        counts.append(c)
        strain.append((c - 10000.0) / 20000.0 * gain)
    return LookupTable(rows, cols, counts, strain)


def _stage(description: str, seed: int, average: int = 2) -> CalibrationStage:
    sensor = load_description(description).sensor_model()
    g = sensor.geometry
    zeroer = Zeroer((g.rows, g.cols), detector=ContactDetector(sensor=sensor, average=average))
    zeroer.hysteresis.set(0.05, 0.5)  # compensating, as once learnt
    return CalibrationStage(_table(g.rows, g.cols, np.random.default_rng(seed)), zeroer)


@pytest.mark.parametrize("description, scene, average", [
    ("fearing1988", "moving", 2), ("fearing1988", "demo", 1), ("flat16", "hand-palm", 2)])
def test_the_compiled_stage_equals_the_reference_frame_by_frame(description: str, scene: str,
                                                                 average: int) -> None:
    """The daemon's detector averages two frames at 1 kHz (detector_average); one frame too."""
    fast, ref = _stage(description, 7, average), _stage(description, 7, average)
    fast.compiled, ref.compiled = True, False
    sensor = load_description(description).sensor_model()
    sim = FingerSimulator(sensor, scene, seed=3)
    rng = np.random.default_rng(11)
    contacts = 0
    taken = []
    kernels = fast._compiled

    def counted(raw: np.ndarray, t: float) -> np.ndarray | None:
        z = kernels(raw, t)
        taken.append(z is not None)
        return z

    fast._compiled = counted  # type: ignore[method-assign]
    for k in range(2500):
        tick = sim.step()
        raw = tick.counts
        if k in (700, 701, 1900):  # a glitch: the ADC returned zeros (an implausible frame)
            raw = np.zeros_like(raw)
        elif rng.random() < 0.02:  # a few counts off by one or two: a noisier reading
            raw = (raw.astype(np.int64) + rng.integers(-2, 3, raw.shape)).clip(0, 65535).astype(np.uint16)
        if k == 1200:
            fast.tare()
            ref.tare()
        a = Frame(seq=k, device_time_us=tick.device_time_us, raw=raw.copy())
        b = Frame(seq=k, device_time_us=tick.device_time_us, raw=raw.copy())
        before = fast.zeroer._frames
        contacts += _same_frame(fast, ref, a, b, k)
        assert fast.zeroer._frames == ref.zeroer._frames == before + 1 or k in (0, 1200)
    # the compiled path took every frame but the first and the one after the tare
    assert contacts > 300 and sum(taken) == len(taken) - 2


def _same_frame(fast: CalibrationStage, ref: CalibrationStage, a: Frame, b: Frame,
                k: int) -> bool:
    """Process ``a`` on ``fast`` and its copy ``b`` on ``ref``; the outputs and every state
    the next frame depends on must agree.  Returns the contact flag."""
    ca, cb = fast.process(a), ref.process(b)
    assert ca == cb, k
    np.testing.assert_allclose(a.strain, b.strain, rtol=1e-12, atol=1e-15, err_msg=str(k))
    # the peak the compiled path gives is its frame's, as published (a contact frame's)
    assert math.isnan(ref.peak) and (not fast.finite or not ca or fast.peak == a.strain.max())
    za, zb = fast.zeroer, ref.zeroer
    assert za._frames == zb._frames and za._last_t == zb._last_t
    assert za.detector.last_statistic == pytest.approx(zb.detector.last_statistic, rel=1e-12, abs=1e-15)
    np.testing.assert_allclose(za.baseline, zb.baseline, rtol=1e-12, atol=1e-15)
    assert za.baseline_var == pytest.approx(zb.baseline_var, rel=1e-12)
    np.testing.assert_allclose(za.hysteresis._peak, zb.hysteresis._peak, rtol=1e-12, atol=1e-15)
    assert za.hysteresis._active == zb.hysteresis._active
    assert (za._residual is None) == (zb._residual is None)
    if za._residual is not None:
        np.testing.assert_allclose(za._residual, zb._residual, rtol=1e-12, atol=1e-15)
    assert (za.in_contact, za._release_until, za._settle_until) == \
        (zb.in_contact, zb._release_until, zb._settle_until)
    assert (za.detector._count, za.detector._head) == (zb.detector._count, zb.detector._head)
    np.testing.assert_allclose(za.detector._total, zb.detector._total, rtol=1e-12, atol=1e-15)
    return ca


def test_the_paths_agree_on_a_damaged_stream_with_drift_followed() -> None:
    """What a daemon does between frames on a damaged serial stream: frames lost (the
    device clock jumps), a frame delivered twice (no time step), a device that restarts (its
    clock goes back), and, while the contact is held, the zeroer following drift around a
    fit's prediction (the baseline moved in place), compensating the rubber's hysteresis, then
    learning it (the compensator switched off between two frames).  Both paths must stay
    equal frame by frame."""
    fast, ref = _stage("fearing1988", 5), _stage("fearing1988", 5)
    fast.compiled, ref.compiled = True, False
    for stage in (fast, ref):  # compensating, not learning: the learner starts at k = 1200
        stage.zeroer.learns_hysteresis = False
    sim = FingerSimulator(scene="press", seed=3, rate_hz=500, loop=True)
    rng = np.random.default_rng(4)
    restart_us = 0
    contacts = drift_steps = compensated = 0
    for k in range(2400):
        tick = sim.step()
        if k > 40 and rng.random() < 0.1:
            continue  # lost on the wire
        t_us = tick.device_time_us - restart_us
        if k == 1200:  # (its first step finds nothing significant: compensation off)
            fast.zeroer.learns_hysteresis = ref.zeroer.learns_hysteresis = True
        if k == 1700:  # the device restarted: its clock starts again near 0
            restart_us = tick.device_time_us - 1000
            t_us = 1000
        for _ in range(2 if rng.random() < 0.01 else 1):  # now and then delivered twice
            a = Frame(seq=k, device_time_us=t_us, raw=tick.counts.copy())
            b = Frame(seq=k, device_time_us=t_us, raw=tick.counts.copy())
            contacts += _same_frame(fast, ref, a, b, k)
            compensated += fast.zeroer._residual is not None
            if fast.in_contact:
                # a fit's prediction of this frame (the frame 3 % weaker: a model a little
                # off), its window the tactels above 5 sigma
                predicted = 0.97 * a.strain
                window = a.strain > 5 * fast.zeroer.detector.sigma
                moved = [s.zeroer.follow_drift(f.strain, f.device_time_us * 1e-6, predicted,
                                               window, fitted=True)
                         for s, f in ((fast, a), (ref, b))]
                assert moved[0] == moved[1], k
                drift_steps += moved[0]
                np.testing.assert_allclose(fast.zeroer.baseline, ref.zeroer.baseline,
                                           rtol=1e-12, atol=1e-15)
    assert contacts > 300 and drift_steps > 50 and compensated > 100
    assert fast.zeroer.hysteresis_learner.steps > 0 and fast.zeroer.hysteresis.fraction == 0.0


def test_frames_the_kernels_do_not_cover_take_the_reference_path() -> None:
    """A frame of float counts with a NaN: the reference path patches and counts it."""
    stage = _stage("fearing1988", 1)
    sim = FingerSimulator(scene="press", seed=2)
    for k in range(5):
        tick = sim.step()
        stage.process(Frame(seq=k, device_time_us=tick.device_time_us, raw=tick.counts))
    raw = sim.step().counts.astype(np.float64)
    raw[2, 3] = np.nan
    f = Frame(seq=5, device_time_us=5000, raw=raw)
    stage.process(f)
    assert stage.zeroer.nonfinite_frames == 1 and np.isfinite(f.strain).all() and f.strain[2, 3] == 0.0


def test_every_count_maps_as_the_table_does_at_every_segment_and_edge() -> None:
    """The kernel searches a tactel's own breakpoints: every count of the 16-bit range, at
    and around each tactel's breakpoints, and beyond them, gives the table's own value."""
    from tactiled.calibration.fused import zero_frame

    rows, cols = 4, 4
    table = _table(rows, cols, np.random.default_rng(5))
    seg = table._forward
    n = rows * cols
    counts = [np.arange(0, 65536, 997, dtype=np.int64)]
    for t in range(n):  # each tactel's breakpoints, and a count either side of each
        edges = np.round(table._counts[t]).astype(np.int64)
        counts.append(np.clip(np.concatenate([edges - 1, edges, edges + 1]), 0, 65535))
    queries = np.concatenate(counts)
    for q in queries:
        raw = np.full(n, q, dtype=np.uint16)
        raw[::3] = 65535 - raw[::3]  # neighbouring tactels far apart in the range
        z = np.empty(n)
        ax = np.zeros((1, rows))
        ay_t = np.zeros((cols, 1))
        bands = np.zeros((4, 1), dtype=np.int64)
        state, _, peak = zero_frame(raw, seg._offset, seg._breaks, seg._first, seg._params,
                                    np.zeros(n), np.zeros(n), 0.0, 1.0, 0.0, 0.0, False, ax,
                                    ay_t, bands, z, z, np.empty(1))
        assert state == 0
        np.testing.assert_array_equal(z, seg(raw.astype(np.float64)))
        assert peak == z.max()


def test_the_drift_following_kernels_match_the_numpy_arithmetic() -> None:
    """Zeroer.follow_drift's two passes against the arithmetic written out: the error and
    its sums, then the baseline's step (clipped pulls outside the window, their mean inside)."""
    from tactiled.calibration.fused import drift_error, pull_baseline

    rng = np.random.default_rng(12)
    zeroed, predicted = rng.normal(0.0, 1e-3, 64), rng.normal(0.0, 1e-3, 64)
    inside = rng.random(64) < 0.4
    error = np.empty(64)
    n_in, miss, finite = drift_error(zeroed, predicted, inside, error)
    expected = zeroed - predicted
    np.testing.assert_array_equal(error, expected)
    assert n_in == int(inside.sum()) and finite
    assert miss == pytest.approx(float(expected[inside] @ expected[inside]), rel=1e-12)
    baseline = rng.normal(0.0, 1e-3, 64)
    limit, weight = 1e-3, 0.01  # about a third of the errors beyond the limit: clipped
    pull = np.clip(expected, -limit, limit) * weight
    want = baseline + np.where(~inside, pull, float(pull[~inside].sum()) / (64 - n_in))
    pull_baseline(baseline, error, inside, limit, weight, 64 - n_in)
    np.testing.assert_allclose(baseline, want, rtol=1e-12, atol=1e-18)
    zeroed[5] = np.nan
    assert not drift_error(zeroed, predicted, inside, error)[2]

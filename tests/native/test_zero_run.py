"""A read's frames through the calibration stage in one call (``ZeroRun``): the core's and the
Python reference's give the same bits, on hypothesis-drawn frames and states, and
``CalibrationStage.process_run`` leaves the stage as ``process`` of each frame does."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactiled import native
from tactiled.calibration import fused_reference as ref
from tactiled.calibration.lut import LookupTable
from tactiled.calibration.stage import CalibrationStage
from tactiled.sensors.model import DEFAULT_SENSOR
from tactiled.frames import Frame

core = pytest.importorskip("tactiled._core") if native.core is None else native.core


def _stage(average: int = 1, hysteresis: tuple[float, float] | None = None) -> CalibrationStage:
    stage = CalibrationStage.for_sensor(LookupTable.linear(sensor_id=0), DEFAULT_SENSOR, 0.0005,
                                        1e-3, average, True)
    if hysteresis is not None:
        stage.zeroer.hysteresis.set(*hysteresis)
    return stage


def _run(kind: type, stage: CalibrationStage, raws: list[np.ndarray], times: np.ndarray,
         state: np.ndarray, constants: np.ndarray) -> tuple[int, list[np.ndarray]]:
    """``kind`` (the core's ZeroRun or the reference's) on copies of the stage's arrays:
    the frames taken, and every array it writes."""
    zr, det = stage.zeroer, stage.zeroer.detector
    seg = stage.table._forward
    n = len(raws)
    out = [zr.baseline.reshape(-1).copy(), zr.hysteresis._peak.reshape(-1).copy(),
           det._ring.copy(), det._total.copy(), np.zeros(zr.shape).reshape(-1),
           np.full((n, *zr.shape), np.nan), np.full(n, np.nan), np.full(n, np.nan), state.copy()]
    runner = kind(seg._offset, seg._breaks, seg._first, seg._params, out[0], out[1], det._ax,
                  det._ay_t, det._bands, out[2], out[3], out[4], constants)
    return runner.run(raws, times, out[5], out[6], out[7], out[8]), out


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(1, 12), average=st.sampled_from([1, 3]),
       fraction=st.sampled_from([0.0, 0.05]), in_contact=st.booleans(),
       level=st.sampled_from([0.0, 0.002, 0.02]), count=st.integers(0, 3))
def test_the_core_and_the_reference_take_a_run_alike(seed: int, n: int, average: int,
                                                     fraction: float, in_contact: bool,
                                                     level: float, count: int) -> None:
    rng = np.random.default_rng(seed)
    stage = _stage(average)
    table = stage.table
    rest = table.to_counts(rng.normal(0.0, 0.0005, (8, 8)))
    stage.process(Frame(seq=0, device_time_us=0, raw=rest, sensor_id=0))  # the baseline formed
    zr, det = stage.zeroer, stage.zeroer.detector
    zr.hysteresis._peak[:] = np.abs(rng.normal(0.0, 0.003, (8, 8)))
    strain = rng.normal(0.0, 0.0005, (n, 8, 8))
    strain[:, 2:5, 3:6] += level * rng.uniform(0.5, 1.5, (n, 3, 3))  # a press, or none
    raws = [table.to_counts(s) for s in strain]
    times = np.cumsum(rng.choice([0.0, 0.001, 0.005, 0.2], n)) + 0.3
    state = np.array((0.3, 5 + count, 0.25 if seed % 2 else 0.31, 0.2 + 0.5 * (seed % 3),
                      1e-8, in_contact, seed % 5 == 0, min(count, average), count % average,
                      0.001, in_contact, False, 0.0, False))
    sigma = det.sigma
    constants = np.array((fraction, 0.4, 3 * sigma, sigma, sigma, det.enter_threshold,
                          det.exit_threshold, zr.tau_drift, zr.tau_release, zr.holdoff,
                          10 * sigma, average))
    taken_core, a = _run(core.ZeroRun, stage, raws, times, state, constants)
    taken_ref, b = _run(ref.ZeroRun, stage, raws, times, state, constants)
    assert taken_core == taken_ref >= 1
    for x, y in zip(a, b):  # every array written, bit for bit (NaN where not written)
        np.testing.assert_array_equal(x, y)
    assert taken_core == n or a[8][5] == 1.0  # a run stops early only at a contact


def _stream() -> list[Frame]:
    """A press that comes and goes twice (a blob of strain, rolling), on a drifting, noisy
    array, at 200 Hz: 60 frames at rest first (the baseline forms), 60 at the end."""
    rng = np.random.default_rng(11)
    table = LookupTable.linear(sensor_id=0)
    rows, cols = np.mgrid[0:8, 0:8]
    frames = []
    for k in range(330):
        s = rng.normal(0.0, 0.0005, (8, 8)) + 3e-7 * k  # noise and drift
        if 60 <= k < 140 or 180 <= k < 270:
            force = 0.01 if k < 140 else 0.004
            cx = 3.5 + 2.0 * math.sin(0.05 * k)
            s += force * np.exp(-((rows - cx) ** 2 + (cols - 4.0) ** 2) / 2.0)
        frames.append(Frame(seq=k, device_time_us=5000 * k, raw=table.to_counts(s),
                            sensor_id=0))
    return frames


@pytest.mark.parametrize("average,hysteresis", [(1, None), (2, (0.04, 0.3))])
def test_process_run_leaves_the_stage_as_process_does(average: int, hysteresis) -> None:
    frames = _stream()
    one, run = _stage(average, hysteresis), _stage(average, hysteresis)
    expected = []
    for f in frames:
        contact = one.process(f)
        expected.append((f.strain.copy(), contact, one.zeroer.detector.last_statistic))
    k, calls, got = 0, 0, []
    run.process(frames[0])  # the first frame forms the baseline (the per-frame path's)
    got.append((frames[0].strain.copy(), run.in_contact, run.zeroer.detector.last_statistic))
    k = 1
    while k < len(frames):
        assert run.can_run()
        chunk = frames[k:k + 16]
        z = np.empty((len(chunk), 8, 8))
        times = np.array([f.device_time_us * 1e-6 for f in chunk])
        taken, stats, _ = run.process_run([f.raw for f in chunk], times, z)
        assert taken >= 1
        for i in range(taken):
            contact = run.in_contact and i == taken - 1
            got.append((z[i].copy(), contact, stats[i]))
        k += taken
        calls += 1
    # runs: a contact frame ends its run, the frames with none go 16 a call
    contacts = sum(c for _, c, _ in expected)
    assert calls <= contacts + (len(frames) - contacts) // 16 + 4
    assert [c for _, c, _ in got] == [c for _, c, _ in expected]
    assert any(c for _, c, _ in expected) and not expected[-1][1]
    for (z1, _, s1), (z2, _, s2) in zip(expected, got):
        np.testing.assert_array_equal(z1, z2)
        assert s1 == s2 or (math.isnan(s1) and math.isnan(s2))
    for name in ("baseline", "baseline_var", "in_contact", "_frames", "_last_t", "_release_until"):
        np.testing.assert_array_equal(getattr(one.zeroer, name), getattr(run.zeroer, name))
    np.testing.assert_array_equal(one.zeroer.hysteresis._peak, run.zeroer.hysteresis._peak)
    assert one.zeroer.hysteresis._active == run.zeroer.hysteresis._active
    np.testing.assert_array_equal(one.zeroer.detector._total, run.zeroer.detector._total)

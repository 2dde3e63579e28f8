"""The tracked pipeline when its fit cannot place the contact (a frame at the noise, a light
touch: the fit withholds the position, so there is nothing to track): the frames after it
that the gate finds unchanged reuse that fit, as the untracked pipeline does, instead of
each waiting for a fit of its own (the slowest fits there are, and all alike).  Driven
synchronously through the pipeline's own entry points; the worker's answer is a fit dict as a
worker sends it (no process needed to make one up)."""

from __future__ import annotations

import numpy as np

from tactiled.pipeline.estimate import GATE_FIT, GATE_UNCHANGED
from tactiled.pipeline.hub import Hub
from tactiled.pipeline.sensor import SensorPipeline
from tactiled.pipeline.sensor_tracking import _Waiting
from tactiled.settings import SensorSettings

SIGMA = 0.0005


class Pool:
    """What SensorPipeline needs of a pool, no processes: jobs stay with the test."""

    restarts = 0

    def __init__(self) -> None:
        self.wakes = 0

    def register_spec(self, sensor, options, finger=None) -> int:
        return 0

    def wake(self) -> None:
        self.wakes += 1


def frame(k: int, strain: np.ndarray) -> _Waiting:
    s = np.array(strain, dtype=float)
    s.flags.writeable = False
    return _Waiting(k, k, 1, k * 1000, 0.0, s, 0.0, k * 1e-3)


def unplaced_fit() -> dict:
    """A worker's answer for a frame at the noise: contact, position and shape withheld."""
    return {"contact": True, "model": "cylinder", "x_mm": None, "y_mm": None,
            "force_n": 0.02, "r1_mm": None, "r2_mm": None, "angle_deg": None,
            "std": {}, "reasons": {"x_mm": "not observable"}, "message": "test"}


def test_frames_unchanged_since_an_unplaceable_fit_reuse_it() -> None:
    hub = Hub()
    seen = []
    hub.add_listener(seen.append)
    pool = Pool()
    p = SensorPipeline(SensorSettings(name="f", url="sim://", noise_sigma=SIGMA),
                       pool=pool, hub=hub)
    rng = np.random.default_rng(3)
    light = np.zeros((8, 8))
    light[3:5, 3:5] = 2 * SIGMA  # a touch at the noise

    p.tracking.track(frame(1, light + rng.normal(0, SIGMA, (8, 8))), True, False)
    assert p.job_waiting_since() is not None and not p.job_background()
    job = p.take_job()
    p.tracking.track(frame(2, light + rng.normal(0, SIGMA, (8, 8))), True, False)  # waits behind it
    p.on_fit_result(job, unplaced_fit(), 3.0, None, None, None)
    # frame 1 gets its fit; frame 2, unchanged but for the noise, reuses it at once
    assert [(e.seq, e.gate, e.fitted_seq) for e in seen if e.kind == "estimate"] == [
        (1, GATE_FIT, 1), (2, GATE_UNCHANGED, 1)]
    assert p.job_waiting_since() is None and p.settled
    for k in range(3, 8):  # and so do the frames after it, with no fit
        p.tracking.track(frame(k, light + rng.normal(0, SIGMA, (8, 8))), True, False)
    est = [e for e in seen if e.kind == "estimate"]
    assert [e.gate for e in est[2:]] == [GATE_UNCHANGED] * 5
    assert all(e.fitted_seq == 1 and e.fit["x_mm"] is None for e in est)
    assert p.job_waiting_since() is None

    # a frame that changed (the contact pressed on) waits for a fit of its own
    firm = light * 20
    p.tracking.track(frame(8, firm + rng.normal(0, SIGMA, (8, 8))), True, False)
    assert p.job_waiting_since() is not None and len(est) == 7
    assert len([e for e in seen if e.kind == "estimate"]) == 7


def test_without_reuse_every_such_frame_waits_for_a_fit() -> None:
    """``reuse_unchanged = false`` turns the gate off here too."""
    hub = Hub()
    seen = []
    hub.add_listener(seen.append)
    p = SensorPipeline(SensorSettings(name="f", url="sim://", noise_sigma=SIGMA,
                                      reuse_unchanged=False), pool=Pool(), hub=hub)
    light = np.zeros((8, 8))
    light[3:5, 3:5] = 2 * SIGMA
    p.tracking.track(frame(1, light), True, False)
    job = p.take_job()
    p.on_fit_result(job, unplaced_fit(), 3.0, None, None, None)
    p.tracking.track(frame(2, light), True, False)
    assert p.job_waiting_since() is not None
    assert [e.gate for e in seen if e.kind == "estimate"] == [GATE_FIT]

"""The tracked pipeline's jobs: a frame's fit never waits for the tracker's relinearisation.

A relinearisation answers no frame; it only moves the point the tracker measures frames
through.  A frame that left the linear range waits for a fit of its own, so that fit goes to a
worker at once, even while a relinearisation of the same sensor is in flight (before, it
waited for that round trip: ~1-2 ms at the median on the moving scene).  The fit brings its own
linearisation; the older one, answered after it, is ignored.  Driven synchronously through the
pipeline's own entry points, with the worker's work (a real fit and a real linearisation) done
in this process: no worker process is needed to make the answers."""

from __future__ import annotations

import math

import numpy as np
from pipeline_helpers import InProcessPool as Pool
from pipeline_helpers import answer

from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.physics.contact import Contact
from tactiled.physics.strain import predict_strain
from tactiled.pipeline.estimate import GATE_FIT
from tactiled.pipeline.hub import Hub
from tactiled.pipeline.sensor import SensorPipeline
from tactiled.pipeline.sensor_tracking import _Waiting
from tactiled.settings import SensorSettings

SIGMA = 0.0005


def frame(k: int, strain: np.ndarray) -> _Waiting:
    s = np.array(strain, dtype=float)
    s.flags.writeable = False
    return _Waiting(k, k, 1, k * 1000, 0.0, s, 0.0, k * 1e-3)


def test_a_frames_fit_goes_out_while_a_relinearisation_is_in_flight() -> None:
    hub = Hub()
    seen = []
    hub.add_listener(seen.append)
    pool = Pool()
    p = SensorPipeline(SensorSettings(name="f", url="sim://", noise_sigma=SIGMA, model="cylinder"),
                       pool=pool, hub=hub)
    fitter = Fitter(pool.sensor, FitOptions(**dict(pool.options)))
    rng = np.random.default_rng(5)

    def pressed(k: int, x0: float, force: float) -> _Waiting:
        c = Contact(10.0, math.inf, 90.0, force, x0, 13.0)
        return frame(k, predict_strain(c) + rng.normal(0.0, SIGMA, (8, 8)))

    # the contact's first frame: a fit, then frames measured by the tracker as it rolls
    p.tracking.track(pressed(1, 11.0, 1.0), True, False)
    answer(p, fitter, p.take_job())
    assert p.tracking.tracker.active and p.fitted == 1
    k = 1
    while not p.job_background():  # rolling 20 um a frame: soon a relinearisation is due
        k += 1
        assert k < 40, "the tracker never asked to relinearise"
        p.tracking.track(pressed(k, 11.0 + 0.02 * (k - 1), 1.0), True, False)
    relin = p.take_job()
    assert relin.kind == "lin" and not p.settled

    # the force doubles: outside the linear range, the frame waits for a fit of its own, and
    # that fit can go to a worker now, while the relinearisation is still in flight
    k += 1
    p.tracking.track(pressed(k, 11.0 + 0.02 * (k - 1), 2.0), True, False)
    assert p.job_waiting_since() is not None and not p.job_background()
    fit_job = p.take_job()
    assert fit_job.kind == "fit+lin" and fit_job.seq == k

    # the fit answers first: the frame is published with it, and the tracker measures
    # through the fit's linearisation ...
    answer(p, fitter, fit_job)
    est = [e for e in seen if e.kind == "estimate"]
    assert (est[-1].seq, est[-1].gate) == (k, GATE_FIT)
    assert abs(est[-1].fit["force_n"] - 2.0) < 0.2
    lin_of_fit = p.tracking.tracker.lin
    assert p.fitted == 2
    # ... and the relinearisation asked for before the step, answered after it, is ignored
    relinearized = p.tracking.relinearized
    answer(p, fitter, relin)
    assert p.tracking.tracker.lin is lin_of_fit and p.tracking.relinearized == relinearized
    assert p.settled
    # the frames after the step are measured at the new force
    p.tracking.track(pressed(k + 1, 11.0 + 0.02 * k, 2.0), True, False)
    est = [e for e in seen if e.kind == "estimate"]
    assert est[-1].seq == k + 1 and abs(est[-1].fit["force_n"] - 2.0) < 0.2


def test_one_relinearisation_at_a_time_and_none_beside_a_frames_fit() -> None:
    """A second relinearisation waits for the first; none goes out while a frame is fitted
    (its fit brings a linearisation anyway)."""
    pool = Pool()
    p = SensorPipeline(SensorSettings(name="f", url="sim://", noise_sigma=SIGMA), pool=pool,
                       hub=Hub())
    lin = frame(1, np.zeros((8, 8)))
    lin.kind, lin.at = "lin", ("cylinder", (2.3, 1.5, 0.0, 11.0, 13.0))
    p._waiting = lin
    assert p.job_waiting_since() is not None and p.job_background()
    p.take_job()
    again = frame(2, np.zeros((8, 8)))
    again.kind, again.at = "lin", lin.at
    p._waiting = again
    assert p.job_waiting_since() is None  # behind the one in flight
    p._lin_in_flight = None
    p._in_flight = frame(3, np.zeros((8, 8)))
    assert p.job_waiting_since() is None  # behind a frame's fit


def _lin_times(first_asked: float | None = None, frames: int = 1500) -> list[float]:
    """Device times (s) of the relinearisations a moving contact (the moving scene, 1 kHz)
    asks for, every job answered at once; ``first_asked``: the time the pipeline last asked,
    as left by an earlier run of the device's clock."""
    from tactiled.pipeline import sensor_tracking as sensor_module
    from tactiled.sim import FingerSimulator

    sim = FingerSimulator(scene="moving", seed=1, sensor_id=1)
    pool = Pool()
    p = SensorPipeline(SensorSettings(name="f", url="sim://"), pool=pool, hub=Hub())
    fitter = Fitter(pool.sensor, FitOptions(**dict(pool.options)))
    if first_asked is not None:
        p.tracking.lin_asked_t = first_asked
    asked = []
    for _ in range(frames):
        p.on_frame(sim.next_frame())
        while p._waiting is not None and p._in_flight is None:
            job = p.take_job()
            if job.kind == "lin":
                asked.append(job.seq * 1e-3)
            answer(p, fitter, job)
    assert sensor_module.MIN_RELINEARIZE_S == 0.004
    return asked


def test_relinearisations_are_asked_for_at_most_every_4_ms() -> None:
    asked = _lin_times()
    assert len(asked) > 100  # the contact moved: it was relinearised, and often
    assert min(np.diff(asked)) >= 0.004 - 1e-9


def test_a_device_clock_that_went_back_does_not_stop_relinearising() -> None:
    # as if the device had run for an hour before a restart brought its clock back to 0
    asked = _lin_times(first_asked=3600.0)
    assert len(asked) > 100

"""Frames waiting for a late fit go out at ``MAX_WAIT_S`` on a timer, not when the next frame
comes.

A tracked contact's frame that left the linear range waits for a fit of its own; when the fit
is late (a loaded machine) the frames waiting get the contact predicted to their time once the
oldest has waited ``MAX_WAIT_S``.  That used to be checked only when the sensor's next frame
arrived, so a sensor whose frames stop (or come slowly) held its last frames for as long.
Driven through the pipeline's own entry points inside a running event loop, with the worker's
work (a real fit and a real linearisation) done in this process; the frame's fit is taken and
never answered, as a worker that is late."""

from __future__ import annotations

import asyncio
import math
import time

import numpy as np
from pipeline_helpers import InProcessPool as Pool
from pipeline_helpers import answer

from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.physics.contact import Contact
from tactiled.physics.strain import predict_strain
from tactiled.pipeline.estimate import GATE_UNCHANGED
from tactiled.pipeline.hub import Hub
from tactiled.pipeline.sensor import SensorPipeline
from tactiled.pipeline.sensor_tracking import MAX_WAIT_S, _Waiting
from tactiled.settings import SensorSettings

SIGMA = 0.0005


def test_frames_waiting_for_a_late_fit_go_out_predicted_with_no_next_frame() -> None:
    async def main() -> None:
        hub = Hub()
        seen = []
        hub.add_listener(seen.append)
        pool = Pool()
        p = SensorPipeline(SensorSettings(name="f", url="sim://", noise_sigma=SIGMA,
                                          model="cylinder"), pool=pool, hub=hub)
        assert not p.lossless
        fitter = Fitter(pool.sensor, FitOptions(**dict(pool.options)))
        rng = np.random.default_rng(5)

        def pressed(k: int, force: float) -> _Waiting:
            s = predict_strain(Contact(10.0, math.inf, 90.0, force, 11.0, 13.0))
            s = np.array(s + rng.normal(0.0, SIGMA, (8, 8)))
            s.flags.writeable = False
            return _Waiting(k, k, 1, k * 1000, time.monotonic(), s, time.monotonic(), k * 1e-3)

        p.tracking.track(pressed(1, 1.0), True, False)  # the contact's first frame: a fit
        answer(p, fitter, p.take_job())
        for k in (2, 3):  # measured by the tracker as they come
            p.tracking.track(pressed(k, 1.0), True, False)
        assert p.tracking.tracker.started and p.tracking.tracked == 2

        late = pressed(4, 2.0)  # the force doubles: the frame waits for a fit of its own ...
        p.tracking.track(late, True, False)
        job = p.take_job()  # ... which a worker takes and does not answer in time
        assert job.seq == 4 and p.tracking.pending
        deadline = time.monotonic() + 5.0
        while not any(e.kind == "estimate" and e.seq == 4 for e in seen):
            assert time.monotonic() < deadline, "the waiting frame never went out"
            await asyncio.sleep(0.001)  # (the loop's turn: the timer runs in it)
        est = next(e for e in seen if e.kind == "estimate" and e.seq == 4)
        assert est.gate == GATE_UNCHANGED and est.contact and p.tracking.predicted == 1
        # not before its time: the oldest waiting frame had waited MAX_WAIT_S
        assert est.published_time - late.since >= MAX_WAIT_S
        assert not p.tracking.pending
        # the fit, answered late, still serves the tracker; nothing is published twice
        answer(p, fitter, job)
        assert [e.seq for e in seen if e.kind == "estimate"].count(4) == 1

    asyncio.run(main())

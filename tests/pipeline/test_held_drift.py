"""A contact held for long on a drifting finger: the zeroer follows the drift around it, so the
estimate keeps its value and the finger lets go when the contact does.

The zeroer freezes its baseline while a contact is held (a held contact is never absorbed).
Drift went on under it: on the simulated finger (drift up to 4e-5 strain a second, a tenth of
a noise sigma) a 1 N grasp held for 40 s read 7-8 % heavy by its end, and after the release the
drift alone held the detector above its exit threshold: the finger never let go, and every frame
after was fitted as a contact.  Now, while the tracker measures the held contact, the zeroer
follows drift where its linearisation's prediction explains the frame (``Zeroer.follow_drift``).
Driven synchronously through the pipeline's own entry points with the worker's work (real fits
and linearisations) done in this process, as in test_tracked_dispatch.py."""

from __future__ import annotations

import time

import numpy as np
import pytest
from pipeline_helpers import InProcessPool, answer

from tactiled.sensors.model import Geometry
from tactiled.sensors.finger import FingerSpec
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.pipeline.hub import Hub
from tactiled.pipeline.sensor import SensorPipeline
from tactiled.settings import SensorSettings
from tactiled.sim import FingerSimulator, Pose, SceneBuilder


RATE = 250.0  # Hz: the drift is a matter of seconds, not of frames
HOLD = 40.0  # s
FORCE = 1.0  # N


def _held(seed: int, follow: bool = True, *, force: float = FORCE, rate: float = RATE,
          finger: FingerSpec | None = None) -> tuple[float | None, int, float, SensorPipeline]:
    """A ``force`` N cylinder held ``HOLD`` s on the simulated ``finger`` (default the
    model's), frames at ``rate`` Hz: (seconds from the release to the detector's exit or None,
    contact frames from 3 s after the release on, median force of the hold's last second,
    the pipeline)."""
    g = Geometry()
    xc, yc = g.span_x / 2.0, g.span_y / 2.0  # the array's centre
    scene = (SceneBuilder(Pose(r1=10.0, psi_deg=60.0, x0=xc, y0=yc)).idle(1.0)
             .press(0.3, force=force).hold(HOLD).release(0.1).idle(6.0).build("long hold"))
    sim = FingerSimulator(scene=scene, seed=seed, loop=False, rate_hz=rate, finger=finger)
    hub = Hub()
    estimates = []
    hub.add_listener(lambda item: estimates.append(item) if hasattr(item, "gate") else None)
    pool = InProcessPool()
    p = SensorPipeline(SensorSettings(name="f", url="sim://"), pool=pool, hub=hub)
    if not follow:
        p.tracking.follow_drift = lambda w, fitted=False: None  # the code before: the baseline frozen whole
    fitter = Fitter(pool.sensor, FitOptions(**dict(pool.options)))
    released = 1.0 + 0.3 + HOLD + 0.1
    exit_after, late = None, 0
    for k in range(round((released + 6.0) * rate)):
        f = sim.next_frame()
        f.host_time = time.monotonic()
        p.on_frame(f)
        while p._waiting is not None and p._in_flight is None:
            answer(p, fitter, p.take_job())
        t = k / rate
        in_contact = p.stage.zeroer.in_contact
        if t > released and exit_after is None and not in_contact:
            exit_after = t - released
        late += t > released + 3.0 and in_contact
    last = [e.fit["force_n"] for e in estimates
            if (released - 1.2) * rate <= e.seq < (released - 0.2) * rate and e.fit.get("force_n")]
    return exit_after, late, float(np.median(last)), p


@pytest.mark.parametrize("seed", [1, pytest.param(3, marks=pytest.mark.slow)])
def test_a_contact_held_for_40_s_keeps_its_force_and_is_let_go(seed: int) -> None:
    """Seed 1 in every run (the control below holds the same draw); seed 3 too with
    ``-m slow`` (each hold is ~12 000 frames through the pipeline, fitted in this process)."""
    exit_after, late, force, p = _held(seed)
    assert exit_after is not None and exit_after < 1.5, exit_after
    assert late == 0
    # the drift of 40 s (up to 1.6e-3 strain, ~3 noise sigmas) is not read as force
    assert force == pytest.approx(FORCE, rel=0.03), force
    assert p.tracking.drift_followed > 0.5 * HOLD / 0.01  # followed most of the hold, every 10 ms at most
    assert p.stats().drift_followed == p.tracking.drift_followed


def test_without_following_the_drift_the_finger_never_lets_go() -> None:
    """The control: the same hold with the baseline frozen whole (the code before)."""
    exit_after, late, force, _ = _held(1, follow=False)
    assert exit_after is None and late > 0
    assert force > 1.05 * FORCE


def test_a_finger_that_departs_from_its_model_is_let_go_too() -> None:
    """A rubber nobody identified (15 % deeper, 20 % softer than the model): the tracker
    cannot measure its frames (they are fitted, nearly all of them), and no prediction explains
    them within noise; the fit of each frame is the best the model gives, and the drift is
    followed from it.  2 N held 40 s, at 100 Hz."""
    paper = FingerSpec()
    finger = FingerSpec(depth_x=paper.depth_x * 1.15, depth_y=paper.depth_y * 1.15,
                        modulus=paper.modulus * 0.8)
    exit_after, late, force, p = _held(1, force=2.0, rate=100.0, finger=finger)
    assert exit_after is not None and exit_after < 1.5, exit_after
    assert late == 0
    assert p.tracking.drift_followed > 0.5 * HOLD / 0.01
    # (its force reads high, 2.33 N: the finger's departure, which only identifying it removes)

"""A tracked contact pressed from a light touch is fitted again each time its largest strain
doubles since the frame its fit was of (``signal_grown``): the model and the curvatures that
light frame chose are not the filter's to learn.  A contact held at one force is not.  A real
SensorPipeline on physics-true frames of the paper's finger, its fits made in this process."""

from __future__ import annotations

import math

from pipeline_helpers import InProcessPool as Pool
from pipeline_helpers import answer, contact_path, make_frames

from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.physics.contact import Contact
from tactiled.pipeline.hub import Hub
from tactiled.pipeline.sensor import SensorPipeline
from tactiled.pipeline.sensor_tracking import REFIT_SIGNAL_RATIO
from tactiled.settings import SensorSettings


def _run(contacts: list[Contact]) -> tuple[SensorPipeline, list]:
    pool = Pool()
    hub = Hub()
    p = SensorPipeline(SensorSettings(name="f", url="sim://", noise_sigma=0.0005,
                                      model="cylinder"), pool=pool, hub=hub)
    out: list = []
    hub.add_listener(lambda it: out.append(it) if it.kind == "estimate" else None)
    fitter = Fitter(pool.sensor, FitOptions(**dict(pool.options)))
    for frame in make_frames(contacts, tail=5):
        p.on_frame(frame)
        while p._waiting is not None and p._in_flight is None:
            answer(p, fitter, p.take_job())
    return p, out


def test_a_contact_pressed_harder_is_fitted_again_as_its_strain_doubles() -> None:
    # a 10 mm cylinder pressed from 0.1 to 3.4 N over 120 frames, held in place
    ramp = [Contact(10.0, math.inf, 90.0, 0.1 * 1.03 ** k, 9.0, 13.0) for k in range(120)]
    p, estimates = _run(ramp)
    grown = p.stats().signal_grown
    fitted = [e for e in estimates if e.contact and e.gate == "fit"]
    # the strain grows about 34-fold: a few doublings, each a fit, and no more
    assert 2 <= grown <= math.ceil(math.log(34.0, REFIT_SIGNAL_RATIO)) + 1, grown
    assert len(fitted) >= grown + 1  # (and the contact's first fit)
    held, _ = _run(contact_path(120, force=1.0, moving=False))
    assert held.stats().signal_grown == 0

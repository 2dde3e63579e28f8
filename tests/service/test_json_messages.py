"""Message building: the display ellipse, the envelope, encoding once per item."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tactiled.fit.result import FitResult
from tactiled.physics.hertz import contact_ellipse_radii
from tactiled.pipeline.estimate import ZeroedFrame, make_estimate
from tactiled_service.json_messages import SCHEMA_VERSION, Encoder, display_ellipse


def fit_line(**values) -> dict:
    line = FitResult(contact=True, model="cylinder").to_json_dict()
    line.update(values)
    return line


def test_ellipse_of_a_cylinder_matches_hertz():
    line = fit_line(r1_mm=10.0, r2_mm=None, angle_deg=30.0, force_n=1.2)
    ell = display_ellipse(line, 12.7, 3.0)
    ref = contact_ellipse_radii(10.0, math.inf, 30.0, 1.2, 12.7, 3.0)
    assert ell == {"a_mm": round(ref.a, 4), "b_mm": round(ref.b, 4),
                   "theta_deg": round(math.degrees(ref.theta) % 180, 3)}
    assert ell["a_mm"] >= ell["b_mm"] > 0


def test_ellipse_of_a_sphere_has_no_angle_input():
    ell = display_ellipse(fit_line(model="sphere", r1_mm=8.0, r2_mm=8.0, angle_deg=None,
                                   force_n=1.5), 12.7, 3.0)
    assert ell is not None and ell["a_mm"] >= ell["b_mm"]


@pytest.mark.parametrize("line", [
    FitResult(contact=False).to_json_dict(),
    fit_line(r1_mm=None, force_n=1.0),
    fit_line(r1_mm=10.0, force_n=None),
    fit_line(r1_mm=10.0, r2_mm=None, angle_deg=0.0, force_n=1.0),  # an infinite line contact
])
def test_no_ellipse_when_hertz_cannot_say(line):
    assert display_ellipse(line, 12.7, 3.0) is None


def test_the_pipelines_own_ellipse_wins():
    own = {"a_mm": 1.0, "b_mm": 0.5, "theta_deg": 10.0}
    assert display_ellipse(fit_line(ellipse=own, r1_mm=10.0, force_n=1.0), 12.7, 3.0) is own


def test_messages_are_encoded_once_per_item():
    enc = Encoder({"f": (12.7, 3.0)})
    est = make_estimate(sensor="f", sensor_id=0, seq=7, device_time_us=7000, host_time=1.0,
                        gate="fit", fitted_seq=7, worker_ms=1.0,
                        fit=fit_line(r1_mm=10.0, angle_deg=90.0, force_n=1.0))
    text = enc.text(est)
    assert enc.text(est) is text
    msg = json.loads(text)
    assert (msg["type"], msg["v"], msg["sensor"], msg["seq"]) == ("estimate", SCHEMA_VERSION,
                                                                   "f", 7)
    assert "class" not in msg and msg["ellipse"]["a_mm"] > 0
    frame = ZeroedFrame("f", 0, 8, 8000, 1.0, False, 0.0, np.full((8, 8), 1e-4))
    fm = json.loads(enc.text(frame))
    assert (fm["type"], fm["rows"], fm["cols"], fm["seq"]) == ("frame", 8, 8, 8)



def test_each_of_several_contacts_gets_its_own_ellipse():
    # an estimate listing two contacts: each element is drawn with its own Hertz ellipse, the
    # one computed for its values alone; the top level keeps the strongest contact's
    enc = Encoder({"f": (12.7, 3.0)})
    strong = {**fit_line(r1_mm=10.0, angle_deg=90.0, force_n=1.0), "contact_id": 3}
    weak = {**fit_line(r1_mm=6.0, angle_deg=20.0, force_n=0.4), "contact_id": 7}
    est = make_estimate(sensor="f", sensor_id=0, seq=9, device_time_us=9000, host_time=1.0,
                        gate="fit", fitted_seq=9, worker_ms=1.0,
                        fit={**strong, "contacts": [strong, weak]})
    before = json.dumps(weak)
    msg = json.loads(enc.text(est))
    got = [c["ellipse"] for c in msg["contacts"]]
    assert got == [display_ellipse(strong, 12.7, 3.0), display_ellipse(weak, 12.7, 3.0)]
    assert got[0] == msg["ellipse"] and got[0] != got[1]
    assert [c["contact_id"] for c in msg["contacts"]] == [3, 7]
    assert json.dumps(weak) == before, "the pipeline's fit line is read-only"

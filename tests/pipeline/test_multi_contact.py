"""Each contact's filter follows its contact across fits (tactiled.pipeline.multi_contact): matched by
place, a new contact starts a filter, a contact gone ends its own, a relinearisation that no
longer fits the contacts held is refused.  Real fits and linearisations of the paper's finger."""

from __future__ import annotations

import numpy as np
import pytest

from tactiled.sensors.model import SensorModel
from tactiled.fit.fitter import Fitter
from tactiled.fit.multi import contacts_json, fit_contacts, linearize_several
from tactiled.fit.linearize import linearize
from tactiled.fit.warm import SEVERAL
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
from tactiled.pipeline.estimate import plain
from tactiled.pipeline.multi_contact import ContactTrackers
from tactiled.pipeline.contact_filter import Tracker

A = Contact(5.0, 5.0, 0.0, 1.2, 7.0, 11.0)
B = Contact(8.0, 8.0, 0.0, 0.6, 18.0, 16.0)


@pytest.fixture(scope="module")
def kit():
    sensor = SensorModel()
    return Fitter(sensor), StrainModel(sensor), sensor


def _several(kit, truths, seed=0):
    fitter, model, _ = kit
    frame = sum((model.predict(c) for c in truths), np.zeros((8, 8)))
    frame = frame + np.random.default_rng(seed).normal(0.0, 0.0005, frame.shape)
    res = fit_contacts(fitter, frame, "sphere")
    assert len(res) == len(truths)
    order = sorted(range(len(res)), key=lambda i: -(res[i].values["force_n"] or 0.0))
    lin = linearize_several(fitter, frame, [(res[i].model, res[i].params) for i in order])
    return frame, lin, plain(contacts_json(res))


def _trackers(kit) -> ContactTrackers:
    return ContactTrackers(lambda: Tracker(geometry=kit[2].geometry), gate_mm=3.8)


def test_filters_follow_their_contacts_across_fits(kit) -> None:
    ct = _trackers(kit)
    frame, lin, base = _several(kit, [A, B])
    assert lin is not None and lin.model == SEVERAL and len(lin.lins) == 2
    assert ct.adopt(lin, 0.0, base) and ct.several and ct.model == SEVERAL
    ct.step(frame.ravel(), 0.0, fitted=True)
    rng = np.random.default_rng(1)
    clean = frame - np.random.default_rng(0).normal(0.0, 0.0005, frame.shape)
    for k in range(1, 30):
        assert ct.step((clean + rng.normal(0.0, 0.0005, frame.shape)).ravel(), k * 1e-3) != "refit"
    est = ct.estimate(base)
    assert [c["frames_used"] for c in est["contacts"]] == [30, 30]
    assert est["force_n"] == est["contacts"][0]["force_n"] > est["contacts"][1]["force_n"]
    by_force = {round(c["force_n"], 1): c for c in est["contacts"]}
    assert abs(by_force[1.2]["x_mm"] - A.x0) < 0.2 and abs(by_force[0.6]["x_mm"] - B.x0) < 0.2
    held_b = next(tr for tr in ct.trackers if abs(tr.x[-2] - B.x0) < 1.0)

    # A is lifted: B's filter goes on, A's ends
    fitter = kit[0]
    only_b = kit[1].predict(B)
    res = fitter.fit(only_b, "sphere")
    one = linearize(fitter, only_b, res.model, np.array(res.params))
    assert ct.adopt(one, 0.0) and not ct.several
    assert ct.trackers[0] is held_b and held_b.n == 30
    # a relinearisation of two contacts no longer fits the one held
    assert not ct.adopt(lin, 0.0)

    # A pressed again, listed second this time: B keeps its filter, A starts a new one
    frame2, lin2, base2 = _several(kit, [B, A], seed=3)
    assert ct.adopt(lin2, 0.0, base2) and ct.several
    assert any(tr is held_b for tr in ct.trackers)
    fresh = next(tr for tr in ct.trackers if tr is not held_b)
    assert fresh.x is None and abs(float(fresh.lin.p[-2]) - A.x0) < 0.5

    ct.clear()
    assert not ct.several and not ct.active and ct.bases == []

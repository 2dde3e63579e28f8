"""Several contacts on one array: regions, fits of several, the joint bound (tactiled.fit.regions,
tactiled.fit.multi).  Frames are the physics' own (sums of predict_strain) plus seeded noise."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.models import get_model
from tactiled.fit.multi import contacts_json, fit_contacts, joint_bounds, predicted_strain
from tactiled.fit.regions import find_regions
from tactiled.physics.contact import Contact, LineContact
from tactiled.physics.strain import StrainModel
from tactiled.sensors import load_description

SIGMA = 0.0005


def _setup(name: str):
    desc = load_description(name)
    sensor = desc.sensor_model()
    fitter = Fitter(sensor, FitOptions(window=desc.window))
    fitter.frozen = True
    return sensor, StrainModel(sensor), fitter


@pytest.fixture(scope="module", params=["fearing1988", "flat16"])
def array(request):
    return _setup(request.param)


def _centre(sensor) -> tuple[float, float]:
    g = sensor.geometry
    return 0.5 * g.span_x, 0.5 * g.span_y


def test_one_contact_of_any_size_is_one_region(array) -> None:
    sensor, model, _ = array
    cx, cy = _centre(sensor)
    rng = np.random.default_rng(1)
    for r in (1.0, 5.0, 30.0, 150.0):
        clean = model.predict(Contact(r, r, 0.0, 1.0, cx, cy))
        for _ in range(20):
            regions = find_regions(clean + rng.normal(0.0, SIGMA, clean.shape), SIGMA)
            assert len(regions) == 1 and regions[0].absorbed == 0, r


def test_far_apart_contacts_are_separate_regions_and_close_ones_one(array) -> None:
    sensor, model, _ = array
    cx, cy = _centre(sensor)
    depth = max(sensor.impulse.depth_x, sensor.impulse.depth_y)
    rng = np.random.default_rng(2)

    def regions(sep: float) -> int:
        a = Contact(4.0, 4.0, 0.0, 1.0, cx - sep / 2, cy)
        b = Contact(4.0, 4.0, 0.0, 0.7, cx + sep / 2, cy)
        clean = model.predict(a) + model.predict(b)
        return len(find_regions(clean + rng.normal(0.0, SIGMA, clean.shape), SIGMA))

    assert regions(3.0 * depth) == 2
    assert regions(0.5 * depth) == 1  # the cover spreads them into one bump


def test_regions_leave_out_masked_tactels_and_noise() -> None:
    sensor, model, _ = _setup("fearing1988")
    rng = np.random.default_rng(3)
    assert find_regions(rng.normal(0.0, SIGMA, (8, 8)), SIGMA) == []
    clean = model.predict(Contact(4.0, 4.0, 0.0, 1.0, 5.0, 6.0)) + model.predict(
        Contact(4.0, 4.0, 0.0, 1.0, 18.0, 20.0))
    mask = np.ones((8, 8), bool)
    peak = np.unravel_index(np.argmax(clean), clean.shape)
    both = find_regions(clean, SIGMA)
    assert len(both) == 2
    # the second contact's tactels masked out: only the first is left
    mask[both[1].tactels] = False
    only = find_regions(clean, SIGMA, mask)
    assert len(only) == 1 and only[0].peak_idx == both[0].peak_idx == tuple(map(int, peak))


def test_a_single_contact_fits_exactly_as_the_single_contact_fitter(array) -> None:
    sensor, model, fitter = array
    cx, cy = _centre(sensor)
    rng = np.random.default_rng(4)
    frame = model.predict(Contact(6.0, 6.0, 0.0, 1.0, cx + 1.0, cy - 1.0))
    frame = frame + rng.normal(0.0, SIGMA, frame.shape)
    (res,) = fit_contacts(fitter, frame, "sphere")
    alone = fitter.fit(frame, "sphere")
    a, b = res.to_json_dict(), alone.to_json_dict()
    a.pop("fit_ms"), b.pop("fit_ms")
    assert a == b
    assert "contacts" not in contacts_json([res])


def test_two_contacts_are_each_recovered_within_their_sigmas(array) -> None:
    sensor, model, fitter = array
    g = sensor.geometry
    truths = [Contact(5.0, 5.0, 0.0, 1.0, 0.25 * g.span_x, 0.3 * g.span_y),
              Contact(9.0, 9.0, 0.0, 0.6, 0.75 * g.span_x, 0.7 * g.span_y)]
    clean = sum(model.predict(c) for c in truths)
    rng = np.random.default_rng(5)
    z = []
    for _ in range(10):
        fits = fit_contacts(fitter, clean + rng.normal(0.0, SIGMA, clean.shape), "sphere")
        assert len(fits) == 2
        assert all("one of 2 contacts" in r.reasons["contacts"] for r in fits)
        for r in fits:
            c = min(truths, key=lambda c: math.dist((c.x0, c.y0), (r.values["x_mm"], r.values["y_mm"])))
            for key, true in (("x_mm", c.x0), ("y_mm", c.y0), ("force_n", c.force), ("r1_mm", c.r1)):
                z.append((r.values[key] - true) / r.std[key])
    z = np.abs(np.array(z))
    assert np.mean(z < 2.0) >= 0.85 and z.max() < 5.0, z
    # the line's strongest contact comes first, with the others listed after it
    line = contacts_json(fits)
    assert line["force_n"] == max(c["force_n"] for c in line["contacts"]) == line["contacts"][0]["force_n"]
    assert len(line["contacts"]) == 2


def test_predicted_strain_is_the_physics_of_the_fitted_contact() -> None:
    sensor, model, fitter = _setup("fearing1988")
    truth = Contact(6.0, 6.0, 0.0, 0.8, 10.0, 12.0)
    res = fitter.fit(model.predict(truth), "sphere")
    pred = predicted_strain(fitter, res)
    fitted = Contact(res.values["r1_mm"], res.values["r1_mm"], 0.0, res.values["force_n"],
                     res.values["x_mm"], res.values["y_mm"])
    np.testing.assert_allclose(pred, model.predict(fitted), rtol=1e-6, atol=1e-9)


def test_a_line_too_wide_to_integrate_predicts_nothing_rather_than_failing_the_fit() -> None:
    # A light line whose radius the frame leaves open can take a radius at which the Hertz
    # half-width is hundreds of mm: its strain cannot be integrated, and the fit of its
    # neighbours must go on without it (a ValueError here failed a palm's whole fit).
    sensor, model, fitter = _setup("flat16")
    cx, cy = _centre(sensor)
    truth = LineContact(10.0, 30.0, 0.05, cx, cy)
    res = fitter.fit(model.predict(truth), "cylinder")
    assert res.line is not None and predicted_strain(fitter, res) is not None
    wide = replace(res, params=(math.log(1e9), *res.params[1:]))
    with pytest.raises(ValueError, match="too long"):  # the physics itself refuses it
        model.predict(LineContact(1e9, 30.0, res.line["load_n_per_mm"], cx, cy))
    assert predicted_strain(fitter, wide) is None


def _fd_fisher(model: StrainModel, contacts: list[Contact], tactels: np.ndarray, sigma: float) -> np.ndarray:
    """Fisher information of (ln r, ln f, x0, y0) per sphere by central differences of the
    physics (independent of the compiled Jacobians joint_bounds uses)."""
    cols = []
    for c in contacts:
        p = np.array([math.log(c.r1), math.log(c.force), c.x0, c.y0])

        def strain(q):
            return model.predict(Contact(math.exp(q[0]), math.exp(q[0]), 0.0, math.exp(q[1]), q[2], q[3]))

        for k, h in enumerate((1e-5, 1e-5, 1e-5, 1e-5)):
            up, dn = p.copy(), p.copy()
            up[k] += h
            dn[k] -= h
            cols.append(((strain(up) - strain(dn)) / (2 * h))[tactels])
    j = np.array(cols).T / sigma
    return j.T @ j


def test_joint_bounds_match_an_independent_fisher_computation() -> None:
    sensor, model, fitter = _setup("flat16")
    contacts = [Contact(5.0, 5.0, 0.0, 1.0, 15.0, 17.0), Contact(7.0, 7.0, 0.0, 0.8, 21.0, 19.0)]
    tactels = np.zeros((16, 16), bool)
    tactels[4:11, 5:10] = True
    params = [("sphere", tuple(get_model("sphere").from_values(c.r1, c.r2, 0.0, c.force, c.x0, c.y0)))
              for c in contacts]
    joint, alone = joint_bounds(fitter, params, tactels)
    cov = np.linalg.inv(_fd_fisher(model, contacts, tactels, fitter.sigma))
    for i, c in enumerate(contacts):
        block = cov[4 * i:4 * i + 4, 4 * i:4 * i + 4]
        assert joint[i]["x_mm"] == pytest.approx(math.sqrt(block[2, 2]), rel=1e-4)
        assert joint[i]["force_n"] == pytest.approx(c.force * math.sqrt(block[1, 1]), rel=1e-4)
        assert joint[i]["r1_mm"] == pytest.approx(c.r1 * math.sqrt(block[0, 0]), rel=1e-4)
        # neighbours whose strains overlap share information: the joint bound is wider
        for key in ("x_mm", "y_mm", "force_n", "r1_mm"):
            assert joint[i][key] >= alone[i][key] * (1 - 1e-9)
        assert joint[i]["x_mm"] > 1.01 * alone[i]["x_mm"]


def test_a_frame_of_several_starts_each_contact_from_the_last_frames() -> None:
    from tactiled.fit.multi import warm_of
    from tactiled.fit.warm import SEVERAL, nearest_start

    sensor, model, fitter = _setup("flat16")
    truths = [Contact(5.0, 5.0, 0.0, 1.0, 10.0, 11.0), Contact(9.0, 9.0, 0.0, 0.6, 28.0, 27.0)]
    rng = np.random.default_rng(8)
    clean = sum(model.predict(c) for c in truths)
    first = fit_contacts(fitter, clean + rng.normal(0.0, SIGMA, clean.shape), "sphere")
    warm = warm_of(first)
    assert warm[0] == SEVERAL and len(warm[1]) == 2
    # each region takes the start nearest its peak, none further than the gate
    assert nearest_start(warm[1], 10.2, 11.1, 2.0)[1] == first[0].params
    assert nearest_start(warm[1], 19.0, 19.0, 2.0) is None
    # a line contact (a flat array's 4-parameter cylinder) has no centre to be near
    assert nearest_start((("cylinder", (1.0, 0.5, -2.0, 0.3)),), 0.3, -2.0, 5.0) is None
    frame = clean + rng.normal(0.0, SIGMA, clean.shape)
    cold = fit_contacts(fitter, frame, "sphere")
    warmed = fit_contacts(fitter, frame, "sphere", warm=warm)
    for a, b in zip(cold, warmed):
        for key in ("x_mm", "y_mm", "force_n", "r1_mm"):
            assert a.values[key] == pytest.approx(b.values[key], abs=0.1 * a.std[key])
    # one contact left: it starts from its own last fit
    (one,) = fit_contacts(fitter, model.predict(truths[0]) + rng.normal(0.0, SIGMA, clean.shape),
                          "sphere", warm=warm)
    assert one.contact and abs(one.values["x_mm"] - 10.0) < 0.2


def test_contacts_held_since_the_last_frame_are_fitted_as_several_at_once(monkeypatch) -> None:
    # Every region a different contact of the last frame's: one fit per contact, from where
    # each was, and not first the frame as one contact (whose model search runs cold on a
    # window its neighbours spoil) -- with the same answer, within a tenth of a sigma.  A
    # region no contact held (a new contact) takes the full path and is found.
    from tactiled.fit import multi
    from tactiled.fit.multi import warm_of

    sensor, model, fitter = _setup("flat16")
    truths = [Contact(5.0, 5.0, 0.0, 1.0, 10.0, 11.0), Contact(9.0, 9.0, 0.0, 0.6, 28.0, 27.0)]
    rng = np.random.default_rng(11)
    clean = sum(model.predict(c) for c in truths)
    warm = warm_of(fit_contacts(fitter, clean + rng.normal(0.0, SIGMA, clean.shape), "auto"))
    moved = [Contact(5.0, 5.0, 0.0, 1.05, 10.1, 11.0), Contact(9.0, 9.0, 0.0, 0.6, 28.0, 27.1)]
    frame = sum(model.predict(c) for c in moved) + rng.normal(0.0, SIGMA, clean.shape)

    calls = []
    fit = fitter.fit
    monkeypatch.setattr(fitter, "fit", lambda strain, *a, **k: calls.append(strain) or fit(strain, *a, **k))
    held = fit_contacts(fitter, frame, "auto", warm=warm)
    assert len(calls) == 2  # one per contact, each on the frame less the other
    assert all(c is not frame for c in calls)
    monkeypatch.setattr(multi, "_all_held", lambda warm, starts: False)
    calls.clear()
    full = fit_contacts(fitter, frame, "auto", warm=warm)
    # the frame as one contact, the second found on the frame less the first, then the first
    # refined on the frame less the second
    assert len(calls) == 3 and calls[0] is frame
    assert len(held) == len(full) == 2
    for a, b, truth in zip(held, full, moved):
        for key, value in (("x_mm", truth.x0), ("y_mm", truth.y0), ("force_n", truth.force),
                           ("r1_mm", truth.r1)):
            assert a.values[key] == pytest.approx(b.values[key], abs=0.1 * b.std[key])
            assert abs(a.values[key] - value) < 4.0 * a.std[key]
    monkeypatch.undo()

    # two regions that the same contact of the last frame is nearest to are not two held
    # contacts (whatever split its strain): the full path
    from tactiled.fit.multi import _all_held

    one = warm[1][0]
    assert _all_held(warm, [one, warm[1][1]])
    assert not _all_held(warm, [one, (one[0], tuple(one[1]))])
    assert not _all_held(warm, [one, None]) and not _all_held(one, [one])

    # a third contact comes: its region has no start, so the frame takes the full path
    third = Contact(4.0, 4.0, 0.0, 0.8, 10.0, 30.0)
    frame3 = frame + model.predict(third)
    out = fit_contacts(fitter, frame3, "auto", warm=warm)
    assert len(out) == 3
    assert min(math.hypot(r.values["x_mm"] - 10.0, r.values["y_mm"] - 30.0) for r in out) < 0.5


def test_a_line_contacts_ridge_is_one_contact_however_the_grid_samples_it() -> None:
    from tactiled.sensors.model import NoiseModel
    from tactiled.physics.contact import LineContact
    from tactiled.sim import add_noise

    sensor, model, fitter = _setup("flat16")
    rng = np.random.default_rng(9)
    split_regions = 0
    for psi in (0.0, 17.0, 30.0, 45.0, 72.0, 90.0, 120.0, 150.0):
        clean = model.predict(LineContact(8.0, psi, 0.035, 18.0, 18.0))
        # quantised to 2 sigma, as the simulator's frames are: the ridge breaks into bumps
        frame = add_noise(clean, NoiseModel(sigma=SIGMA, quantum=0.001), rng)
        split_regions += len(find_regions(frame, SIGMA)) > 1
        (res,) = fit_contacts(fitter, frame, "cylinder")
        assert res.label == "line" and "contacts" not in res.reasons, psi
    assert split_regions >= 2  # the case this guards: several regions, one contact

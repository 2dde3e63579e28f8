"""Lines among several contacts, and a line's window along its length (tactiled.fit.selection,
tactiled.fit.linewindow).  Frames are the physics' own (sums of predict_strain) plus seeded
noise; bounds are the Cramer-Rao bounds at the truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.multi import fit_contacts, predicted_strain
from tactiled.fit.regions import find_regions
from tactiled.fit.selection import penalty
from tactiled.physics.contact import Contact, LineContact
from tactiled.physics.strain import StrainModel
from tactiled.sensors import load_description
from tactiled.sensors.description import builtin_text, parse_description_text


def _setup(desc):
    sensor = desc.sensor_model()
    fitter = Fitter(sensor, FitOptions(window=desc.window))
    fitter.frozen = True
    return sensor, StrainModel(sensor), fitter


@pytest.fixture(scope="module")
def flat16():
    return _setup(load_description("flat16"))


def _angle_err(a: float, b: float) -> float:
    return (a - b + 90.0) % 180.0 - 90.0


def test_a_line_is_fitted_along_its_length_to_its_bound(flat16) -> None:
    """The line's window follows the ridge across the pad: its angle's error reaches the
    bound of its own band, far below what a 6x6 window could do, and its sigma covers it."""
    sensor, model, fitter = flat16
    sigma = sensor.noise.sigma
    rng = np.random.default_rng(5)
    z6, z_own, covered = [], [], []
    for psi in (20.0, 65.0, 110.0, 155.0):
        line = LineContact(8.0, psi, 0.05, 19.0, 18.0)
        clean = model.predict(line)
        six = fitter.line_cramer_rao(clean, line, window=6)["angle_deg"]
        own = fitter.line_cramer_rao(clean, line)["angle_deg"]
        assert own < 0.5 * six  # the line's length holds its angle
        for _ in range(15):
            res = fitter.fit(clean + rng.normal(0.0, sigma, clean.shape), "cylinder")
            assert res.label == "line" and res.n_points > 36
            err = _angle_err(res.values["angle_deg"], psi)
            z6.append(err / six)
            z_own.append(err / own)
            covered.append(abs(err) <= 2.0 * res.std["angle_deg"])
    assert math.sqrt(np.mean(np.square(z6))) <= 0.7
    assert 0.6 <= math.sqrt(np.mean(np.square(z_own))) <= 1.3
    assert np.mean(covered) >= 0.85


def test_a_small_pad_fits_a_line_on_all_of_it() -> None:
    text = builtin_text("robotiq_tsf85").replace('name = "robotiq_tsf85"', 'name = "pad6x4"')
    sensor, model, fitter = _setup(parse_description_text(text.replace("rows = 7", "rows = 6"), "pad6x4"))
    line = LineContact(6.0, 70.0, 0.08, 10.0, 6.0)
    clean = model.predict(line)
    res = fitter.fit(clean + np.random.default_rng(1).normal(0.0, sensor.noise.sigma, clean.shape), "cylinder")
    assert res.window == (0, 0, 6, 4) and res.n_points == 24


def test_a_line_whose_ridge_the_grid_splits_is_one_contact(flat16) -> None:
    sensor, model, fitter = flat16
    sigma = sensor.noise.sigma
    rng = np.random.default_rng(7)
    split = 0
    for k in range(12):
        psi = 15.0 + 13.0 * k
        line = LineContact(4.0, psi, 0.03, 18.0 + 0.4 * k, 19.0)
        frame = model.predict(line) + rng.normal(0.0, sigma, (16, 16))
        split += len(find_regions(frame, sigma)) > 1
        out = fit_contacts(fitter, frame, "auto")
        assert len(out) == 1 and out[0].label == "line", psi
    assert split >= 3  # the case is exercised: the grid samples these ridges as several bumps


@pytest.mark.parametrize("second", ["line", "ball", "edge"])
def test_a_line_and_another_contact_are_two_contacts(flat16, second: str) -> None:
    """A bar beside a parallel bar, a ball or an edge, 14 mm apart: two contacts, each where
    it is and with its own model."""
    sensor, model, fitter = flat16
    sigma = sensor.noise.sigma
    rng = np.random.default_rng(11)
    for trial in range(6):
        psi = 30.0 * trial + 10.0
        n = (-math.sin(math.radians(psi)), math.cos(math.radians(psi)))
        a = LineContact(10.0, psi, 0.06, 18.75 + 7.0 * n[0], 18.75 + 7.0 * n[1])
        at = (18.75 - 7.0 * n[0], 18.75 - 7.0 * n[1])
        b = (LineContact(6.0, psi + 2.0, 0.04, *at) if second == "line"
             else LineContact(0.5, psi - 4.0, 0.03, *at) if second == "edge"
             else Contact(6.0, 6.0, 0.0, 0.8, *at))
        frame = model.predict(a) + model.predict(b) + rng.normal(0.0, sigma, (16, 16))
        out = fit_contacts(fitter, frame, "auto")
        assert len(out) == 2, (second, trial, [r.label for r in out])
        assert all("one of 2 contacts" in r.reasons["contacts"] for r in out)
        for truth in (a, b):
            near = [r for r in out if math.dist((r.values["x_mm"], r.values["y_mm"]), (truth.x0, truth.y0))
                    < 2.5 or (isinstance(truth, LineContact) and abs(
                        -math.sin(truth.psi) * (r.values["x_mm"] - truth.x0)
                        + math.cos(truth.psi) * (r.values["y_mm"] - truth.y0)) < 1.0)]
            assert len(near) == 1, (second, trial, truth)
            r = near[0]
            if isinstance(truth, LineContact):
                assert r.label in ("line", "edge")
                assert abs(_angle_err(r.values["angle_deg"], truth.psi_deg)) < 4.0 * r.std["angle_deg"]
            else:
                assert r.model in ("sphere", "general")


def test_an_extra_contact_pays_for_its_parameters(flat16) -> None:
    """The information criterion: noise fitted by a contact does not pay ``k ln N``; a second
    ball whose peak stands 10 sigmas above the noise does."""
    sensor, model, fitter = flat16
    sigma = sensor.noise.sigma
    rng = np.random.default_rng(3)
    ball = Contact(5.0, 5.0, 0.0, 1.0, 12.0, 12.0)
    clean = model.predict(ball)
    weak = Contact(5.0, 5.0, 0.0, 1.0, 28.0, 27.0)
    weak_strain = model.predict(weak)
    weak_strain *= 12.0 * sigma / weak_strain.max()
    for _ in range(10):
        frame = clean + rng.normal(0.0, sigma, clean.shape)
        assert len(fit_contacts(fitter, frame, "auto")) == 1
        two = fit_contacts(fitter, frame + weak_strain, "auto")
        assert len(two) == 2
        # the gain of the weaker over the noise: its strain's chi^2, over the charge
        w = min(two, key=lambda r: r.values["force_n"] or 0.0)
        pred = predicted_strain(fitter, w)
        assert float(np.sum((pred / sigma) ** 2)) > penalty(w, 256)


def test_auto_compares_the_line_with_the_ellipses_on_the_same_tactels(flat16) -> None:
    """A bar near the pad's edge with another bar's tail in its band: its chi^2 over the band
    is beyond the noise's, and the point models are judged on that band too (where a finite
    ellipse's ends leave the ridge unexplained): auto keeps the line.  A point model's chi^2 on
    the band is the frame less its predicted strain there, computed independently."""
    from tactiled.fit.linewindow import band, chi2_on_band

    sensor, model, fitter = flat16
    sigma = sensor.noise.sigma
    a = LineContact(10.3, 3.2, 0.06, 24.0, 8.7)
    b = LineContact(12.4, 7.6, 0.05, 14.6, 23.3)
    rng = np.random.default_rng(0)
    compared = 0
    for _ in range(12):
        frame = model.predict(a) + model.predict(b) + rng.normal(0.0, sigma, (16, 16))
        res = fitter.fit(frame, "auto")
        assert res.label == "line" and abs(_angle_err(res.values["angle_deg"], a.psi_deg)) < 1.0
        if res.criterion is not None:  # the band's chi^2 left the noise's: the models compared
            compared += 1
            assert res.criterion["cylinder"] == pytest.approx(res.chi2 + 4 * math.log(res.n_points))
            assert res.criterion["cylinder"] < min(res.criterion["sphere"], res.criterion["general"])
        ball = fitter.fit(frame, "sphere")
        chi2, n = chi2_on_band(fitter, frame, None, "sphere", ball.params)
        peak = np.unravel_index(int(np.argmax(frame)), frame.shape)
        seen = band(frame, np.ones(frame.shape, bool), peak, float(frame.max()), sigma)
        assert n == int(seen.sum()) == res.n_points
        left = (frame - predicted_strain(fitter, ball))[seen] / sigma
        assert chi2 == pytest.approx(float(left @ left), rel=1e-6)
    assert compared >= 2


def test_a_ridge_across_the_pad_is_told_from_a_blob_and_a_finite_ellipse(flat16) -> None:
    from tactiled.fit.linewindow import runs_across

    sensor, model, fitter = flat16
    sigma = sensor.noise.sigma
    rng = np.random.default_rng(2)

    def across(c) -> bool:
        frame = model.predict(c) + rng.normal(0.0, sigma, (16, 16))
        return runs_across(fitter, fitter.flattened(frame), None)[0]

    for psi in (0.0, 30.0, 75.0, 120.0, 170.0):
        assert across(LineContact(8.0, psi, 0.05, 18.0, 20.0)), psi
    for r in (3.0, 10.0, 25.0):
        assert not across(Contact(r, r, 0.0, 1.0, 17.0, 19.0)), r
    # an ellipse 3:1, both its ends on the pad
    assert not across(Contact(4.0, 40.0, 30.0, 1.0, 18.0, 18.0))

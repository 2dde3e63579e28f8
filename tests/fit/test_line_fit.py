"""Fitting a cylinder on a flat array: the line model recovers radius, angle, load per length and
offset at the Cramer-Rao bound, and withholds the total force with its reason."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled.fit.fitter import Fitter
from tactiled.physics.contact import Contact, LineContact
from tactiled.physics.strain import StrainModel
from tactiled.sensors import load_description


@pytest.fixture(scope="module")
def flat16():
    sensor = load_description("flat16").sensor_model()
    return sensor, StrainModel(sensor), Fitter(sensor)


def test_a_noise_free_line_is_recovered(flat16) -> None:
    sensor, model, fitter = flat16
    truth = LineContact(8.0, 60.0, 0.08, 17.0, 20.0)
    res = fitter.fit(model.predict(truth), "cylinder")
    assert res.contact and res.converged and res.model == "cylinder" and res.label == "line"
    assert res.values["r1_mm"] == pytest.approx(8.0, rel=1e-4)
    assert res.values["angle_deg"] == pytest.approx(60.0, abs=1e-3)
    assert res.line["load_n_per_mm"] == pytest.approx(0.08, rel=1e-5)
    g = sensor.geometry
    assert res.line["offset_mm"] == pytest.approx(truth.offset_from(g.span_x / 2, g.span_y / 2), abs=1e-4)
    # the reported point is on the line, the one nearest the array's centre
    n = (-math.sin(math.radians(60.0)), math.cos(math.radians(60.0)))
    assert (res.values["x_mm"] - truth.x0) * n[0] + (res.values["y_mm"] - truth.y0) * n[1] == pytest.approx(0.0, abs=1e-4)
    assert res.values["force_n"] is None and "load per length" in res.reasons["force_n"]
    doc = res.to_json_dict()
    assert doc["line"]["load_n_per_mm"] == pytest.approx(0.08, rel=1e-5) and doc["force_n"] is None


def test_noisy_lines_are_fitted_at_the_bound_with_honest_sigmas(flat16) -> None:
    sensor, model, fitter = flat16
    rng = np.random.default_rng(11)
    z: dict[str, list[float]] = {k: [] for k in ("r1_mm", "angle_deg", "load_n_per_mm", "offset_mm")}
    covered = {k: 0 for k in z}
    n = 0
    for truth in (LineContact(8.0, 60.0, 0.08, 17.0, 20.0), LineContact(15.0, 170.0, 0.15, 20.0, 15.0)):
        clean = model.predict(truth)
        crb = fitter.line_cramer_rao(clean, truth)
        g = sensor.geometry
        true = {"r1_mm": truth.r1, "angle_deg": truth.psi_deg % 180, "load_n_per_mm": truth.load,
                "offset_mm": truth.offset_from(g.span_x / 2, g.span_y / 2)}
        for _ in range(40):
            res = fitter.fit(clean + rng.normal(0, sensor.noise.sigma, clean.shape), "cylinder")
            n += 1
            for k in z:
                est = res.line[k] if k in res.line else res.values[k]
                sd = res.line.get(f"{k}_std") if k in res.line else res.std[k]
                err = est - true[k]
                if k == "angle_deg":
                    err = (err + 90) % 180 - 90
                z[k].append(err / crb[k])
                covered[k] += abs(err) <= 2 * sd
    for k in z:
        rms = math.sqrt(np.mean(np.square(z[k])))
        assert rms < 1.3, (k, rms)
        assert covered[k] / n >= 0.88, (k, covered[k] / n)


def test_auto_on_a_flat_array_tells_a_line_from_a_sphere(flat16) -> None:
    sensor, model, fitter = flat16
    rng = np.random.default_rng(3)
    line = model.predict(LineContact(10.0, 120.0, 0.1, 18.0, 18.0))
    res = fitter.fit(line + rng.normal(0, 5e-4, line.shape), "auto")
    assert res.label == "line" and res.model == "cylinder"
    ball = model.predict(Contact(6.0, 6.0, 0.0, 1.0, 15.0, 14.0))
    res = fitter.fit(ball + rng.normal(0, 5e-4, ball.shape), "auto")
    assert res.model == "sphere" and res.values["r1_mm"] == pytest.approx(6.0, rel=0.1)
    assert res.values["force_n"] == pytest.approx(1.0, rel=0.05)


@pytest.mark.parametrize("name", ["xela_uskin_4x4", "robotiq_tsf85", "flexitac_12x32"])
def test_every_flat_builtin_fits_a_line(name: str) -> None:
    sensor = load_description(name).sensor_model()
    model = StrainModel(sensor)
    g = sensor.geometry
    truth = LineContact(8.0, 35.0, 0.2, 0.5 * g.span_x, 0.45 * g.span_y)
    res = Fitter(sensor).fit(model.predict(truth), "cylinder")
    assert res.converged and res.values["r1_mm"] == pytest.approx(8.0, rel=1e-3)
    assert res.line["load_n_per_mm"] == pytest.approx(0.2, rel=1e-4)

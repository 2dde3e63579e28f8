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


def test_the_compiled_line_search_is_the_python_one(flat16) -> None:
    """The line model's compiled search (kind LINE) against the Python solver on the same
    residual and start: the same steps, the same end."""
    from tactiled.fit import compiled
    from tactiled.fit.search import LINE_BOUNDS as _LINE_BOUNDS
    from tactiled.fit.line import STEPS
    from tactiled.fit.solver import levenberg_marquardt

    sensor, model, fitter = flat16
    rng = np.random.default_rng(11)
    frame = model.predict(LineContact(7.0, 50.0, 0.08, 17.0, 20.0)) + rng.normal(0, 5e-4, (16, 16))
    fr = fitter._line_frame(frame, None)
    prob = fitter._line_problem(fr)
    p0 = prob.starts(fr.clean, model.xs_full, model.ys_full, fr.peak)[0]
    atol = 1e-4 * (fitter.sigma / fr.peak) ** 2
    window = (fr.xs, fr.ys, fr.target, fr.valid, fr.inv_scale, fr.ex, fr.ey)
    iterations = []
    for noise_cost in (math.inf, 1e-9):  # the second: every cost beyond it
        c = compiled.solve(compiled.LINE, p0, STEPS, 60, atol, fitter._model_args, window,
                           fitter.options.tol, bounds=_LINE_BOUNDS, verdict_tol=100 * atol,
                           noise_cost=noise_cost)
        p = levenberg_marquardt(prob.residual_and_jacobian, p0, max_step=STEPS, max_iter=60,
                                atol=atol, verdict_tol=100 * atol, bounds=_LINE_BOUNDS,
                                noise_cost=noise_cost)
        assert (c.iterations, c.evaluations, c.converged, c.message) == \
            (p.iterations, p.evaluations, p.converged, p.message)
        assert np.allclose(c.p, p.p, rtol=1e-9, atol=1e-12)
        iterations.append(c.iterations)
    # tolerances that grow with the cost end the search no later
    assert iterations[1] <= iterations[0] and iterations[0] > 1


def test_auto_keeps_a_line_that_explains_the_window_without_scouting(flat16) -> None:
    sensor, model, fitter = flat16
    rng = np.random.default_rng(5)
    frame = model.predict(LineContact(9.0, 70.0, 0.1, 19.0, 18.0)) + rng.normal(0, 5e-4, (16, 16))
    alone = fitter.fit(frame, "cylinder")
    auto = fitter.fit(frame, "auto")
    assert auto.model == "cylinder" and auto.label == "line" and auto.converged
    assert "no other model tried" in auto.message
    # auto scouts the line, then solves it on from there: the same minimum, to a sliver of
    # each value's sigma (the solver stops within 0.01 of chi^2 of it)
    for key, v in alone.values.items():
        if v is not None and alone.std.get(key):
            assert abs(auto.values[key] - v) < 0.05 * alone.std[key], key
    # a ball is no line: the other models are fitted and the sphere chosen
    ball = model.predict(Contact(6.0, 6.0, 0.0, 1.0, 15.0, 14.0)) + rng.normal(0, 5e-4, (16, 16))
    res = fitter.fit(ball, "auto")
    assert res.model == "sphere" and "no other model tried" not in res.message
    # there the line's scout sat at a minimum far above the noise: it was not solved on
    assert fitter._line_scouted and res.criterion["cylinder"] > 2 * res.n_points
    fitter.fit(frame, "auto")
    assert not fitter._line_scouted  # a line is solved fully


def test_a_scouted_line_auto_answers_is_reported_in_full(flat16) -> None:
    """A ball's line scout is ranked by its chi^2 alone; where auto's budget runs out before
    the other models and the scout is the answer, it is reported as any line fit is: its
    condition, its sigmas (here the place's found unknowable and withheld with the reason),
    the force withheld with the line's reason, its label."""
    sensor, model, fitter = flat16
    rng = np.random.default_rng(1)
    ball = model.predict(Contact(6.0, 6.0, 0.0, 1.0, 20.0, 18.0))
    ball = ball + rng.normal(0.0, sensor.noise.sigma, ball.shape)
    res = fitter.fit(ball, "auto", budget_s=1e-9)  # out of time once the line is scouted
    assert fitter._line_scouted and res.model == "cylinder" and res.label == "line"
    assert res.condition is not None and res.condition > 1.0
    assert "load per length" in res.reasons["force_n"] and "r2_mm" in res.reasons
    for key in ("x_mm", "y_mm", "r1_mm", "angle_deg"):  # a sigma, or a reason for none
        assert res.std.get(key) is not None or key in res.reasons, key
    assert any(res.std.get(k) is not None for k in ("r1_mm", "angle_deg"))


def test_a_warm_ellipse_running_off_a_flat_array_is_not_kept(flat16) -> None:
    """auto's warm path: the previous frame's general ellipse, where it runs off the array at
    both ends, is the line; the choice is made afresh (as a cold fit's is)."""
    sensor, model, fitter = flat16
    rng = np.random.default_rng(8)
    frame = model.predict(LineContact(9.0, 20.0, 0.1, 19.0, 18.0)) + rng.normal(0, 5e-4, (16, 16))
    gen = fitter.fit(frame, "general")
    assert fitter._runs_off(gen)  # the premise: the ellipse fitted to a line runs off
    res = fitter.fit(frame, "auto", warm=("general", gen.params))
    assert res.model == "cylinder" and res.label == "line"
    assert "kept from the previous frame" not in res.message


def test_a_line_is_judged_against_its_own_four_parameters() -> None:
    """A line contact's chi^2 test counts its own parameters (four: ln R, psi, ln load,
    offset), not the cylinder's five it is reported under."""
    from tactiled.fit.result import FitResult

    fitter = Fitter(load_description("flat16").sensor_model())
    n = 16
    # between the 11- and the 12-degree-of-freedom thresholds (3 sigma above the mean)
    chi2 = 0.5 * ((11 + 3 * math.sqrt(22)) + (12 + 3 * math.sqrt(24)))
    line = FitResult(contact=True, model="cylinder", params=(1.0, 0.3, -2.0, 0.1), chi2=chi2, n_points=n)
    point = FitResult(contact=True, model="cylinder", params=(1.0, 0.3, 0.0, 5.0, 5.0), chi2=chi2, n_points=n)
    assert fitter._consistent(line)
    assert not fitter._consistent(point)

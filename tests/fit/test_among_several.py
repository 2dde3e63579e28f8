"""A contact fitted as one of several (tactiled.fit.auto.ModelSelector.among_several): a round
blob's sphere alone on a flat array, a curved array's cylinder scouted.  Frames are the
physics' own (sums of StrainModel.predict) plus seeded noise; the models chosen and the values
are compared with the truth, and with what auto gives the same frame alone."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled.fit.auto import PLAIN_MESSAGE, ROUND_MESSAGE, round_blob
from tactiled.fit.budget import budget_spent
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.linewindow import runs_across
from tactiled.fit.multi import fit_contacts
from tactiled.physics.contact import Contact, LineContact
from tactiled.physics.strain import StrainModel
from tactiled.sensors import load_description
from tactiled_bench import grasps


def _setup(name: str, **options):
    desc = load_description(name)
    sensor = desc.sensor_model()
    fitter = Fitter(sensor, FitOptions(window=desc.window, **options))
    fitter.frozen = True
    return sensor, StrainModel(sensor), fitter


@pytest.fixture(scope="module")
def flat16():
    return _setup("flat16")


@pytest.fixture(scope="module")
def finger():
    return _setup("fearing1988")


def _band(fitter: Fitter, frame: np.ndarray) -> np.ndarray:
    across, band = runs_across(fitter, fitter.flattened(frame), None)
    assert band is not None
    return band


def _spy(selector, name: str) -> list:
    """The selector's method ``name`` replaced on the instance by the real one that records
    its answers (the list returned; ``del selector.<name>`` restores the class's)."""
    real = getattr(selector, name)
    answers: list = []

    def spy(*args, **kwargs):
        res = real(*args, **kwargs)
        answers.append(res)
        return res

    setattr(selector, name, spy)
    return answers


def test_a_balls_band_is_round_and_a_lines_is_not(flat16) -> None:
    sensor, model, fitter = flat16
    rng = np.random.default_rng(1)
    noise = lambda: rng.normal(0.0, sensor.noise.sigma, (16, 16))  # noqa: E731
    for r, at in ((3.0, (12.0, 20.0)), (10.0, (20.0, 15.0)), (25.0, (18.0, 18.0))):
        assert round_blob(_band(fitter, model.predict(Contact(r, r, 0.0, 1.0, *at)) + noise())), r
    for psi in (0.0, 35.0, 80.0, 125.0, 170.0):
        line = LineContact(8.0, psi, 0.05, 18.0, 20.0)
        assert not round_blob(_band(fitter, model.predict(line) + noise())), psi
    assert not round_blob(np.eye(16, dtype=bool))  # a diagonal ridge, however thin
    assert not round_blob(np.zeros((16, 16), bool))


def test_balls_beside_a_line_are_spheres_fitted_alone_and_within_their_sigmas(flat16) -> None:
    """A bar and two balls 14 mm either side of it, each ball's peak 60-80 noise sigmas:
    every ball is a sphere that the sphere alone explained (auto's line and ellipse not
    scouted for it), its values within four of its sigmas."""
    sensor, model, fitter = flat16
    sigma = sensor.noise.sigma
    rng = np.random.default_rng(8)
    answers = _spy(fitter.selector, "sphere_alone")
    try:
        for trial in range(6):
            psi = 15.0 + 25.0 * trial
            line = LineContact(10.0, psi, 0.03, 18.75, 18.75)
            n = (-math.sin(math.radians(psi)), math.cos(math.radians(psi)))
            balls = [Contact(5.0, 5.0, 0.0, 0.15, 18.75 + s * 14.0 * n[0] + 4.0 * n[1],
                             18.75 + s * 14.0 * n[1] - 4.0 * n[0]) for s in (-1.0, 1.0)]
            frame = model.predict(line) + sum(model.predict(b) for b in balls) \
                + rng.normal(0.0, sigma, (16, 16))
            out = fit_contacts(fitter, frame, "auto")
            assert len(out) == 3, trial
            for b in balls:
                r = min(out, key=lambda r: math.dist((r.values["x_mm"], r.values["y_mm"]), (b.x0, b.y0)))
                assert r.model == "sphere" and r.line is None, trial
                for key, true in (("x_mm", b.x0), ("y_mm", b.y0), ("force_n", b.force)):
                    assert abs(r.values[key] - true) < 4.0 * r.std[key], (trial, key)
    finally:
        del fitter.selector.sphere_alone
    assert len(answers) == 12  # each ball's blob is round: the sphere tried alone ...
    assert all(a is not None and a.message.startswith(ROUND_MESSAGE) for a in answers)  # ... and kept


def test_an_ellipse_beside_a_line_is_one_general_contact_not_a_sphere_and_a_phantom(flat16) -> None:
    """An ellipsoid's blob (r2 1.5-3 times r1) the sphere does not explain: auto chooses on
    the whole frame as alone, and the frame is two contacts, the ellipse a general one."""
    sensor, model, fitter = flat16
    rng = np.random.default_rng(4)
    line = LineContact(10.0, 20.0, 0.06, 20.0, 8.0)
    for ratio in (1.5, 2.0, 3.0):
        ellipse = Contact(6.0, 6.0 * ratio, 70.0, 1.0, 18.0, 28.0)
        for _ in range(3):
            frame = model.predict(line) + model.predict(ellipse) \
                + rng.normal(0.0, sensor.noise.sigma, (16, 16))
            out = fit_contacts(fitter, frame, "auto")
            assert len(out) == 2, ratio
            (r,) = [r for r in out if r.line is None]
            assert r.model == "general", ratio
            assert math.dist((r.values["x_mm"], r.values["y_mm"]), (ellipse.x0, ellipse.y0)) < 1.0


def test_a_cylinder_scouted_among_several_is_solved_to_the_same_minimum(finger) -> None:
    """On the paper's finger, auto with the cylinder scouted and solved only if chosen lands
    where auto's full cylinder fit does: same model, values within 0.1 of their sigma."""
    sensor, model, fitter = finger
    rng = np.random.default_rng(2)
    for psi in (40.0, 75.0, 110.0, 140.0):
        c = Contact(8.0, math.inf, psi, 1.2, 12.0, 14.0)
        frame = model.predict(c) + rng.normal(0.0, sensor.noise.sigma, (8, 8))
        plain = fitter.fit(frame, "auto")
        with fitter.selector.among_several():
            scouted = fitter.fit(frame, "auto")
        assert plain.model == scouted.model == "cylinder", psi
        assert scouted.converged and scouted.std.get("angle_deg") is not None
        for key, v in plain.values.items():
            if v is not None and plain.std.get(key):
                assert abs(scouted.values[key] - v) < 0.1 * plain.std[key], (psi, key)


def test_a_scouted_cylinder_whose_budget_ran_out_is_reported_not_left_a_scout() -> None:
    """The budget spent while the cylinder was a scout: the answer is the cylinder reported
    at the point reached (values or reasons for each, the budget's reason), as auto's answer
    cut short always is."""
    sensor, model, fitter = _setup("fearing1988", budget_iterations=4)
    frame = model.predict(Contact(8.0, math.inf, 60.0, 1.2, 12.0, 14.0)) \
        + np.random.default_rng(3).normal(0.0, sensor.noise.sigma, (8, 8))
    with fitter.selector.among_several():
        res = fitter.fit(frame, "auto")
    assert res.contact and res.model == "cylinder" and not res.converged
    assert budget_spent(res.reasons)
    assert res.values  # a report, not a scout's bare chi^2
    for key in ("x_mm", "y_mm", "force_n"):
        assert res.values.get(key) is not None or key in res.reasons


def test_a_ridge_tests_second_moments_are_the_covariances_eigen_decomposition() -> None:
    """linewindow.spread's closed form against numpy's sample covariance and eigh, on seeded
    point sets (scattered, nearly collinear, a few tactels)."""
    from tactiled.fit.linewindow import spread

    rng = np.random.default_rng(5)
    for trial in range(300):
        k = int(rng.integers(3, 30))
        x = rng.integers(0, 16, k).astype(float)
        y = x * float(rng.integers(-2, 3)) + rng.integers(0, 2, k) if trial % 3 == 0 \
            else rng.integers(0, 16, k).astype(float)
        w, v = np.linalg.eigh(np.cov(np.vstack((x, y))))
        small, big, (ux, uy) = spread(x, y)
        assert small == pytest.approx(w[0], abs=1e-9) and big == pytest.approx(w[1], abs=1e-9)
        if w[1] - w[0] > 1e-9:  # a unique principal axis: the same one, up to its sign
            assert abs(ux * v[0, 1] + uy * v[1, 1]) == pytest.approx(1.0, abs=1e-9)


def test_a_round_blob_the_sphere_alone_misses_is_chosen_without_a_line_scout(flat16) -> None:
    """An ellipsoid's blob (r2 1.5 times r1) beside a bar: its band is round, the sphere alone
    leaves it above the noise, and the choice between the sphere and the general ellipse is
    made without scouting a line for it (ModelSelector.round_choice): the general ellipse,
    where auto on the blob alone also puts it, its centre within four of its sigmas."""
    sensor, model, fitter = flat16
    rng = np.random.default_rng(6)
    answers = _spy(fitter.selector, "round_choice")
    try:
        line = LineContact(10.0, 20.0, 0.06, 20.0, 8.0)
        ellipse = Contact(6.0, 9.0, 70.0, 1.0, 18.0, 28.0)
        for _ in range(3):
            noise = rng.normal(0.0, sensor.noise.sigma, (16, 16))
            alone = fitter.fit(model.predict(ellipse) + noise, "auto")
            out = fit_contacts(fitter, model.predict(line) + model.predict(ellipse) + noise, "auto")
            assert len(out) == 2
            (r,) = [r for r in out if r.line is None]
            assert r.model == alone.model == "general"
            for key, true in (("x_mm", ellipse.x0), ("y_mm", ellipse.y0)):
                assert abs(r.values[key] - true) < 4.0 * r.std[key], key
    finally:
        del fitter.selector.round_choice
    assert answers and all(a is not None and a.model == "general" for a in answers)


def test_profile_tests_run_only_on_published_fits_and_answers_are_unchanged(finger) -> None:
    """Frozen, a frame of several contacts runs the point fits' profile tests, and makes
    their values and sigmas (PointFit.result), only on the results it publishes
    (Fitter.deferring): fewer of each than with every fit made whole at once (9 tests against
    16 here), and the published contacts identical, every key (fit_ms aside)."""
    sensor, model, fitter = finger
    desc = load_description("fearing1988")
    eager = Fitter(sensor, FitOptions(window=desc.window))
    eager.frozen, eager.defer_tests = True, False
    rng = np.random.default_rng(11)
    runs = {id(f): [_spy(point, "tests") for point in f.points.values()] for f in (fitter, eager)}
    made = {id(f): [_spy(point, "result") for point in f.points.values()] for f in (fitter, eager)}
    several = 0
    try:
        for psi in (30.0, 80.0, 130.0):
            clean = (model.predict(Contact(8.0, math.inf, psi, 1.0, 6.0, 6.0))
                     + model.predict(Contact(4.0, 4.0, 0.0, 0.8, 18.0, 18.0))
                     + model.predict(Contact(5.0, 5.0, 0.0, 0.8, 6.0, 20.0)))
            frame = clean + rng.normal(0.0, sensor.noise.sigma, clean.shape)
            got, want = fit_contacts(fitter, frame, "auto"), fit_contacts(eager, frame, "auto")
            several += len(got) > 1
            assert [_published(r) for r in got] == [_published(r) for r in want], psi
    finally:
        for f in (fitter, eager):
            for point in f.points.values():
                del point.tests, point.result
    assert several >= 2, several
    tested, tested_eager = (sum(len(v) for v in runs[id(f)]) for f in (fitter, eager))
    assert 0 < tested < tested_eager, (tested, tested_eager)
    whole, whole_eager = (sum(len(v) for v in made[id(f)]) for f in (fitter, eager))
    assert 0 < whole < whole_eager, (whole, whole_eager)


def _published(r) -> dict:
    return {k: v for k, v in r.to_json_dict().items() if k != "fit_ms"}


def test_crossing_cylinders_on_the_finger_are_cylinders_the_general_ellipse_not_tried(finger) -> None:
    """The contacts bench's crossing cylinders on the paper's finger (tactiled_bench.grasps,
    seeded): every contact is reported as a cylinder, within four of its sigmas of its truth,
    the general ellipse not tried where the cylinder explains the window to the noise (as a
    candidate, ModelSelector.plain) and a general ellipse chosen on the whole frame replaced
    by the cylinder on the frame less its neighbour (ModelSelector.simpler).  Choosing by the
    criterion alone, the general ellipse took about a quarter of these cylinders."""
    sensor, model, fitter = finger
    drawn = [(truths, frame) for grasp, _, truths, frame in
             grasps.frames_of(model, 8, np.random.default_rng(3))
             if grasp == "crossing" and truths is not None]
    replaced = _spy(fitter.selector, "simpler")
    plain = 0
    try:
        for truths, frame in drawn:
            out = fit_contacts(fitter, frame, "auto")
            assert len(out) == 2 and all(r.model == "cylinder" for r in out), [r.model for r in out]
            plain += sum(r.message.startswith(PLAIN_MESSAGE) for r in out)
            for c in truths:
                r = min(out, key=lambda r: math.dist((r.values["x_mm"], r.values["y_mm"]), (c.x0, c.y0)))
                for key, true in (("x_mm", c.x0), ("y_mm", c.y0), ("force_n", c.force)):
                    assert abs(r.values[key] - true) < 4.0 * r.std[key], key
                gap = abs((r.values["angle_deg"] - c.psi_deg + 90.0) % 180.0 - 90.0)
                assert gap < 4.0 * r.std["angle_deg"]
    finally:
        del fitter.selector.simpler
    assert len(drawn) == 8
    assert plain >= len(drawn)  # most contacts' cylinders explain their windows ...
    assert any(r.contact for r in replaced)  # ... and a whole frame's general became one


@pytest.mark.parametrize("r1,r2,force", [(3.0, 9.0, 1.0), (4.0, 12.0, 1.5)])
def test_an_ellipsoid_beside_a_ball_on_the_finger_is_still_a_general_ellipse(finger, r1, r2, force) -> None:
    """An ellipsoid (radii 3 times apart, 100-150 noise sigmas) beside a ball on the paper's
    finger: two contacts, the ellipsoid a general ellipse at every orientation (neither the
    cylinder nor the sphere explains it), as it is alone."""
    sensor, model, fitter = finger
    rng = np.random.default_rng(3)
    for psi in (20.0, 60.0, 100.0, 140.0):
        ellipsoid = Contact(r1, r2, psi, force, 7.0, 8.0)
        clean = model.predict(ellipsoid) + model.predict(Contact(5.0, 5.0, 0.0, 1.0, 19.0, 22.0))
        out = fit_contacts(fitter, clean + rng.normal(0.0, sensor.noise.sigma, clean.shape), "auto")
        assert len(out) == 2, psi
        r = min(out, key=lambda r: math.dist((r.values["x_mm"], r.values["y_mm"]), (7.0, 8.0)))
        assert r.model == "general", psi

"""A light ball's radius on a coarse pad of its own cover (benchmarks/descriptions/pad6x4.toml:
6x4 tactels at 4 mm under a 2 mm cover) is tested on its profile likelihood on both sides
(tactiled.fit.profile.radius_points): its fits land at radii several times too small or too
large, where the linearised sigmas of the place and the radius are a fraction of the bound at
the truth.  Scored against the simulator's truth over noise draws, with the profile and
without it (the same frames), and the fitter's profile points checked against scipy's least
squares on the simulator's own strain model."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares

import tactiled.fit.point as point
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
from tactiled.sensors import load_description

PAD = Path(__file__).resolve().parents[2] / "benchmarks" / "descriptions" / "pad6x4.toml"
#: A 5.2 mm ball at 0.84 N (a peak of 56 noise sigmas): about a quarter of its fits land at
#: under half its radius.
BALL = Contact(5.2, 5.2, 0.0, 0.84, 11.0, 4.9)
DRAWS = 200
KEYS = ("x_mm", "y_mm", "r1_mm")


@pytest.fixture(scope="module")
def pad():
    desc = load_description(PAD)
    sensor = desc.sensor_model()
    model = StrainModel(sensor)
    clean = model.predict(BALL)
    rng = np.random.default_rng(3)
    frames = [clean + rng.normal(0.0, sensor.noise.sigma, clean.shape) for _ in range(DRAWS)]
    return model, Fitter(sensor, FitOptions(window=desc.window)), frames


def _truth(key: str) -> float:
    return {"x_mm": BALL.x0, "y_mm": BALL.y0, "r1_mm": BALL.r1}[key]


def _scores(fitter: Fitter, frames) -> tuple[dict[str, list[float]], int]:
    """``|error| / sigma`` of each published x, y and radius, and the fits landing under half
    the true radius."""
    z: dict[str, list[float]] = {k: [] for k in KEYS}
    small = 0
    for frame in frames:
        res = fitter.fit(frame, "sphere")
        r = res.values.get("r1_mm")
        small += r is not None and r < 0.5 * BALL.r1
        for k in KEYS:
            v, sd = res.values.get(k), res.std.get(k)
            if v is not None and sd:
                z[k].append(abs(v - _truth(k)) / sd)
    return z, small


def test_a_light_balls_place_and_radius_cover_the_truth(pad) -> None:
    _, fitter, frames = pad
    z, small = _scores(fitter, frames)
    assert small >= 0.2 * DRAWS  # the case: fits at small radii
    assert len(z["x_mm"]) == len(z["y_mm"]) == DRAWS  # the place is always published
    assert len(z["r1_mm"]) >= 0.6 * DRAWS
    for k in KEYS:
        assert np.mean(np.array(z[k]) <= 2.0) >= 0.9, k
        assert np.mean(np.array(z[k]) > 4.0) <= 0.02, k


def test_without_the_radius_profile_the_same_frames_are_covered_less(pad, monkeypatch) -> None:
    _, fitter, frames = pad
    monkeypatch.setattr(point, "radius_points", lambda *a, **k: [])
    plain, _ = _scores(fitter, frames)
    monkeypatch.undo()
    tested, _ = _scores(fitter, frames)
    for k in KEYS:
        # the linearised sigmas alone (and the one point below a radius) miss the 90 % bar
        assert np.mean(np.array(plain[k]) <= 2.0) < 0.9, k
        assert np.mean(np.array(plain[k]) <= 2.0) < np.mean(np.array(tested[k]) <= 2.0) - 0.03, k
        assert np.mean(np.array(plain[k]) > 4.0) > np.mean(np.array(tested[k]) > 4.0), k


def _independent(model: StrainModel, sigma: float, frame: np.ndarray, values: dict,
                 radius: float) -> tuple[float, np.ndarray]:
    """chi^2 of ``frame`` minimised over the force and the place with the ball's radius held
    at ``radius`` (mm), and ``(force, x, y)`` there: the simulator's strain model and scipy's
    least squares, none of the fitter's code."""
    def residual(q: np.ndarray) -> np.ndarray:
        c = Contact(radius, radius, 0.0, math.exp(q[0]), q[1], q[2])
        return ((model.predict(c) - frame) / sigma).ravel()

    best = None
    for scale in (1.0, radius / values["r1_mm"]):  # the force as found, and scaled with r
        q0 = [math.log(values["force_n"] * scale), values["x_mm"], values["y_mm"]]
        sol = least_squares(residual, q0, x_scale=[0.1, 0.3, 0.3])
        if best is None or sol.cost < best.cost:
            best = sol
    return 2.0 * float(best.cost), np.array([math.exp(best.x[0]), best.x[1], best.x[2]])


def test_every_independent_profile_point_lies_within_its_rise_of_the_published_sigma(pad) -> None:
    # where the fit lands at a small radius, the profile computed independently at twice and
    # four times it: a point chi^2 rises by r at lies at most sqrt(max(r, 1)) published
    # sigmas away (the radius, and the place it moves to), as a quadratic's would
    model, fitter, frames = pad
    checked = 0
    for frame in frames:
        res = fitter.fit(frame, "sphere")
        r = res.values.get("r1_mm")
        if r is None or not r < 0.5 * BALL.r1:
            continue
        chi2, _ = _independent(model, fitter.sigma, frame, res.values, r)
        assert chi2 <= res.chi2 + 0.05  # scipy finds the fitter's minimum there
        for at in (2.0 * r, 4.0 * r):
            c2, (_, x, y) = _independent(model, fitter.sigma, frame, res.values, at)
            rise = c2 - res.chi2
            if rise >= 16.0:
                continue  # beyond the reach of a 4-sigma interval
            reach = 1.1 * math.sqrt(max(rise, 1.0))
            assert abs(at - r) <= reach * res.std["r1_mm"]
            assert abs(x - res.values["x_mm"]) <= reach * res.std["x_mm"] + 0.01
            assert abs(y - res.values["y_mm"]) <= reach * res.std["y_mm"] + 0.01
            checked += 1
        if checked >= 12:
            break
    assert checked >= 8

"""The tracker publishes nothing more confident than the fit it rests on.

A fit's profile test (tactiled.fit.profile) widens a sigma where the likelihood rises more
slowly than its curvature says: a near-circle's orientation on a coarse pad, an ellipse's
larger radius.  The tracker pools linearised frames, whose sigma knows nothing of that; it
multiplies its pooled sigma by the fit's widening (``fit_widening``), so on the fit's own frame
it publishes the fit's sigma, and only the frames it pools shrink it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.linearize import linearize
from tactiled.fit.params import VALUE_KEYS
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
from tactiled.pipeline.contact_filter import Tracker
from tactiled.pipeline.fit_sigmas import fit_widening, radius_force_variance
from tactiled.sensors import load_description

RATE = 100.0


@pytest.fixture(scope="module")
def xela():
    desc = load_description("xela_uskin_4x6")
    sensor = desc.sensor_model()
    return sensor, StrainModel(sensor), Fitter(sensor, FitOptions(window=desc.window,
                                                                  withhold_relative_sigma=0.5))


def _widened_fit(xela):
    """A near-sphere on the XELA 4x6 pad (radii 1.3 times apart at 2 N) whose fit's profile
    test widened its orientation's sigma: ``(frames of the contact, fit, its linearisation)``."""
    sensor, model, fitter = xela
    g = sensor.geometry
    rng = np.random.default_rng(11)
    for _ in range(40):
        r1 = rng.uniform(5.0, 10.0)
        c = Contact(r1, 1.3 * r1, rng.uniform(0.0, 180.0), 2.0, 0.5 * g.span_x, 0.5 * g.span_y)
        clean = model.predict(c)
        frames = [clean + rng.normal(0.0, sensor.noise.sigma, clean.shape) for _ in range(10)]
        res = fitter.fit(frames[0], "general")
        if res.params is None or res.values.get("angle_deg") is None:
            continue
        lin = linearize(fitter, frames[0], res.model, np.array(res.params))
        if lin is None:
            continue
        fit = res.to_json_dict()
        if fit_widening(fit, lin)[VALUE_KEYS.index("angle_deg")] > 1.2:
            return frames, fit, lin
    raise AssertionError("no widened orientation in 40 near-spheres")


def test_the_tracker_carries_a_fits_widened_sigma(xela) -> None:
    frames, fit, lin = _widened_fit(xela)
    i = VALUE_KEYS.index("angle_deg")
    w = fit_widening(fit, lin)[i]
    carried, plain = Tracker(withhold_relative_sigma=0.5), Tracker(withhold_relative_sigma=0.5)
    carried.adopt(lin, 0.0, fit)
    plain.adopt(lin, 0.0)  # as a relinearisation: no fit's sigma to carry
    for tr in (carried, plain):
        tr.step(frames[0].ravel(), 0.0, fitted=True)
    on_fit = carried.estimate(fit)
    # on the fit's own frame: the fit's sigma (the linearised one alone is w times narrower)
    assert on_fit["std"]["angle_deg"] == pytest.approx(fit["std"]["angle_deg"], rel=0.02)
    assert plain.estimate(fit)["std"]["angle_deg"] < on_fit["std"]["angle_deg"] / 1.15
    assert "widened" in on_fit["reasons"]["angle_deg"]
    for k, f in enumerate(frames[1:], 1):
        assert carried.step(f.ravel(), k / RATE) == plain.step(f.ravel(), k / RATE) == "tracked"
    a, b = carried.estimate(fit), plain.estimate(fit)
    # the frames pooled shrink both alike; the widening stays
    assert a["std"]["angle_deg"] == pytest.approx(w * b["std"]["angle_deg"], rel=1e-9)
    assert a["std"]["angle_deg"] < on_fit["std"]["angle_deg"]
    assert a["angle_deg"] == b["angle_deg"]
    # a relinearisation keeps what the fit gave
    again = linearize(xela[2], frames[-1], lin.model, np.array(carried.x))
    carried.adopt(again, 0.0)
    assert carried._widen[i] == w


def test_a_forces_variance_its_radius_explains() -> None:
    # ln r, ln f, x0, y0 (a sphere): with correlation rho the radius explains rho^2 of it
    sd_r, sd_f, rho = 0.4, 0.1, 0.9
    cov = np.diag([sd_r ** 2, sd_f ** 2, 0.01, 0.01])
    cov[0, 1] = cov[1, 0] = rho * sd_r * sd_f
    names = ("ln_r", "ln_f", "x0", "y0")
    assert radius_force_variance(cov, names) == pytest.approx(rho ** 2 * sd_f ** 2)
    cov[0, 1] = cov[1, 0] = 0.0
    assert radius_force_variance(cov, names) == 0.0
    # general: ln_ra and beta both radii
    c = np.eye(6) * 0.01
    c[0, 3] = c[3, 0] = 0.005
    c[1, 3] = c[3, 1] = 0.005
    full = radius_force_variance(c, ("ln_ra", "beta", "psi", "ln_f", "x0", "y0"))
    v = np.array([0.005, 0.005])
    assert full == pytest.approx(v @ np.linalg.solve(np.eye(2) * 0.01, v))
    assert math.isclose(full, 0.005)


def test_a_filter_run_off_to_a_radius_no_fit_gives_publishes_no_force() -> None:
    """XELA 4x4 (4.7 mm pitch): a light ball's radius is not seen (one frame's sigma of ln R is
    several units), so each frame's step of it passes as noise and the filter can run along
    the valley of radius and force: in the daemon one reached 180 m on its third frame, where
    the model puts no strain on the window whatever the force, and published 0.008 +- 0.057 N
    against the truth's 0.25 N.  Such a state's force is withheld (its radius is beyond any
    a fit gives); where the state comes back within it, its force is published again."""
    from tactiled.fit.params import PARAMS, RADIUS_LIMITS
    from tactiled.pipeline.kernels import X

    desc = load_description("xela_uskin_4x4")
    sensor = desc.sensor_model()
    g = sensor.geometry
    fitter = Fitter(sensor, FitOptions(window=desc.window))
    clean = StrainModel(sensor).predict(Contact(8.0, 8.0, 0.0, 0.25, 0.5 * g.span_x, 0.5 * g.span_y))
    rng = np.random.default_rng(3)
    frames = [clean + rng.normal(0.0, sensor.noise.sigma, clean.shape) for _ in range(3)]
    res = fitter.fit(frames[0], "sphere")
    fit = res.to_json_dict()
    lin = linearize(fitter, frames[0], res.model, np.array(res.params))
    tr = Tracker(geometry=g)
    tr.adopt(lin, 0.0, fit)
    tr.step(frames[0].ravel(), 0.0, fitted=True)
    assert tr.step(frames[1].ravel(), 1.0 / RATE) == "tracked"
    i_r, i_f = PARAMS["sphere"].index("ln_r"), PARAMS["sphere"].index("ln_f")
    # where the daemon's filter went: 180 m, 0.008 N
    tr._s[X, i_r], tr._s[X, i_f] = math.log(1.8e5), math.log(0.008)
    est = tr.estimate(fit)
    assert est["force_n"] is None and est["std"]["force_n"] is None
    assert "beyond any a fit gives" in est["reasons"]["force_n"]
    assert est["r1_mm"] is None
    # ... and inside the limits the same force is published (the rule is the radius's)
    tr._s[X, i_r] = math.log(0.5 * RADIUS_LIMITS[1])
    assert tr.estimate(fit)["force_n"] is not None

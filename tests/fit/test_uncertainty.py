"""Cramer-Rao uncertainties: MODEL.md's reference values, and honesty on noisy frames."""

import math

import numpy as np
import pytest

from tactiled.sensors.model import NoiseModel
from tactiled.fit.models import get_model
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
from tactiled.sim import add_noise


def test_model_md_cramer_rao_reference(fitter):
    # 12.5 mm cylinder at 90 deg, 1 N, sigma 0.0005, 4x4 window around the peak; the contact
    # half way between tactels along x (the paper's sec. 7.1 set-up).
    c = Contact(12.5, math.inf, 90.0, 1.0, 3.5 * 3.3, 3 * 3.9)
    frame = StrainModel().predict(c)
    start = get_model("cylinder").from_values(12.5, math.inf, 90.0, 1.0, c.x0, c.y0)
    res = fitter.fit(frame, "cylinder", start=start)
    assert fitter.sigma == 0.0005
    assert res.window[2:] == (4, 4)
    s = res.std
    assert s["r1_mm"] == pytest.approx(1.1, abs=0.1)  # 9 %
    assert s["r1_mm"] / 12.5 == pytest.approx(0.09, abs=0.01)
    assert s["angle_deg"] == pytest.approx(2.4, abs=0.2)
    assert s["force_n"] == pytest.approx(0.010, abs=0.001)
    assert s["x_mm"] == pytest.approx(0.028, abs=0.003)
    assert s["y_mm"] == pytest.approx(0.036, abs=0.003)


def test_reported_sigma_matches_actual_scatter(noisy_fitter):
    """On frames quantised to 0.001 plus Gaussian 0.0003 the RMS error of each parameter is
    within 1.2x the reported Cramer-Rao bound, and about 95 % of errors fall inside 2 sigma."""
    rng = np.random.default_rng(11)
    noise = NoiseModel(sigma=0.0003, quantum=0.001)
    c = Contact(10.0, math.inf, 70.0, 1.0, 11.2, 12.9)
    clean = StrainModel().predict(c)
    truth = {"r1_mm": c.r1, "angle_deg": c.psi_deg, "force_n": c.force, "x_mm": c.x0, "y_mm": c.y0}
    errors = {k: [] for k in truth}
    sigmas = {k: [] for k in truth}
    for _ in range(300):
        res = noisy_fitter.fit(add_noise(clean, noise, rng), "cylinder")
        for k, t in truth.items():
            e = res.values[k] - t
            errors[k].append((e + 90.0) % 180.0 - 90.0 if k == "angle_deg" else e)
            sigmas[k].append(res.std[k])
    for k in truth:
        e, s = np.array(errors[k]), np.array(sigmas[k])
        ratio = math.sqrt(np.mean(e**2)) / np.median(s)
        assert 0.8 < ratio < 1.2, (k, ratio)
        assert np.mean(np.abs(e) < 2 * s) > 0.90, k


def test_mean_of_n_frames_has_sqrt_n_smaller_bounds(fitter):
    """A frame that is the mean of N frames (fit(..., frames=N)) is fitted with noise
    sigma / sqrt(N): the bounds shrink by sqrt(N) and chi^2 grows by N for the same residuals;
    the fitter's own sigma is back afterwards."""
    rng = np.random.default_rng(4)
    c = Contact(10.0, math.inf, 70.0, 1.0, 11.2, 12.9)
    frame = add_noise(StrainModel().predict(c), NoiseModel(sigma=0.0005 / 4.0), rng)  # a mean of 16
    one = fitter.fit(frame, "cylinder")
    many = fitter.fit(frame, "cylinder", frames=16)
    for k in ("r1_mm", "angle_deg", "force_n", "x_mm", "y_mm"):
        assert many.std[k] == pytest.approx(one.std[k] / 4.0, rel=1e-6)
        assert many.values[k] == pytest.approx(one.values[k], rel=1e-6, abs=1e-9)
    assert many.chi2 == pytest.approx(16.0 * one.chi2, rel=1e-6)
    assert fitter.sigma == 0.0005
    with pytest.raises(ValueError, match="frames"):
        fitter.fit(frame, "cylinder", frames=0)


def test_the_mismatch_quantile_is_scipy_stats_chi2() -> None:
    """The fitter takes chi^2's quantile from scipy.special (scipy.stats is a slow import):
    the same numbers as ``scipy.stats.chi2.ppf``, bit for bit, for every window size."""
    from scipy.stats import chi2

    from tactiled.fit.search import MISMATCH_LEVEL, _chi2_limit

    for dof in range(1, 300):
        assert _chi2_limit(dof) == chi2.ppf(MISMATCH_LEVEL, dof)

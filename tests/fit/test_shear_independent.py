"""The shear estimates on independent simulations: 3-axis readings computed by direct quadrature
of the Boussinesq and Cerruti kernels over the Hertz pressure, the Cattaneo-Mindlin traction and
the torsion (tests/fit/mindlin_quadrature.py, no tactiled physics in it), fitted through
``tactiled fit --sensor`` and scored against the truth; and the profile interval of ``lam``
against a brute-force profile (a full re-fit at each ``lam``)."""

import math

import numpy as np
import pytest
from scipy.optimize import least_squares

from mindlin_quadrature import (ARRAYS, EDGE, MindlinQuadrature, description, edge_copies, edge_score,
                                fit_through_cli, scenes, score)
from tactiled.fit.shear import MU_RESOLVED, ShearFitter
from tactiled.fit.shear_profile import TWO_SIGMA_CHI2
from tactiled.physics.threeaxis import ShearContact, ThreeAxisModel

#: (r1, force, dx, dy from the centre, fx, fy, torque, lam): stick, partial slip, near slip.
LOADS = ((12.0, 1.3, 0.4, -0.3, 0.25, -0.15, 0.12, 0.0),
         (20.0, 2.0, 0.0, 0.2, 0.5, 0.2, -0.3, 0.6),
         (8.0, 0.7, -0.3, 0.0, 0.1, 0.3, 0.05, 0.93))


@pytest.mark.parametrize("spec", ARRAYS)
def test_independent_quadrature_equals_the_model(spec):
    """The product's forward model and the independent quadrature agree to a thousandth of the
    noise on every 3-axis description (flat and the curved finger), stick to near slip."""
    desc = description(spec)
    model, sim = ThreeAxisModel(desc), MindlinQuadrature(desc)
    cx, cy = model.centre()
    for r1, force, dx, dy, fx, fy, torque, lam in LOADS:
        mine = sim.frame(r1, force, cx + dx, cy + dy, fx, fy, torque, lam)
        theirs = model.frame(ShearContact(r1, force, cx + dx, cy + dy, fx, fy, torque, lam))
        assert np.abs(theirs).max() > 30 * model.noise.max()  # a real signal, not noise
        assert np.abs(mine - theirs).max() < 1e-3 * model.noise.min(), (spec, lam)


def test_independent_quadrature_is_converged():
    """Doubling the quadrature's nodes changes the readings by under 1e-4 of the noise."""
    desc = description("xela_uskin_4x4")
    coarse, fine = MindlinQuadrature(desc), MindlinQuadrature(desc, nodes=64)
    for r1, force, dx, dy, fx, fy, torque, lam in LOADS:
        a = coarse.frame(r1, force, 7.0 + dx, 7.0 + dy, fx, fy, torque, lam)
        b = fine.frame(r1, force, 7.0 + dx, 7.0 + dy, fx, fy, torque, lam)
        assert np.abs(a - b).max() < 1e-4 * coarse.noise.min()


def test_fit_on_independent_frames_through_the_cli(tmp_path):
    """16 independent frames on the XELA 4x4 patch through ``tactiled fit --sensor``: the
    tangential force and torsion within 4 sigma on every frame and within 2 sigma on most;
    mu and slip_margin, where published, within 4 sigma, else withheld with a reason."""
    desc = description("xela_uskin_4x4")
    frames, truth = scenes(MindlinQuadrature(desc), 16, np.random.default_rng(11))
    lines = fit_through_cli(desc, frames, tmp_path)
    sc = score(lines, truth)
    for key in ("fx_n", "fy_n", "torque_nmm", "q_over_p"):
        assert sc[key]["withheld"] == 0 and sc[key]["beyond4"] == 0, key
    # 64 values: an honest bound misses 2 sigma some 3 times; 10 misses is under 1e-3 likely
    assert np.mean([sc[k]["cover"] for k in ("fx_n", "fy_n", "torque_nmm", "q_over_p")]) >= 0.85
    for key in ("mu", "slip_margin"):
        assert sc[key]["n"] == 0 or sc[key]["beyond4"] == 0, key
    for line in lines:
        if line["shear"]["mu"] is None:
            assert "Q/(mu P)" in line["reasons"]["mu"]
        else:  # published with its bound, and the margin to slip with it
            assert 0 < line["shear"]["std"]["mu"] < line["shear"]["mu"]
            assert line["shear"]["slip_margin"] is not None


def _brute_profile(fitter, frame, est, lam):
    """chi2 at ``lam`` minimised over the seven other parameters by a full re-fit."""
    idx = est.window
    data = (frame.reshape(-1, 3)[idx] / fitter.model.noise).ravel()

    def residual(q):
        p = np.append(q, lam)
        return fitter._predict(p, idx).ravel() - data

    res = least_squares(residual, est.params[:7], method="lm", xtol=1e-10, ftol=1e-10)
    return 2.0 * res.cost


def test_profile_interval_matches_a_brute_force_profile():
    """On a one-sided likelihood (a partial-slip frame on the XELA patch) the interval's ends
    are where a full re-fit at fixed lam finds chi2 = least + 4, to the interval's resolution."""
    desc = description("xela_uskin_4x4")
    m = ThreeAxisModel(desc)
    cx, cy = m.centre()
    rng = np.random.default_rng(3)
    frame = m.frame(ShearContact(15.0, 1.8, cx + 0.3, cy, 0.6, 0.2, 0.1, 0.7)) + rng.normal(size=m.shape) * m.noise
    fitter = ShearFitter(desc)
    est = fitter.fit(frame)
    prof = est.lam_profile
    assert prof is not None and 0.0 < prof.hi - prof.lo < 1.0
    chi = {lam: _brute_profile(fitter, frame, est, lam) for lam in np.linspace(0.0, 1.0, 41)}
    least = min(chi.values())
    brute = [lam for lam, c in chi.items() if c <= least + TWO_SIGMA_CHI2]
    assert prof.lo == pytest.approx(min(brute), abs=0.04)
    assert prof.hi == pytest.approx(max(brute), abs=0.04)


def test_mu_published_near_slip():
    """A contact near slip (lam 0.97) on the 16x16 pad: the profile resolves mu although the
    estimate of lam may sit at its bound 1 (no Gaussian bound there); mu within 3 sigma."""
    desc = description("flat16_3axis")
    m = ThreeAxisModel(desc)
    cx, cy = m.centre()
    rng = np.random.default_rng(4)
    truth_mu = 0.5
    c = ShearContact(25.0, 2.0, cx, cy, 0.97 * truth_mu * 2.0, 0.0, 0.0, 0.97)
    est = ShearFitter(desc).fit(m.frame(c) + rng.normal(size=m.shape) * m.noise)
    mu, s_mu, why = est.mu()
    assert why is None, why
    assert abs(mu - truth_mu) <= 3 * s_mu and s_mu < MU_RESOLVED * mu
    margin, s_margin = est.slip_margin()
    assert abs(margin - 0.03) <= 3 * s_margin


@pytest.mark.slow
@pytest.mark.parametrize("spec", ARRAYS)
def test_bars_on_independent_frames(spec, tmp_path):
    """The issue's bars on 80 independent frames per array: fx, fy, torque RMS/CRB <= 1.3 and
    2-sigma coverage >= 90 %; mu, where published, coverage >= 90 %."""
    desc = description(spec)
    frames, truth = scenes(MindlinQuadrature(desc), 80, np.random.default_rng(100 + ARRAYS.index(spec)))
    sc = score(fit_through_cli(desc, frames, tmp_path), truth)
    for key in ("fx_n", "fy_n", "torque_nmm"):
        assert sc[key]["ratio"] <= 1.3 and sc[key]["cover"] >= 0.9, (key, sc[key])
    if sc["mu"]["n"] >= 10:
        assert sc["mu"]["cover"] >= 0.9, sc["mu"]
    assert math.isfinite(sc["q_over_p"]["ratio"])


@pytest.mark.slow
@pytest.mark.parametrize("scene", EDGE, ids=lambda s: f"{s[0]}-lam{s[3]}")
def test_mu_at_the_edge_of_resolution(scene, tmp_path):
    """100 noisy copies of a scene whose bound says mu's relative sigma near 20 %: where mu is
    published (decided by its bound at the estimate, the interval widened for that
    selection), its 2-sigma interval covers the truth on >= 90 % of those copies; where the
    bound at the truth resolves mu, it is published on most copies."""
    spec, r1, force, lam, mu = scene
    desc = description(spec)
    clean, frames = edge_copies(MindlinQuadrature(desc), r1, force, lam, mu, 100,
                                np.random.default_rng(EDGE.index(scene) + 1))
    sc = edge_score(fit_through_cli(desc, frames, tmp_path), mu)
    if sc["n"] >= 10:
        assert sc["cover"] >= 0.9, sc
    if not isinstance(ShearFitter(desc).fit(clean).mu_band(), str):
        assert sc["published"] >= 0.4, sc

"""An ellipse's orientation (the general model) is tested on its profile likelihood, as a
line's is (tactiled.fit.profile.angle_profile at its two near points): near a sphere the
likelihood is flat in the orientation and its linearised sigma too small.  Scored against the
simulator's truth over noise draws, with the test and without it (the same frames)."""

from __future__ import annotations

import math

import numpy as np

import tactiled.fit.point as point
from tactiled.physics.contact import Contact

WIDENED = "sigma widened to its profile likelihood"


def _angles(monkeypatch, on_description, profiled: bool) -> list[tuple[float, float, str]]:
    """``(error deg, sigma deg, reason)`` of every published orientation over the draws."""
    if not profiled:
        monkeypatch.setattr(point, "angle_profile", lambda *a, **k: None)
        monkeypatch.setattr(point, "round_test", lambda *a, **k: None)
    sensor, model, fitter = on_description("xela_uskin_4x6")
    rng = np.random.default_rng(21)
    out = []
    # ellipsoids 1.5-2 times longer than wide at 2-3 N on the coarse pad (60-90 noise sigmas)
    for r1, r2, psi, force in ((10.0, 20.0, 120.0, 2.0), (5.0, 10.0, 60.0, 2.5), (12.0, 18.0, 150.0, 3.0)):
        c = Contact(r1, r2, psi, force, 11.0, 7.0)
        clean = model.predict(c)
        for _ in range(40):
            res = fitter.fit(clean + rng.normal(0.0, sensor.noise.sigma, clean.shape), "general")
            a, sd = res.values.get("angle_deg"), res.std.get("angle_deg")
            if a is not None and sd:
                err = (a - psi + 90.0) % 180.0 - 90.0
                out.append((err, sd, res.reasons.get("angle_deg", "")))
    return out


def test_a_near_spheres_orientation_has_an_honest_sigma(monkeypatch, on_description) -> None:
    tested = _angles(monkeypatch, on_description, True)
    assert len(tested) >= 100  # most orientations are published
    z = np.array([abs(e) / sd for e, sd, _ in tested])
    assert np.mean(z <= 2.0) >= 0.9
    assert np.mean(z > 4.0) == 0.0
    assert sum(WIDENED in why for _, _, why in tested) >= 0.3 * len(tested)


def test_without_the_profile_the_same_frames_are_covered_less(monkeypatch, on_description) -> None:
    plain = _angles(monkeypatch, on_description, False)
    z = np.array([abs(e) / sd for e, sd, _ in plain])
    assert not any(WIDENED in why for _, _, why in plain)
    # the linearised sigma alone is too small for some: more of them beyond 2 sigmas
    monkeypatch.undo()
    tested = _angles(monkeypatch, on_description, True)
    zt = np.array([abs(e) / sd for e, sd, _ in tested])
    assert np.mean(zt > 2.0) < np.mean(z > 2.0)
    assert math.isfinite(float(zt.max()))


def _near_spheres(monkeypatch, on_description, tested: bool,
                  force: float = 2.0) -> tuple[list[float], int]:
    """``|error| / sigma`` of every published orientation of light near-spheres (radii
    1.0-1.4 times apart, 4-15 mm, at ``force`` N) on the coarse XELA 4x6 pad, and the fits
    made."""
    if not tested:
        monkeypatch.setattr(point, "round_test", lambda *a, **k: None)
    sensor, model, fitter = on_description("xela_uskin_4x6")
    g = sensor.geometry
    rng = np.random.default_rng(5)
    out, n = [], 0
    for _ in range(12):
        r1 = math.exp(rng.uniform(math.log(4.0), math.log(15.0)))
        psi = rng.uniform(0.0, 180.0)
        c = Contact(r1, r1 * rng.uniform(1.0, 1.4), psi, force,
                    g.span_x * rng.uniform(0.3, 0.7), g.span_y * rng.uniform(0.3, 0.7))
        clean = model.predict(c)
        for _ in range(10):
            res = fitter.fit(clean + rng.normal(0.0, sensor.noise.sigma, clean.shape), "general")
            n += 1
            a, sd = res.values.get("angle_deg"), res.std.get("angle_deg")
            if a is not None and sd:
                out.append(abs((a - psi + 90.0) % 180.0 - 90.0) / sd)
    return out, n


def test_a_near_circles_orientation_is_never_a_confident_guess(monkeypatch, on_description) -> None:
    # the orientation of an ellipse its frame does not tell from a circle is withheld, or its
    # sigma widened to its profile round the quarter turn: none beyond 4 sigmas
    z, n = _near_spheres(monkeypatch, on_description, True)
    assert len(z) >= 0.4 * n
    assert max(z) <= 4.0
    assert np.mean(np.array(z) <= 2.0) >= 0.9
    monkeypatch.undo()
    plain, _ = _near_spheres(monkeypatch, on_description, False)
    assert sum(v > 4.0 for v in plain) >= 3  # the linearised sigma alone: confident, wrong

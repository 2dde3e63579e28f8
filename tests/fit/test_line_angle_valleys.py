"""A weak line's fit in the wrong valley of its angle (tactiled/fit/profile.py ``angle_scan``,
tactiled/fit/linefit.py).

The ``demo`` scene's cylinder (10 mm at 1 N) lies along the 12x32 mat through (11, 31) mm:
its peak is about 4 noise sigmas, and a single frame's line fit can lock 10-60 deg off in
angle with a linearised sigma of 2-6 deg, its place swung round the window with it, several
mm off with a sigma of tenths.  Those frames are drawn here, one noise draw each (the draws
that did so), and then a run of draws at the same place: every published angle and place
lies within 4 of its sigmas of the truth, or is withheld with its reason.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
from tactiled.sensors import load_description
from tactiled.sim import as_line

#: The scene's line on the mat: along +y through (11, 31) mm.
TRUTH = Contact(10.0, math.inf, 90.0, 1.0, 11.0, 31.0)
#: Noise draws whose frame the fit, by its linearised sigma alone, put 4.5-20 sigmas off in
#: angle or place (measured: angle 64-127 deg with sigmas of 3-8 deg, places 2-12 mm off
#: with sigmas of 0.2-1.1 mm).
DRAWN = (35, 38, 41, 62, 81, 100, 147, 194)


@pytest.fixture(scope="module")
def mat() -> tuple[Fitter, np.ndarray, float]:
    desc = load_description("flexitac_12x32")
    sensor = desc.sensor_model()
    clean = StrainModel(sensor).predict(as_line(TRUTH, sensor.geometry))
    return Fitter(sensor, FitOptions(window=desc.window)), clean, sensor.noise.sigma


def _far(fitter: Fitter, strain: np.ndarray) -> tuple[list[str], bool]:
    """The published angle and place (across the line) beyond 4 of their sigmas, and
    whether the angle is published."""
    res = fitter.fit(strain, "cylinder")
    assert res.contact and res.label == "line", res.message
    out = []
    a, sa = res.values["angle_deg"], res.std["angle_deg"]
    if a is not None:
        err = (a - TRUTH.psi_deg + 90.0) % 180.0 - 90.0
        if abs(err) > 4.0 * sa:
            out.append(f"angle {a:.1f} +- {sa:.2f} deg")
    else:
        assert res.reasons["angle_deg"]
    x, sx = res.values["x_mm"], res.std["x_mm"]  # across a line along +y: x
    if x is not None:
        if abs(x - TRUTH.x0) > 4.0 * sx:
            out.append(f"x {x:.2f} +- {sx:.2f} mm")
    else:
        assert res.reasons["x_mm"]
    return out, a is not None


@pytest.mark.parametrize("draw", DRAWN)
def test_a_weak_line_drawn_where_its_fit_went_wrong_is_not_confidently_wrong(
        mat: tuple[Fitter, np.ndarray, float], draw: int) -> None:
    fitter, clean, sigma = mat
    strain = clean + np.random.default_rng(draw).normal(0.0, sigma, clean.shape)
    assert _far(fitter, strain)[0] == []


def test_a_weak_lines_angle_and_place_over_many_draws(
        mat: tuple[Fitter, np.ndarray, float]) -> None:
    """40 other draws: by the linearised sigma alone 9 of them put the angle or the place
    beyond 4 sigmas (and 12 angles were withheld); tested on the profile at most 2, and at
    least three quarters of the angles stay published (measured: 1 and 34)."""
    fitter, clean, sigma = mat
    far, published = 0, 0
    for draw in range(200, 240):
        strain = clean + np.random.default_rng(draw).normal(0.0, sigma, clean.shape)
        wrong, shown = _far(fitter, strain)
        far += bool(wrong)
        published += shown
    assert far <= 2, far
    assert published >= 30, published

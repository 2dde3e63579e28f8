"""The fitter never raises and never returns NaN or inf, whatever the frame."""

import json
import math

import numpy as np
import pytest

from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel

GOOD = StrainModel().predict(Contact(8.0, math.inf, 80.0, 1.0, 11.0, 13.0))


def frames():
    rng = np.random.default_rng(3)
    yield "zeros", np.zeros((8, 8))
    yield "negative", -np.abs(GOOD)
    yield "noise only", rng.normal(0, 0.0005, (8, 8))
    nan = GOOD.copy()
    nan[3, 3] = np.nan
    yield "nan at peak", nan
    inf = GOOD.copy()
    inf[2, 4] = np.inf
    yield "inf", inf
    yield "all nan", np.full((8, 8), np.nan)
    sat = np.minimum(GOOD, 0.5 * GOOD.max())
    yield "saturated", sat
    dead = GOOD.copy()
    dead[3, 4] = 0.0
    yield "dead tactel", dead
    yield "half off the array", StrainModel().predict(Contact(8.0, math.inf, 80.0, 1.0, -2.0, 13.0))
    yield "corner", StrainModel().predict(Contact(3.0, 3.0, 0.0, 1.0, 0.0, 0.0))
    yield "huge", GOOD * 1e6
    yield "tiny", GOOD * 1e-9
    yield "spike", np.where(np.arange(64).reshape(8, 8) == 27, 0.05, 0.0)


@pytest.mark.parametrize("name,frame", list(frames()), ids=[n for n, _ in frames()])
@pytest.mark.parametrize("model", ["cylinder", "sphere", "general", "auto"])
def test_never_raises_never_nan(fitter, name, frame, model):
    res = fitter.fit(frame, model)
    line = json.dumps(res.to_json_dict(frame=0), allow_nan=False)  # raises on NaN/inf
    assert json.loads(line)["frame"] == 0
    for k, v in res.values.items():
        if v is None and res.contact and res.model:
            assert k in res.reasons or k == "r2_mm" or k == "angle_deg"


def test_mask_excludes_tactels(fitter):
    frame = GOOD.copy()
    frame[2, 3] = 0.5  # a stuck tactel inside the window
    mask = np.ones((8, 8), bool)
    mask[2, 3] = False
    clean = fitter.fit(GOOD, "cylinder")
    masked = fitter.fit(frame, "cylinder", mask=mask)
    assert masked.values["r1_mm"] == pytest.approx(clean.values["r1_mm"], rel=1e-3)
    assert masked.n_points == clean.n_points - 1


def test_window_sizes(fitter):
    for n in (3, 4, 6, 8, 20):
        res = fitter.fit(GOOD, "cylinder") if n == 4 else type(fitter)(fitter.sensor, type(fitter.options)(window=n)).fit(GOOD, "cylinder")
        assert res.values["r1_mm"] == pytest.approx(8.0, rel=1e-3)
        assert res.window[2] == min(n, 8)


@pytest.mark.parametrize("x0", [-12.0, -6.0])
def test_contact_off_the_array_is_not_confident_nonsense(fitter, x0):
    # Only the tail of the response is seen: the radius must not come back "certain".
    frame = StrainModel().predict(Contact(8.0, math.inf, 80.0, 1.0, x0, 13.0))
    res = fitter.fit(frame, "cylinder")
    assert res.values["r1_mm"] is None and res.std["r1_mm"] is None
    assert "Cramer-Rao" in res.reasons["r1_mm"]


def test_light_touch_withholds_radius(fitter):
    # MODEL.md: radius is not observable at low force.  At 0.02 N with sigma 0.0005 the
    # bound on a 25 mm radius is far above 50 %: with the daemon's policy the radius is null,
    # (0.05 N here: at 0.02 N it is over 10x the radius and always withheld)
    # location and force kept; without it, it is reported but flagged.
    from tactiled.fit.fitter import FitOptions, Fitter

    frame = StrainModel().predict(Contact(25.0, math.inf, 90.0, 0.05, 11.0, 13.0))
    flagged = fitter.fit(frame, "cylinder")
    assert flagged.values["r1_mm"] is not None
    assert flagged.reasons["r1_mm"].startswith("poorly determined (force too low for curvature)")
    res = Fitter(fitter.sensor, FitOptions(withhold_relative_sigma=0.5)).fit(frame, "cylinder")
    assert res.values["r1_mm"] is None
    assert res.reasons["r1_mm"].startswith("force too low for curvature")
    assert res.values["force_n"] == pytest.approx(0.05, rel=0.05)
    assert abs(res.values["x_mm"] - 11.0) < 0.2

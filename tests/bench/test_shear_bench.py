"""The shear bench's pieces on a few frames: figures computed against the simulator's truth."""

import math

import pytest

from tactiled_bench import shear


def test_accuracy_and_slip_figures_on_a_small_run():
    desc = shear.resolve("xela_uskin_4x4")
    acc = shear.accuracy(desc, 12, seed=3)
    for q in ("fx", "fy", "torque"):
        assert 0.5 < acc[f"{q}_ratio"] < 2.0 and 0.0 <= acc[f"{q}_cover"] <= 1.0
    assert 0.0 <= acc["mu_resolved"] <= 1.0
    slip = shear.slip(desc, pulls=1, sticks=0, seed=4)
    assert slip["pulls"] == 1 and slip["missed"] == 0 and 0 <= slip["median_delay"] <= 10


def test_resolve_makes_a_one_axis_description_three_axis():
    d = shear.resolve("flat16_3axis")
    assert d.axes == 3 and d.rows == 16 and d.taxel_depth_mm == d.depth_x_mm
    assert shear.resolve("xela_uskin_4x6").axes == 3
    assert d.axis_gain == (1000.0, 1000.0, 1000.0)


def test_known_onset_and_held_contacts_on_a_small_run():
    """The statistic a test that knew the onset sees 5 frames after it is reported for every
    constant-friction pull (on the 4x4 patch, far over the noise); contacts held at 0.95 mu P,
    drawn from a fit's covariance, give no onset."""
    desc = shear.resolve("xela_uskin_4x4")
    slip = shear.slip(desc, pulls=2, sticks=0, seed=5, kinetic=1.0)
    assert slip["known_median"] > 3.0 and 0.0 <= slip["known_over"] <= 1.0
    # the motion alone is part of the joint evidence: never more than both together
    assert 0.0 < slip["motion_median"] <= slip["known_median"] and 0.0 <= slip["motion_over"] <= 1.0
    assert 0.0 < slip["motion_clean_median"] <= slip["clean_median"]
    assert 0.0 < slip["snr_needed"] <= slip["motion_snr_needed"]
    held = shear.null_events(desc, 2, seed=6, hold_frames=100)
    assert held["onsets"] == 0 and held["scenes"] == 2 and held["frames"] >= 2 * (150 + 100)


def test_the_factor_95_percent_needs_against_its_closed_form():
    """Equal noiseless statistics m: 95 % over the threshold t needs f m - t = 1.6449 (the
    one-sided 95 % point of a unit normal), so f = (t + 1.6449) / m; a spread adds to it."""
    assert shear.snr_needed([3.0] * 5, threshold=4.5) == pytest.approx((4.5 + 1.6449) / 3.0, rel=1e-4)
    assert shear.snr_needed([12.0] * 5, threshold=4.5) == pytest.approx(6.1449 / 12.0, rel=1e-4)
    assert shear.snr_needed([2.0, 6.0], threshold=4.5) > 6.1449 / 4.0
    assert math.isnan(shear.snr_needed([]))


def test_pulls_at_the_limit_report_the_margins_resolution():
    """A pull that stays put at the friction's limit (``limit``) on the 4x4 patch: its delay is
    scored within 5 frames either side, and the margin's sigma 5 frames after the onset is
    reported against the detector's MARGIN_SIGMA (the patch does not resolve it: a factor
    over 1)."""
    desc = shear.resolve("xela_uskin_4x4")
    r = shear.slip(desc, pulls=1, sticks=0, seed=4, kind="limit")
    assert r["pulls"] == 1 and r["early"] == 0 and 0.0 <= r["within"] <= 1.0
    assert r["margin_resolved"] == (r["margin_snr_needed"] <= 1.0)
    assert r["margin_snr_needed"] > 1.0


def test_the_bias_of_lam_near_slip_is_measured_scene_by_scene():
    """The bench's measure behind the margin's floor (tactiled.fit.slip.BIAS): on three pulls
    at the limit of the 4x4 patch, each scene's mean error of the unclipped lam over its sigma,
    on its frames under stick with a true lam of 0.8 or more, and that mean's standard error;
    the means lie within 4 standard errors of 0 plus BIAS (the floor covers them), and the
    summary is their mean, spread and noise."""
    import numpy as np

    from tactiled.fit.slip import BIAS

    desc = shear.resolve("xela_uskin_4x4")
    r = shear.slip(desc, pulls=3, sticks=0, seed=6, kind="limit")
    assert len(r["biases"]) == 3
    m, se = np.array(r["biases"]).T
    assert np.all(se > 0) and np.all(se < 0.5) and np.all(np.abs(m) <= BIAS + 4 * se), r["biases"]
    mean, spread, noise, n = shear._scene_bias(r["biases"])
    assert n == 3 and mean == pytest.approx(m.mean()) and spread == pytest.approx(m.std())
    assert noise == pytest.approx(math.sqrt(np.mean(se ** 2)))

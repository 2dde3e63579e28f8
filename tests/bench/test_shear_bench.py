"""The shear bench's pieces on a few frames: figures computed against the simulator's truth."""

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
    held = shear.null_events(desc, 2, seed=6, hold_frames=100)
    assert held["onsets"] == 0 and held["scenes"] == 2 and held["frames"] >= 2 * (150 + 100)

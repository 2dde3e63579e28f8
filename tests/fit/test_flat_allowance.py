"""A flat array's work allowance (tactiled.fit.budget.FLAT_WORK_FACTOR) goes only to the
searches that earn it: a window no model explains stops at the base work and says so; a ball
on the flat 12x32 mat whose fit needs more than the base still gets it, and converges where
the unbudgeted fit does.  Costs are measured by ``tactiled bench --suite unexplained`` and
``--suite sensors`` (docs/performance/fit-time.md), never asserted here."""

from __future__ import annotations

import numpy as np

from tactiled_bench import unexplained
from tactiled.fit.budget import DEFAULT_WORK, DENIED, EXHAUSTED, budget_spent
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.params import VALUE_KEYS
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
from tactiled.sensors import load_description


def test_random_flat_frames_stop_at_the_base_work_and_say_so():
    sensor = unexplained.flat32()
    frames = unexplained.random_patterns(sensor, np.random.default_rng(5), 8)
    fitter = Fitter(sensor, unexplained.daemon_options())
    # the same frames given the whole allowance as of right (a base three times as large)
    rich = Fitter(sensor, unexplained.daemon_options(budget_work=3 * DEFAULT_WORK))
    assert fitter.allowance == 2 * DEFAULT_WORK
    denied = wanted = 0
    for frame in frames:
        res = fitter.fit(frame, "auto")
        assert fitter.spent[1] <= DEFAULT_WORK  # nothing of the allowance was spent
        fit_reason = res.reasons.get("fit", "")
        if DENIED in fit_reason:
            denied += 1
            assert not res.converged and budget_spent(res.reasons)
            assert fit_reason.startswith(EXHAUSTED)
            assert all(res.values[k] is None for k in VALUE_KEYS) or "widened" in fit_reason
        rich.fit(frame, "auto")
        wanted += rich.spent[1] > DEFAULT_WORK
    assert denied >= 2 and wanted >= 2, (denied, wanted)


def test_a_ball_on_the_flat_mat_earns_the_allowance_and_converges():
    """A 21 mm ball at ~7 N on the 12x32 mat (wider than its 4x4 window): auto scouts the
    line, the sphere and the ellipse, and needs more than the base work; it gets it and lands
    on the unbudgeted fit's sphere."""
    desc = load_description("flexitac_12x32")
    sensor = desc.sensor_model()
    clean = StrainModel(sensor).predict(Contact(20.8, 20.8, 0.0, 7.3, 8.7, 44.0))
    fitter = Fitter(sensor, FitOptions(window=desc.window))
    free = Fitter(sensor, FitOptions(window=desc.window, budget_iterations=None, budget_work=None))
    over = 0
    for seed in range(4):
        frame = clean + np.random.default_rng(seed).normal(0.0, sensor.noise.sigma, clean.shape)
        res, ref = fitter.fit(frame, "auto"), free.fit(frame, "auto")
        assert ref.converged and ref.model == "sphere"
        assert res.converged and res.model == "sphere", res.reasons
        assert "fit" not in res.reasons
        over += fitter.spent[1] > DEFAULT_WORK
        for k in ("x_mm", "y_mm", "r1_mm", "force_n"):
            # the same minimum, to within the convergence tolerance (0.1 sigma)
            assert abs(res.values[k] - ref.values[k]) <= 0.1 * ref.std[k], (k, res.values, ref.values)
    assert over >= 2  # the allowance was needed (the line scouted on its band, in half), and granted

"""A fit's budget (tactiled.fit.budget): every fit stays within its iterations and work, a fit
the budget stopped says so (not converged, a reason, sigmas widened or values withheld), and
the budget changes no fit that converges without it.  Its cost is measured by ``tactiled bench
--suite unexplained`` (docs/performance/benchmarks.md), never asserted here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled_bench import unexplained
from tactiled_bench.suite import build_suite
from tactiled.fit.budget import EXHAUSTED, budget_spent
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.params import VALUE_KEYS
from tactiled.fit.result import FitResult


@pytest.fixture(scope="module")
def quick_fits() -> tuple[list[str], list[tuple[str, FitResult]]]:
    """The quick bench's frames (simulated contacts, pressed blobs, hand prints, random and
    saturated patterns on 8x8 and 32x32 arrays), fitted once as the daemon fits (each fit's
    deferred learning caught up after it): the budget's problems found, and every
    ``(set name, result)``."""
    results: list[tuple[str, FitResult]] = []
    return unexplained.budget_check(quick=True, seed=9, results=results), results


def test_every_fit_of_the_quick_frame_sets_keeps_its_budget(quick_fits):
    problems, results = quick_fits
    assert len(results) >= 200 and problems == [], problems


def test_a_fit_the_budget_stopped_says_so_and_widens_or_withholds(quick_fits):
    stopped = 0
    for name, res in quick_fits[1]:
        if name == "contacts 8x8" or not budget_spent(res.reasons):
            continue
        stopped += 1
        assert not res.converged and res.reasons["fit"].startswith(EXHAUSTED)
        values = [res.values[k] for k in VALUE_KEYS]
        if all(v is None for v in values):
            assert "withheld" in res.reasons["fit"] or "model choice" in res.reasons["fit"] \
                or "not tried" in res.reasons["fit"], res.reasons
        else:
            assert "widened" in res.reasons["fit"] or "not tried" in res.reasons["fit"], res.reasons
        assert res.to_json_dict()["converged"] is False
    assert stopped >= 20  # frames the model cannot explain do run out of budget


def test_a_small_budget_stops_a_fit_and_widens_its_sigmas_by_the_distance_left():
    frame = build_suite(1, 1, kinds=("cylinder",), seed=4)[0]
    full = Fitter(options=FitOptions(budget_iterations=None, budget_work=None)).fit(frame.strain, "cylinder")
    assert full.converged and full.iterations > 3
    res = Fitter(options=FitOptions(budget_iterations=2)).fit(frame.strain, "cylinder")
    assert res.iterations <= 2 and not res.converged
    assert res.reasons["fit"].startswith(f"{EXHAUSTED} (2 iterations)")
    if res.values["x_mm"] is not None:  # within reach of the minimum: every sigma widened
        widen = float(res.reasons["fit"].split("widened ")[1].split("x")[0])
        assert widen > 1.0
        for k in ("x_mm", "y_mm", "force_n"):
            # the minimum lies within the widened 1-sigma... plus its own error: 3 sigma
            assert abs(res.values[k] - full.values[k]) <= 3.0 * res.std[k]
    else:
        assert "withheld" in res.reasons["fit"]


def test_the_budget_changes_no_fit_that_converges_without_it():
    frames = build_suite(12, 2, seed=7)
    for options in ({}, {"withhold_relative_sigma": 0.5, "learn_floor": True}):
        with_budget = Fitter(options=FitOptions(**options))
        without = Fitter(options=FitOptions(budget_iterations=None, budget_work=None, **options))
        for bf in frames:
            a, b = with_budget.fit(bf.strain, "auto"), without.fit(bf.strain, "auto")
            if not b.converged:
                continue
            ja, jb = a.to_json_dict(), b.to_json_dict()
            ja.pop("fit_ms"), jb.pop("fit_ms")
            assert ja == jb
            its, work = with_budget.spent
            assert its <= with_budget.options.budget_iterations // 1.2  # a margin, not at the edge
            assert work <= with_budget.options.budget_work / 1.2 and math.isfinite(work)


def test_budget_options_are_checked():
    for bad in ({"budget_iterations": 0}, {"budget_work": -1}, {"budget_iterations": 1.5}):
        try:
            FitOptions(**bad)
        except ValueError as err:
            assert next(iter(bad)) in str(err)
        else:
            raise AssertionError(f"{bad} accepted")
    assert FitOptions(budget_iterations=None, budget_work=None).budget_work is None
    assert np.isfinite(FitOptions().budget_work)


def test_a_budget_too_small_for_one_evaluation_answers_cleanly():
    """Every model, on the paper's finger and on a flat pad (its line model): a budget that
    cannot pay for the first evaluation gives a well-formed, not converged answer."""
    from tactiled.physics.contact import Contact, LineContact
    from tactiled.physics.strain import StrainModel
    from tactiled.sensors import load_description

    for name, contact in (("fearing1988", Contact(6.0, math.inf, 70.0, 1.2, 12.0, 14.0)),
                          ("flat16", LineContact(8.0, 60.0, 0.08, 17.0, 20.0))):
        sensor = load_description(name).sensor_model()
        frame = StrainModel(sensor).predict(contact)
        fitter = Fitter(sensor, FitOptions(budget_work=1))
        for model in ("cylinder", "sphere", "general", "auto"):
            res = fitter.fit(frame, model)
            assert res.contact and not res.converged, (name, model, res)
            assert budget_spent(res.reasons), (name, model, res.reasons)
            assert all(res.values[k] is None for k in VALUE_KEYS), (name, model, res.values)
            assert fitter.spent[1] <= 1



def test_a_frame_the_model_cannot_explain_keeps_its_budget_and_says_so():
    """A pattern no contact makes (random strains on the paper's finger, as the daemon fits
    it): the fit stays within its budget, and its sigmas are widened by the residuals' excess
    or its values withheld, with the reasons."""
    from tactiled_bench.unexplained import FINGER_8, daemon_options

    fitter = Fitter(FINGER_8, daemon_options())
    for seed in range(3):
        frame = np.random.default_rng(seed).uniform(0.0, 0.05, (8, 8))
        res = fitter.fit(frame, "cylinder")
        assert res.chi2 > 100 * res.n_points  # nothing like a contact
        assert res.iterations <= fitter.budget_limits[0] and fitter.spent[1] <= fitter.budget_limits[1]
        assert "residuals exceed the noise" in res.reasons["uncertainty"]
        assert res.converged or budget_spent(res.reasons)

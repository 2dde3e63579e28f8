"""The configs and models suites' scoring (benchmarks/tactiled_bench/runner.py): an ellipsoid's
second radius is scored as its first is, in % of the truth, where its bound resolves it."""

from __future__ import annotations

import pytest

from tactiled_bench import runner
from tactiled_bench.suite import build_suite
from tactiled.fit.fitter import Fitter


def test_an_ellipsoids_second_radius_is_scored_where_its_bound_resolves_it() -> None:
    fitter = Fitter()
    frames = build_suite(8, 1, kinds=("general", "sphere"), seed=3)
    general = [f for f in frames if f.kind == "general"]
    truths = [runner.truth_of(f, fitter) for f in general]
    assert all(t.values["r2_mm"] == f.contact.r2 for t, f in zip(truths, general))
    assert runner.truth_of(next(f for f in frames if f.kind == "sphere"), fitter).values["r2_mm"] is None
    # the bound at the truth decides, as for the first radius
    for t in truths:
        assert runner.observable("r2_mm", t) == (t.crb["r2_mm"] / t.values["r2_mm"] < runner.OBSERVABLE_RELATIVE)
    assert any(runner.observable("r2_mm", t) for t in truths)
    assert runner.error("r2_mm", 33.0, 30.0) == pytest.approx(10.0)
    assert runner.crb_in_units("r2_mm", 3.0, 30.0) == pytest.approx(10.0)

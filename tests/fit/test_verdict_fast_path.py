"""The rule's fast path (tactiled/fit/verdict.py, ``_all_kept``) decides as the rule does.

``judge_values`` skips its value-by-value tests when ``_all_kept`` finds every value kept by
them; on values and sigmas drawn across every threshold of the rule (each radius's relative
sigma around ``withhold_relative_sigma`` and ``UNOBSERVABLE_RELATIVE_SIGMA``, radii around
``RADIUS_LIMITS``, places around the array's span, angles around ``MAX_ANGLE_SIGMA``, and
None, zero, negative, non-finite and integer values), it returns what the tests one by one
return: the same values, sigmas, reasons and ellipse.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactiled.fit import verdict
from tactiled.fit.params import MAX_ANGLE_SIGMA, RADIUS_LIMITS, VALUE_KEYS
from tactiled.fit.verdict import ArrayLimits, judge_values
from tactiled.sensors.model import SensorModel

PAPER = ArrayLimits.of(SensorModel())
SPAN_X = PAPER.span_x + PAPER.dx

_odd = st.sampled_from([None, 0.0, -1.0, math.nan, math.inf, -math.inf, 3])
_value = st.one_of(_odd, st.floats(-5.0, 60.0), st.sampled_from(
    [RADIUS_LIMITS[0], RADIUS_LIMITS[0] * 0.999, RADIUS_LIMITS[1], RADIUS_LIMITS[1] * 1.001]))
# relative sigmas around the rule's bounds: 0.5 (the daemon's), 10 (unobservable)
_rel = st.one_of(_odd, st.floats(0.0, 20.0), st.sampled_from([0.5, 0.5000001, 10.0, 10.0001]))
_sd = st.one_of(_odd, st.floats(0.0, 100.0), st.sampled_from(
    [SPAN_X, SPAN_X * 1.0001, MAX_ANGLE_SIGMA, MAX_ANGLE_SIGMA * 1.0001]))


#: a well measured contact: every value kept (the fast path's common case)
GOOD = {"x_mm": 10.0, "y_mm": 12.0, "force_n": 0.5, "r1_mm": 8.0, "r2_mm": 20.0,
        "angle_deg": 30.0}


@st.composite
def contacts(draw: st.DrawFn) -> tuple[dict, dict, str]:
    """A well measured contact with some of its values and sigmas drawn anywhere (most
    draws change one or two: the fast path is taken, or just missed, near each bound)."""
    values = dict(GOOD)
    std = {k: 0.05 * v for k, v in values.items()}
    for key in draw(st.lists(st.sampled_from(VALUE_KEYS), max_size=3, unique=True)):
        if draw(st.booleans()):
            values[key] = draw(_value)
        v = values[key]
        if key in ("r1_mm", "r2_mm", "force_n") and isinstance(v, float) and draw(st.booleans()):
            rel = draw(_rel)
            std[key] = rel * v if isinstance(rel, float) and math.isfinite(v) else rel
        else:
            std[key] = draw(_sd)
    return values, std, draw(st.sampled_from(["sphere", "cylinder", "general", "line"]))


def _judged(values: dict, std: dict, label: str, wrs: float | None) -> tuple:
    v, s, r = dict(values), dict(std), {}
    ell = judge_values(v, s, r, PAPER, label=label, withhold_relative_sigma=wrs)
    return repr(v), repr(s), r, ell


@settings(max_examples=400, deadline=None)
@given(contacts(), st.sampled_from([None, 0.5]))
def test_the_fast_path_decides_as_the_rule(drawn: tuple, wrs: float | None) -> None:
    values, std, label = drawn
    fast = _judged(values, std, label, wrs)
    kept = verdict._all_kept(values, std, PAPER, wrs)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(verdict, "_all_kept", lambda *a: False)  # the value-by-value tests only
        slow = _judged(values, std, label, wrs)
    assert fast == slow
    if kept:  # the fast path keeps what the tests keep: only the ellipse rule, after them,
        # may withhold a value
        assert {why for k, why in slow[2].items() if k in VALUE_KEYS} <= {slow[2].get("ellipse")}


def test_a_well_measured_contact_takes_the_fast_path() -> None:
    values = dict(GOOD)
    std = {k: 0.05 * v for k, v in values.items()}
    assert verdict._all_kept(values, std, PAPER, 0.5)
    std["r1_mm"] = 0.6 * values["r1_mm"]  # a radius beyond the daemon's bound: the tests decide
    assert not verdict._all_kept(values, std, PAPER, 0.5)
    assert verdict._all_kept(values, std, PAPER, None)

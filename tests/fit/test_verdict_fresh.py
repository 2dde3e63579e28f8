"""The rule on an estimate made for its frame alone (tactiled/fit/verdict.py, ``judge_fresh``)
gives what ``judge`` gives, key for key and in the same order.

The daemon publishes a tracker's estimate through ``judge_fresh``: each contact judged once,
in place, the top level given its first contact's verdict.  On estimates of one and of several
contacts shaped as ``association.identified(..., fresh=True)`` leaves them, with values and
sigmas drawn across every threshold of the rule (test_verdict_fast_path.py's draws: radii,
forces, places and angles around their bounds, None, zero, negative, non-finite), and lines and
contacts too long for the array among them, both give the same JSON text.  ``ellipse_of`` is held
to ``physics.hertz.contact_ellipse_radii``, whose records and checks it skips, on drawn values.
"""

from __future__ import annotations

import copy
import json
import math

from hypothesis import given, settings
from hypothesis import strategies as st
from test_verdict_fast_path import PAPER, contacts

from tactiled.fit.verdict import ArrayLimits, ellipse_of, judge, judge_fresh
from tactiled.physics.hertz import contact_ellipse_radii
from tactiled.sensors import load_description

#: a flat array (the 16x16 pad): a cylinder there is a line, not an ellipse
PAD = ArrayLimits.of(load_description("flat16").sensor_model())


def _contact(values: dict, std: dict, label: str, ellipse: bool, line: bool) -> dict:
    """One contact's dict as a tracker's estimate holds it: its own std and reasons."""
    c = {"contact": True, "model": label, **values, "rms": 1e-4, "std": dict(std),
         "label": label, "peak": 0.01, "reasons": {"x_mm": "kept"},
         "ellipse": {"a_mm": 1.0, "b_mm": 1.0, "theta_deg": 0.0} if ellipse else None,
         "frames_used": 7}
    if line:
        c["line"] = {"length_mm": 10.0}
    return c


@st.composite
def estimates(draw: st.DrawFn) -> dict:
    """A fresh estimate of one contact (``{**one, "contacts": [one], "contact_id"...}``) or of
    several (the strongest's copy at the top, its contacts listed after it)."""
    each = [_contact(*draw(contacts()), draw(st.booleans()), draw(st.booleans()) and k == 0)
            for k in range(draw(st.integers(1, 3)))]
    for i, c in enumerate(each, 1):
        c["contact_id"] = i
    if len(each) == 1:
        return {**each[0], "contacts": each}
    return {**each[0], "contacts": each, "contact_id": 1}


def _text(fit: dict) -> str:
    return json.dumps(fit, allow_nan=True)


@settings(max_examples=300, deadline=None)
@given(estimates(), st.sampled_from([None, 0.5, 0.2]), st.booleans())
def test_a_fresh_estimate_is_judged_as_the_rule_judges_it(fit, wrs, flat_pad) -> None:
    limits = PAD if flat_pad else PAPER
    want = judge(copy.deepcopy(fit), limits, withhold_relative_sigma=wrs)
    got = judge_fresh(copy.deepcopy(fit), limits, withhold_relative_sigma=wrs)
    assert _text(got) == _text(want)
    # the top level and its first contact do not share the dicts a consumer may read apart
    if got.get("contact"):
        first = got["contacts"][0]
        assert got["std"] is not first["std"] and got["std"] == first["std"]


@settings(max_examples=100, deadline=None)
@given(estimates())
def test_a_top_level_that_is_not_its_first_contacts_copy_goes_to_the_rule(fit) -> None:
    fit = copy.deepcopy(fit)
    fit["std"] = dict(fit["std"])  # (no longer the first contact's own dict)
    want = judge(copy.deepcopy(fit), PAPER, withhold_relative_sigma=0.5)
    assert _text(judge_fresh(fit, PAPER, withhold_relative_sigma=0.5)) == _text(want)


_radius = st.one_of(st.floats(1e-3, 1e4), st.sampled_from([math.inf, math.nan, 0.0, -1.0]))


@settings(max_examples=300, deadline=None)
@given(_radius, st.one_of(st.none(), _radius), st.one_of(st.none(), st.floats(-720.0, 720.0)),
       st.one_of(st.floats(1e-6, 1e3), st.sampled_from([math.inf, math.nan, 0.0])),
       st.booleans())
def test_the_ellipse_is_the_hertz_ellipse(r1, r2, angle, force, flat_pad) -> None:
    limits = PAD if flat_pad else PAPER
    values = {"r1_mm": r1, "r2_mm": r2, "angle_deg": angle, "force_n": force}
    got = ellipse_of(values, limits)
    # the reference: the Hertz ellipse's own function, its errors a missing ellipse
    want = None
    r2_ = math.inf if r2 is None else r2
    if r1 > 0.0 and force > 0.0 and (angle is not None or r2_ == r1) and not (
            math.isinf(r2_) and math.isinf(limits.finger_radius)):
        try:
            e = contact_ellipse_radii(r1, r2_, 0.0 if angle is None else angle, force,
                                      limits.finger_radius, limits.compliance)
        except (ValueError, ZeroDivisionError, OverflowError):
            e = None
        if e is not None and math.isfinite(e.a) and math.isfinite(e.b) and e.a >= 0.0:
            want = {"a_mm": e.a, "b_mm": e.b, "theta_deg": math.degrees(e.theta) % 180.0}
    assert got == want

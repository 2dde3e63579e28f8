"""A tracked estimate built from its base's plan (``Tracker.estimate_from``: what depends on the
fit it rests on kept per base, the withholding rules' answer inline where it is None for
sure) is the estimate the rules give value by value, key for key and in the same order.

The reference below is the estimate as built before that plan, every value through
``Tracker._withheld`` (the rules themselves, unchanged); both run on the same tracker (a real
fit's linearisation of the paper's finger, sphere and cylinder) with its numbers, frame
counts, excess, widening and base drawn across the rules' thresholds: values around zero and
the radius's bounds, sigmas around each relative limit, the position's and the angle's,
non-finite variances, values the core marks absent, bases with values withheld for soft and
hard reasons, flat radii, keys missing.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.linearize import linearize
from tactiled.fit.params import (MAX_ANGLE_SIGMA, RADIUS_LIMITS, TOO_LIGHT,
                                 UNOBSERVABLE_RELATIVE_SIGMA, VALUE_KEYS, radius_tied_force,
                                 wrap_deg)
from tactiled.fit.profile import FLAT, FLAT_ACROSS, TEST_RELATIVE_SIGMA
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
from tactiled.pipeline import contact_filter as cf
from tactiled.pipeline.contact_filter import OFF_ARRAY_MM, Tracker
from tactiled.pipeline.fit_sigmas import beyond_tested, kept_by_limits, runaway_radius
from tactiled.sensors.model import NoiseModel, SensorModel


def reference(tr: Tracker, base: dict[str, Any], numbers: list[float], var: list[float],
              cov_rf: float, absent: int, rate: list[float], pvv: list[float]) -> dict[str, Any]:
    """The estimate value by value (the body of ``estimate_from`` before its per-base plan)."""
    values: dict[str, Any] = dict(zip(VALUE_KEYS, numbers))
    for i, key in enumerate(VALUE_KEYS):
        if absent >> i & 1:
            values[key] = None
    if values["angle_deg"] is not None:
        values["angle_deg"] = wrap_deg(values["angle_deg"])
    i_f, i_r = VALUE_KEYS.index("force_n"), VALUE_KEYS.index("r1_mm")
    out = dict(base)
    reasons0 = base.get("reasons") or {}
    why = [str(reasons0.get(k, "")).startswith(cf._SOFT)
           and FLAT_ACROSS not in str(reasons0.get(k, "")) for k in VALUE_KEYS]
    soft = [base.get(k) is not None or w for k, w in zip(VALUE_KEYS, why)]
    base_std = base.get("std") or {}
    flat = [FLAT in str(reasons0.get(k, "")) or (
        k in ("r1_mm", "r2_mm") and beyond_tested(base.get(k), base_std.get(k)))
        for k in VALUE_KEYS]
    reasons = dict(reasons0)
    std: dict[str, Any] = {}
    for i, key in enumerate(VALUE_KEYS):
        v = values[key]
        if not soft[i] or v is None or not math.isfinite(var[i]):
            out[key] = base.get(key)
            std[key] = base_std.get(key)
            continue
        sd_i = math.sqrt(var[i]) * tr._widen[i]
        withheld = tr._withheld(key, v, sd_i, flat[i])
        tied = None
        if not withheld and key == "force_n" and math.isfinite(var[i_r]) and math.isfinite(cov_rf):
            r1, sd_r = values.get("r1_mm"), math.sqrt(var[i_r])
            unresolved = (soft[i_r] and r1 is not None
                          and tr._withheld("r1_mm", r1, sd_r, flat[i_r]) is not None)
            if unresolved or radius_tied_force(r1, sd_r, sd_i, cov_rf) is not None:
                f0, sd0 = base.get(key), base_std.get(key)
                rel0 = sd0 / f0 if f0 and sd0 and f0 > 0.0 else 0.0
                sd_i = max(math.sqrt(sd_i * sd_i + v * v * tr.excess * tr._radius_share()),
                           v * rel0)
                withheld = tr._withheld(key, v, sd_i) or runaway_radius(r1)
                tied = (f"poorly determined ({TOO_LIGHT}: the force rests on a radius the "
                        f"frames do not resolve: its sigma holds one frame's uncertainty "
                        f"of that radius, {100 * sd_i / v:.0f} % of it)")
        if withheld:
            out[key], std[key] = None, None
            reasons[key] = withheld
            continue
        out[key], std[key] = v, sd_i
        if tied is not None:
            reasons[key] = tied
        elif why[i] and tr._widen[i] <= 1.0:
            del reasons[key]
    rates: dict[str, Any] = dict.fromkeys(cf.RATE_KEYS)
    sds: dict[str, Any] = dict.fromkeys(cf.RATE_KEYS)
    if tr.n < cf.MIN_RATE_FRAMES:
        for _, key, _ in tr._rate_of:
            reasons[key] = f"the contact changed {tr.n} frame(s) ago: too few frames for a rate"
    else:
        for i, key, name in tr._rate_of:
            scale = (180.0 / math.pi if name == "psi"
                     else (values["force_n"] or 0.0) if name == "ln_f" else 1.0)
            rates[key] = rate[i] * scale
            sds[key] = math.sqrt(max(pvv[i] * tr.excess, 0.0)) * abs(scale)
    if tr.model == "sphere":
        reasons["angle_rate_deg_s"] = "undefined: sphere model"
    out.update(rates)
    std.update(sds)
    out["std"], out["reasons"], out["frames_used"] = std, reasons, tr.n
    return out


@pytest.fixture(scope="module", params=["sphere", "cylinder"])
def tracked(request) -> tuple[Tracker, dict[str, Any]]:
    """A tracker holding a real fit's linearisation (the fit's dict: the base it rests on)."""
    sensor = SensorModel(noise=NoiseModel(sigma=0.0005))
    fitter = Fitter(sensor, FitOptions(withhold_relative_sigma=0.5))
    truth = Contact(r1=6.0, r2=6.0 if request.param == "sphere" else math.inf, psi_deg=60.0,
                    force=0.8, x0=8.0, y0=9.0)
    s = StrainModel(sensor).predict(truth) + np.random.default_rng(3).normal(0, 5e-4, (8, 8))
    res = fitter.fit(s, request.param)
    tr = Tracker(withhold_relative_sigma=0.5)
    tr.adopt(linearize(fitter, s, res.model, np.array(res.params)))
    tr.step(s.ravel(), 0.0, fitted=True)
    return tr, res.to_json_dict()


_odd = st.sampled_from([0.0, -1.0, math.inf, math.nan])
_values = st.tuples(st.floats(-2.0, 20.0), st.floats(-2.0, 20.0), st.one_of(
    st.floats(-0.5, 5.0), _odd), st.one_of(st.floats(-1.0, 1.5 * RADIUS_LIMITS[1]), _odd,
    st.sampled_from([RADIUS_LIMITS[0] * 0.999, RADIUS_LIMITS[0], RADIUS_LIMITS[1],
                     RADIUS_LIMITS[1] * 1.001])), st.one_of(st.floats(0.1, 500.0), _odd),
    st.floats(-400.0, 400.0))
#: a sigma drawn near a limit of its value's (relative, absolute) or anywhere
_rel = st.one_of(st.floats(0.0, 12.0), st.sampled_from(
    [0.5, 0.5000001, TEST_RELATIVE_SIGMA, UNOBSERVABLE_RELATIVE_SIGMA,
     UNOBSERVABLE_RELATIVE_SIGMA * 1.0000001]))
_soft = st.sampled_from(["", f"{TOO_LIGHT}: its sigma is 80 % of it", "poorly determined",
                         f"{TOO_LIGHT}: {FLAT}", f"orientation not observable: {FLAT_ACROSS}",
                         "not a measurement: a radius of -1"])


@st.composite
def frames(draw: st.DrawFn, base0: dict[str, Any]) -> tuple:
    numbers = list(draw(_values))
    var = []
    for i, v in enumerate(numbers):
        if i < 2:
            sd = draw(st.one_of(st.floats(0.0, 8.0), st.just(OFF_ARRAY_MM)))
        elif i == 5:
            sd = draw(st.one_of(st.floats(0.0, 40.0), st.just(MAX_ANGLE_SIGMA)))
        else:
            sd = draw(_rel) * abs(v) if math.isfinite(v) else draw(st.floats(0.0, 3.0))
        var.append(draw(st.one_of(st.just(sd * sd), _odd.filter(lambda x: x != -1.0))))
    base = dict(base0)
    base["std"] = dict(base0.get("std") or {})
    base["reasons"] = dict(base0.get("reasons") or {})
    for key in draw(st.lists(st.sampled_from(VALUE_KEYS), max_size=3, unique=True)):
        kind = draw(st.sampled_from(["withheld", "value", "missing"]))
        if kind == "withheld":
            base[key] = None
            base["reasons"][key] = draw(_soft)
        elif kind == "value":
            base[key] = draw(st.floats(0.01, 30.0))
            base["std"][key] = draw(st.one_of(st.none(), st.floats(0.0, 20.0)))
        else:
            del base[key]
    k = len(numbers)  # (the rates: one per parameter, as many as any model has)
    rate = draw(st.lists(st.floats(-50.0, 50.0), min_size=k, max_size=k))
    pvv = draw(st.lists(st.floats(-1.0, 10.0), min_size=k, max_size=k))
    return (base, numbers, var, draw(st.floats(-2.0, 2.0)), draw(st.integers(0, 63)), rate, pvv,
            draw(st.integers(1, 6)), draw(st.sampled_from([1.0, 2.5])),
            draw(st.sampled_from([None, 0.5, 0.2])),
            [draw(st.sampled_from([1.0, 1.3])) for _ in VALUE_KEYS])


@settings(max_examples=300, deadline=None)
@given(data=st.data())
def test_the_planned_estimate_is_the_rules_estimate(tracked, data) -> None:
    tr, fit = tracked
    base, numbers, var, cov_rf, absent, rate, pvv, n, excess, withhold, widen = data.draw(
        frames(fit))
    tr.n, tr.excess, tr.withhold, tr._widen = n, excess, withhold, widen
    args = (base, numbers, var, cov_rf, absent, rate, pvv)
    want, got = _outcome(reference, tr, *args), _outcome(Tracker.estimate_from, tr, *args)
    assert got == want
    # the plan is kept per base: the same base's next frame is built from it again
    assert _outcome(Tracker.estimate_from, tr, *args) == want


def _outcome(build: Any, *args: Any) -> str:
    """The estimate's JSON text, or the error it raises (a force of zero tied to its radius
    divides by it, in both)."""
    try:
        return json.dumps(build(*args))
    except ArithmeticError as e:
        return type(e).__name__


@settings(max_examples=300, deadline=None)
@given(data=st.data())
def test_a_value_kept_by_its_limits_is_one_the_rules_keep(tracked, data) -> None:
    """``kept_by_limits`` answers only where ``Tracker._withheld`` answers None."""
    tr, fit = tracked
    base = data.draw(frames(fit))[0]
    tr.withhold = data.draw(st.sampled_from([None, 0.5, 0.2]))
    judged = tr._judged(base)
    flat, lims = judged[4], judged[-1]
    i = data.draw(st.integers(0, len(VALUE_KEYS) - 1))
    v = data.draw(_values)[i]
    sd = data.draw(st.one_of(st.floats(0.0, 50.0), _odd, st.sampled_from(
        [OFF_ARRAY_MM, MAX_ANGLE_SIGMA, 0.5 * abs(v) if math.isfinite(v) else 1.0])))
    if kept_by_limits(i, v, sd, lims[i]):
        assert tr._withheld(VALUE_KEYS[i], v, sd, flat[i]) is None

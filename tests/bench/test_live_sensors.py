"""``tactiled bench --suite sensors``'s live part: the daemon's own estimates of the demo scene
on a coarse pad (XELA 4x4: without the gate's carry limit one fit was reused for 220 frames
while the cylinder rolled), through the whole daemon with real worker processes, scored
against the simulator's truth (benchmarks/tactiled_bench/live_sensors.py).

Bars: no value bit-identical for more than ``MAX_CARRIED`` + 1 estimates while its contact
moves; no estimate listing a second contact on a pad touched once; at least 85 % of the
published values within 2 of their sigmas; the share of estimates with a value beyond 4
sigma under 5 % on the XELA 4x4 pad and, the live bar, under 1 % on the paper's finger and
the XELA 4x6 pad and, on its second noise draw, the XELA 4x4 pad (every built-in
description on seeds 1-3: ``-m slow``, about 4 minutes), with nothing stale.
"""

from __future__ import annotations

import math

import pytest

from tactiled_bench import live_sensors
from tactiled.fit.params import VALUE_KEYS
from tactiled.fit.verdict import ArrayLimits, ellipse_of
from tactiled.pipeline.gate import MAX_CARRIED
from tactiled.sensors import builtin_names, load_description


def test_the_daemon_on_a_coarse_pad_against_the_truth() -> None:
    desc = load_description("xela_uskin_4x4")
    s = live_sensors.score(desc, rate=100.0, seed=1)
    c = s["counts"]
    assert c["contact_estimates"] >= 1000, c
    assert c["phantom"] == 0, c
    assert max(s["stale"].values()) <= MAX_CARRIED + 1, s["stale"]
    published = sum(s["n"].values()) - sum(s["withheld"].values())
    assert published >= 2000
    assert sum(s["covered"].values()) >= 0.85 * published
    assert c["with_far"] <= 0.05 * c["contact_estimates"], c
    lines = live_sensors.report(desc, s, 100.0)
    assert any(line.startswith("| offset |") for line in lines)
    # the ball's force is resolved by the whole pad's bound at the truth in most frames (its
    # radius in none): what is withheld of it is scored against that
    assert s["resolved"]["force_n"] >= 0.5 * s["n"]["force_n"] > 0, s["resolved"]
    assert s["resolved"]["r1_mm"] == 0
    assert s["resolved_withheld"]["force_n"] <= s["withheld"]["force_n"]
    # ... and withheld in at most 10 % of those (the bar; 52 % when the tracker withheld
    # a force resting on a radius it withholds, now published with that radius's uncertainty)
    assert s["resolved_withheld"]["force_n"] <= 0.1 * s["resolved"]["force_n"], s["resolved_withheld"]
    force = next(line for line in lines if line.startswith("| force_n |")).split(" | ")
    assert force[5].endswith(f"({s['resolved']['force_n']})")


def test_the_daemons_tracked_radii_on_a_coarse_pad_stay_within_their_sigmas() -> None:
    """XELA 4x6 (4.7 mm pitch): a light ball's first frames give a radius at 20-40 times the
    truth with a sigma of about half of it (a likelihood not quadratic there), and the
    tracker, pooling linearised frames from that point, published radii 5-7 of its sigmas
    from the truth.  A tracked radius is published only once its frames bring its sigma
    within the range where the profile test vouches for a linearised sigma (10 %); none
    published lies beyond 4 sigma of the simulator's truth."""
    desc = load_description("xela_uskin_4x6")
    estimates = live_sensors.play(desc, 100.0, seed=1)
    true = live_sensors.truth(desc, 100.0, max(t for t, _ in estimates) + 1)
    tracked, held, far = 0, 0, []
    for tick, fit in estimates:
        if not (fit.get("contact") and true[tick]) or (fit.get("frames_used") or 0) < 2:
            continue
        c = true[tick][0]
        r, sd = fit.get("r1_mm"), (fit.get("std") or {}).get("r1_mm")
        if math.isinf(c.r2):  # a line's radius comes from a fit, not the tracker
            continue
        if r is None:
            held += "over" in str(fit["reasons"].get("r1_mm"))  # "... over N frame(s) is X %"
            continue
        tracked += 1
        assert sd <= 0.1 * r + 1e-12 or "carried" in fit["reasons"], (tick, r, sd)
        if abs(r - c.r1) > 4.0 * sd:
            far.append((tick, r, sd, c.r1))
    assert held >= 20, held  # withheld while the frames do not resolve it
    assert not far, far


#: The live bar: no more than this share of a description's contact estimates carries a value
#: beyond ``live_sensors.FAR_SIGMAS`` of its sigma from the simulator's truth.
LIVE_BAR = 0.01
#: Descriptions whose simulated finger the daemon does not yet keep within the bar (what is
#: left there: docs/performance/fit-time.md)
_NOT_YET: dict[str, str] = {}
#: The share of the values other than the radius a description may withhold (below): 25 %,
#: but on the 12x32 mat, where the demo's line (1 N at about 4 noise sigmas) is fitted on the
#: band of tactels that see it above the noise, a piece of it, and its orientation and place
#: are withheld where their profile likelihood is flat (28-46 % of the line's estimates on
#: seeds 1-3; docs/concepts/uncertainty.md)
WITHHELD_BAR = {"flexitac_12x32": 0.5}


def _live_bar(s: dict, name: str = "") -> None:
    c = s["counts"]
    assert c["contact_estimates"] >= 1000, c
    assert c["phantom"] == 0, c
    assert max(s["stale"].values()) <= MAX_CARRIED + 1, s["stale"]
    assert c["with_far"] <= LIVE_BAR * c["contact_estimates"], (c, s["far"])
    # withholding is not how the bar is met: at most 25 % of the values other than the
    # radius (the demo's line is 10 mm at 1 N and its ball 8 mm at up to 1.5 N, radii the
    # coarse and flat descriptions do not resolve: docs/concepts/uncertainty.md)
    held = sum(v for k, v in s["withheld"].items() if k != "r1_mm")
    bar = WITHHELD_BAR.get(name, 0.25)
    assert held <= bar * sum(v for k, v in s["n"].items() if k != "r1_mm"), s["withheld"]


def _nothing_stale(desc, estimates: list) -> tuple[int, int]:
    """Every published estimate of a contact says how old its values are (``frames_used``; a
    reused one its fit's frame and ``reasons["carried"]``), and its ellipse is the one its
    published values give for that frame (null with a reason where they give none).  Returns
    how many were carried and how many ellipses were compared."""
    limits = ArrayLimits.of(desc.sensor_model())
    carried = checked = 0
    for _, fit in estimates:
        if not fit.get("contact"):
            continue
        assert (fit.get("frames_used") or 0) >= 1, fit
        why = fit["reasons"].get("carried")
        if why is not None:
            carried += 1
            assert "frame(s) earlier" in why and fit["frames_used"] == 1, fit
        if fit.get("label") == "line" or fit.get("line") is not None:
            continue
        want = ellipse_of({k: fit.get(k) for k in VALUE_KEYS}, limits)
        if want is None:
            assert fit.get("ellipse") is None and fit["reasons"].get("ellipse"), fit
        else:
            checked += 1
            got = fit["ellipse"]
            for key in ("a_mm", "b_mm", "theta_deg"):
                assert got[key] == pytest.approx(want[key], rel=1e-9, abs=1e-9), (got, want)
    return carried, checked


def test_no_stale_and_no_confident_wrong_value_live_on_a_coarse_pad() -> None:
    """XELA 4x6 (4.7 mm pitch): a light ball first fitted as a plane (the tracker then held its
    curvature and published forces 4-8 sigmas low), a weak line reused for frames it moved in
    (its angle and place carried beyond 4 sigmas).  Through the daemon, against the truth:
    within the live bar, and nothing stale."""
    desc = load_description("xela_uskin_4x6")
    estimates = live_sensors.play(desc, 100.0, seed=1)
    _live_bar(live_sensors.score(desc, 100.0, 1, estimates))
    carried, _ = _nothing_stale(desc, estimates)
    assert carried >= 50, carried


def test_the_live_bar_on_the_papers_finger() -> None:
    """The paper's finger (tracked cylinders and spheres, each with its Hertz ellipse):
    within the live bar, and every ellipse the one its tracked values give."""
    desc = load_description("fearing1988")
    estimates = live_sensors.play(desc, 100.0, seed=1)
    _live_bar(live_sensors.score(desc, 100.0, 1, estimates))
    _, checked = _nothing_stale(desc, estimates)
    assert checked >= 500, checked


def _tracked_far(desc, estimates: list, key: str) -> tuple[list[tuple], int]:
    """The estimates of a ball resting on two or more frames whose ``key`` lies beyond
    ``FAR_SIGMAS`` of its sigma from the simulator's truth (``(tick, value, sigma, truth)``),
    and how many such estimates published ``key``."""
    true = live_sensors.truth(desc, 100.0, max(t for t, _ in estimates) + 1)
    far, n = [], 0
    for tick, fit in estimates:
        if not (fit.get("contact") and true[tick]) or (fit.get("frames_used") or 0) < 2:
            continue
        c, v, sd = true[tick][0], fit.get(key), (fit.get("std") or {}).get(key)
        if math.isinf(c.r2) or v is None:
            continue
        t = c.force if key == "force_n" else c.r1
        n += 1
        if abs(v - t) > live_sensors.FAR_SIGMAS * sd:
            far.append((tick, v, sd, t))
    return far, n


def test_a_light_balls_tracked_force_on_a_coarse_pad_carries_its_radiuss_uncertainty() -> None:
    """XELA 4x4 (4.7 mm pitch), second noise draw: an 8 mm ball pressed from 0.2 to 1.5 N is
    fitted at 30-300 mm, a radius the frames do not resolve, and the filter, relinearised
    wherever its state drifts along that valley, measured the force 20-30 % low with the
    sigma of a point (10 estimates 4.6-8.7 sigmas off), the linearised share of its variance
    that is the radius's swinging 0.0-0.9 from one frame to the next.  A tracked force resting
    on a radius the tracker withholds is published with the radius's part of one frame's
    variance and at least its fit's relative sigma: published (withheld in 52 % of the frames
    whose bound resolves it when such a force went with its radius), at most one beyond 4 sigma
    (a filter's third frame run off to a radius of 180 m), and the live bar."""
    desc = load_description("xela_uskin_4x4")
    estimates = live_sensors.play(desc, 100.0, seed=2)
    far, n = _tracked_far(desc, estimates, "force_n")
    assert n >= 150 and len(far) <= 1, (n, far)
    s = live_sensors.score(desc, 100.0, 2, estimates)
    assert s["resolved_withheld"]["force_n"] <= 0.1 * s["resolved"]["force_n"], s["resolved_withheld"]
    _live_bar(s)


def test_a_release_is_followed_without_a_confident_lag() -> None:
    """The 12x32 mat (flexitac): the ball's release (1.5 N to nothing in 0.25 s, the log
    force falling ever faster) left the constant-velocity filter 0.1-0.3 behind in log
    force with a sigma of 0.02-0.03 (9 forces 4.5-5.8 sigmas high).  The innovations' run to
    one side now goes into the rate's variance, so the filter catches up, and into the
    published force's, so it says so: at most 2 % of the ball's tracked forces beyond 4 sigma
    of the truth (5 % before; 1 of 177 here now, a press's single frame)."""
    desc = load_description("flexitac_12x32")
    estimates = live_sensors.play(desc, 100.0, seed=1)
    far, n = _tracked_far(desc, estimates, "force_n")
    assert n >= 100 and len(far) <= 0.02 * n, (n, far)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("name", [
    pytest.param(n, marks=pytest.mark.xfail(strict=True, reason=_NOT_YET[n])) if n in _NOT_YET
    else n for n in builtin_names()])
def test_the_live_bar_on_every_builtin_description(name: str, seed: int) -> None:
    _live_bar(live_sensors.score(load_description(name), 100.0, seed), name)


def _ellipsoid(r1: float, r2: float, force: float):
    """A scene of one ellipsoid (radii ``r1``, ``r2`` mm) at the array's centre: pressed to
    ``force`` N at 30 deg, held, turned to 90 deg, held, released."""
    from tactiled.sim import Pose, SceneBuilder

    def scene(g):
        xc, yc = 0.5 * (g.rows - 1) * g.dx, 0.5 * (g.cols - 1) * g.dy
        return (SceneBuilder(Pose(r1=r1, r2=r2, psi_deg=30.0, x0=xc, y0=yc)).idle(0.3)
                .press(0.3, force=force).hold(0.6).rotate(0.6, psi_deg=90.0).hold(0.3)
                .release(0.3).idle(0.3).build("ellipsoid"))
    return scene


def _ellipse_scores(desc, estimates: list) -> dict[str, list[int]]:
    """Per value of a general contact: [estimates, withheld, within 2 sigma, beyond 4 sigma,
    published with a sigma its fit's profile widened] against the simulator's truth."""
    true = live_sensors.truth(desc, 100.0, max(t for t, _ in estimates) + 1, scene="ellipsoid")
    out: dict[str, list[int]] = {}
    for tick, fit in estimates:
        if not (fit.get("contact") and true[tick]):
            continue
        c = true[tick][0]
        for key, t in (("r1_mm", c.r1), ("r2_mm", c.r2), ("angle_deg", c.psi_deg),
                       ("force_n", c.force)):
            v, sd = fit.get(key), (fit.get("std") or {}).get(key)
            row = out.setdefault(key, [0, 0, 0, 0, 0])
            row[0] += 1
            if v is None:
                row[1] += 1
                continue
            err = (v - t + 90.0) % 180.0 - 90.0 if key == "angle_deg" else v - t
            row[2] += abs(err) <= 2.0 * sd
            row[3] += abs(err) > live_sensors.FAR_SIGMAS * sd
            row[4] += "widened" in str(fit["reasons"].get(key, ""))
    return out


@pytest.mark.slow
def test_a_live_ellipsoid_is_published_no_more_confident_than_its_fits(monkeypatch) -> None:
    """The tracker carries the sigma a fit's profile test widened (an ellipse's orientation,
    its larger radius) and does not lift an orientation the fit found flat across the
    half-turn.  On the paper's finger a 5 x 10 mm ellipsoid at 1 N: its orientation and r2
    within their sigmas, most orientations published with the fit's widened sigma.  On the
    XELA 4x6 pad a 6 x 8 mm one at 2 N, whose fits find the orientation's likelihood flat:
    the tracker lifted it and published 13 of 124 orientations beyond 4 sigma; now none.
    On the paper's finger the tracked r1 (held, averaging every frame since the filter
    started) was published 11 times of 110 beyond 4 sigma: a sphere tracked through the
    press at 9-10 mm, then the ellipse's r1 held at 6.4-6.2 mm against 5; the lag the
    held parameters' innovations show now goes into their variance (kernels.held_lag):
    at most 3 (the ellipse's, at 4.0-4.1 sigma)."""
    from tactiled.sim import SCENES

    for name, (r1, r2, force), widened in (("fearing1988", (5.0, 10.0, 1.0), True),
                                           ("xela_uskin_4x6", (6.0, 8.0, 2.0), False)):
        monkeypatch.setitem(SCENES, "ellipsoid", _ellipsoid(r1, r2, force))
        desc = load_description(name)
        s = _ellipse_scores(desc, live_sensors.play(desc, 100.0, 1, scene="ellipsoid"))
        for key in ("r2_mm", "angle_deg", "force_n"):
            n, held, within, far, _ = s[key]
            assert n >= 150 and far == 0, (name, key, s[key])
            # (coverage where enough are published to measure it)
            assert n - held < 20 or within >= 0.9 * (n - held), (name, key, s[key])
        if widened:
            assert s["angle_deg"][4] >= 100, s
            assert s["r1_mm"][3] <= 3, s["r1_mm"]

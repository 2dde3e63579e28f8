"""The ``moving`` scene against its own truth: contacts that never rest (speeds, turn rates,
force ramps), three indentors in turn with brief lift-offs between them, a clean loop, and
deterministic frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled.sensors.model import Geometry
from tactiled.physics.contact import Contact
from tactiled.sim import (
    MOVING_FORCE_N,
    MOVING_SPEED_MM_S,
    MOVING_TURN_DEG_S,
    FingerSimulator,
    named_scene,
)

RATE = 1000.0  # Hz: the rate the scene is made for (segments last whole milliseconds)
EPS = 1e-6


def kind(c: Contact) -> str:
    """cylinder, sphere or edge, as the scene's truth makes them."""
    if c.r1 == pytest.approx(c.r2):
        return "sphere"
    assert math.isinf(c.r2), c
    return "edge" if c.r1 < 1.0 else "cylinder"


@pytest.fixture(scope="module")
def ticks() -> list[tuple[float, Contact | None]]:
    """One pass of the scene's truth at 1 kHz, as the simulated finger plays it (plus the
    first tick of the next pass)."""
    sim = FingerSimulator(scene="moving", rate_hz=RATE)
    return [(sim.scene_time(k), sim.scene.contact_at(sim.scene_time(k)))
            for k in range(sim.ticks_per_pass + 1)]


def touching_pairs(ticks):
    return [(a, b) for (_, a), (_, b) in zip(ticks, ticks[1:]) if a is not None and b is not None]


def test_contacts_never_rest_and_roll_at_20_to_100_mm_s(ticks) -> None:
    speeds = [math.hypot(b.x0 - a.x0, b.y0 - a.y0) * RATE for a, b in touching_pairs(ticks)]
    assert len(speeds) > 0.75 * len(ticks)  # touching most of the time
    lo, hi = MOVING_SPEED_MM_S
    assert min(speeds) >= lo - EPS and max(speeds) <= hi + EPS
    # the whole range is used, not just its ends
    assert min(speeds) == pytest.approx(lo, abs=0.01) and max(speeds) == pytest.approx(hi, abs=0.01)
    assert any(45 < v < 85 for v in speeds)


def test_turns_at_up_to_180_deg_s(ticks) -> None:
    turns = [abs(b.psi_deg - a.psi_deg) * RATE for a, b in touching_pairs(ticks)
             if kind(a) != "sphere" and kind(a) == kind(b)]
    turns = [min(t, 180.0 * RATE - t) for t in turns]  # psi folds at 180
    assert max(turns) <= MOVING_TURN_DEG_S + EPS
    assert max(turns) == pytest.approx(MOVING_TURN_DEG_S, abs=0.01)
    # both turning indentors turn, through at least 90 degrees each
    for which in ("cylinder", "edge"):
        psis = [c.psi_deg for _, c in ticks if c is not None and kind(c) == which]
        assert max(psis) - min(psis) >= 90.0 - EPS, which


def test_force_ramps_within_0_3_to_2_n_between_touch_down_and_lift_off() -> None:
    scene = named_scene("moving")
    lo, hi = MOVING_FORCE_N
    ramps = []
    for seg in scene.segments:
        if seg.kind in ("approach", "idle"):
            continue
        assert seg.ease == "linear", seg  # constant rates: nothing eases to rest
        if seg.kind == "press":
            assert seg.start.force == 0.0 and lo <= seg.end.force <= hi
        elif seg.kind == "release":
            assert seg.end.force == 0.0 and lo <= seg.start.force <= hi
        else:
            assert lo <= seg.start.force <= hi and lo <= seg.end.force <= hi
            ramps.append(abs(seg.end.force - seg.start.force) / seg.duration)
    forces = [f for seg in scene.segments if seg.kind not in ("approach", "idle", "press", "release")
              for f in (seg.start.force, seg.end.force)]
    assert min(forces) == pytest.approx(lo) and max(forces) == pytest.approx(hi)
    assert min(ramps) > 0.5  # N/s: the force always changes too
    # touch-down and lift-off happen while rolling (speeds checked above), never at rest
    for seg in scene.segments:
        if seg.kind in ("press", "release"):
            assert (seg.start.x0, seg.start.y0) != (seg.end.x0, seg.end.y0)


def test_cylinder_then_sphere_then_edge_with_brief_lift_offs(ticks) -> None:
    kinds: list[str] = []
    runs: list[int] = []  # lengths of the untouched spells, in ticks
    gap = 0
    for _, c in ticks:
        if c is None:
            gap += 1
            continue
        if gap and kinds:
            runs.append(gap)
        gap = 0
        if not kinds or kinds[-1] != kind(c):
            assert not kinds or runs, "the indentor changed without a lift-off"
            kinds.append(kind(c))
    assert kinds == ["cylinder", "sphere", "edge"]
    assert len(runs) == 2  # the lift-offs inside the pass; the third is across the loop
    for n in runs:
        assert 0.09 <= n / RATE <= 0.12  # ~0.1 s in the air
    # across the loop: 0.65 s untouched, for the zeroer (an idle and the last approach)
    lead = next(i for i, (_, c) in enumerate(ticks) if c is not None)
    trail = next(i for i, (_, c) in enumerate(reversed(ticks[:-1])) if c is not None)
    assert 0.64 <= (lead + trail) / RATE <= 0.67
    spheres = [c for _, c in ticks if c is not None and kind(c) == "sphere"]
    edges = [c for _, c in ticks if c is not None and kind(c) == "edge"]
    assert {c.r1 for c in spheres} == {8.0} and {c.r1 for c in edges} == {0.5}


def test_stays_on_the_array(ticks) -> None:
    g = Geometry()
    for _, c in ticks:
        if c is not None:  # a tactel pitch and more inside the array's edge
            assert g.dx <= c.x0 <= g.span_x - g.dx and g.dy <= c.y0 <= g.span_y - g.dy


def test_loops_cleanly(ticks) -> None:
    scene = named_scene("moving")
    assert scene.segments[0].start == scene.segments[-1].end
    assert ticks[0][1] is None and ticks[-2][1] is None  # untouched at both ends
    assert ticks[-1][0] == 0.0  # the next pass starts over
    sim = FingerSimulator(scene="moving", rate_hz=RATE, noise=0.0, drift=None, hysteresis=None)
    assert sim.ticks_per_pass == round(scene.duration * RATE) == 5450
    first = [sim.step().contact for _ in range(sim.ticks_per_pass)]
    again = [sim.step().contact for _ in range(200)]
    assert again == first[:200]


def test_deterministic_frames_by_seed() -> None:
    def counts(seed: int) -> list[np.ndarray]:
        sim = FingerSimulator(scene="moving", seed=seed, rate_hz=RATE)
        sim.skip(700)  # into the first roll
        return [sim.step().counts for _ in range(50)]

    a, b, c = counts(5), counts(5), counts(6)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not all(np.array_equal(x, y) for x, y in zip(a, c))
    # every frame of a moving contact needs a new strain prediction
    sim = FingerSimulator(scene="moving", seed=1, rate_hz=RATE)
    sim.skip(600)
    for _ in range(100):
        sim.step()
    assert sim.predictions == 100


def test_available_by_name_in_simulate_and_sim_urls() -> None:
    from tactiled.sim import SCENES, scene_from_spec

    assert "moving" in SCENES and scene_from_spec("Moving").name == "moving"
    small = Geometry(rows=4, cols=4)
    c = named_scene("moving", small).contact_at(0.7)
    assert 0 < c.x0 < small.span_x and 0 < c.y0 < small.span_y

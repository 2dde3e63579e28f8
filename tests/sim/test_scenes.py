"""Scenes: segment interpolation, the builder and the built-in scenes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled.sensors.model import Geometry
from tactiled.physics.contact import Contact
from tactiled.sim import (SCENES, MultiScene, Pose, Scene, SceneBuilder, Segment, named_scene,
                          scene_from_spec)

CENTRE = (Geometry().span_x / 2, Geometry().span_y / 2)


def test_linear_and_smooth_interpolation() -> None:
    a = Pose(r1=10.0, psi_deg=30.0, force=0.5, x0=2.0, y0=4.0)
    b = Pose(r1=10.0, psi_deg=150.0, force=1.5, x0=12.0, y0=8.0)
    lin = Segment("rotate", 2.0, a, b, "linear")
    mid = lin.pose_at(1.0)
    assert mid.psi_deg == pytest.approx(90.0)
    assert mid.force == pytest.approx(1.0) and mid.x0 == pytest.approx(7.0)
    assert lin.pose_at(0.5).psi_deg == pytest.approx(60.0)  # constant speed
    smooth = Segment("rotate", 2.0, a, b, "smooth")
    assert smooth.pose_at(1.0).psi_deg == pytest.approx(90.0)  # symmetric about the middle
    # smoothstep(0.25) = 0.15625: slower than linear near the ends
    assert smooth.pose_at(0.5).psi_deg == pytest.approx(30.0 + 120.0 * 0.15625)
    assert smooth.pose_at(-1.0) == a and smooth.pose_at(5.0).psi_deg == pytest.approx(150.0)


def test_radii_interpolate_as_curvatures() -> None:
    cyl = Pose(r1=10.0, r2=math.inf, force=1.0)
    sph = Pose(r1=5.0, r2=5.0, force=1.0)
    seg = Segment("press", 1.0, cyl, sph, "linear")
    mid = seg.pose_at(0.5)
    assert 1.0 / mid.r1 == pytest.approx(0.5 * (0.1 + 0.2))
    assert 1.0 / mid.r2 == pytest.approx(0.5 * 0.2)
    assert mid.r1 <= mid.r2
    assert seg.pose_at(0.0).r2 == math.inf


def test_zero_force_is_no_contact_and_psi_folds() -> None:
    assert Pose(force=0.0).contact() is None
    c = Pose(r1=3.0, psi_deg=200.0, force=0.2, x0=1.0, y0=2.0).contact()
    assert c == Contact(3.0, math.inf, 20.0, 0.2, 1.0, 2.0)


def test_segment_validation() -> None:
    with pytest.raises(ValueError, match="kind"):
        Segment("jump", 1.0, Pose(), Pose())
    with pytest.raises(ValueError, match="duration"):
        Segment("hold", 0.0, Pose(), Pose())
    with pytest.raises(ValueError, match="must not touch"):
        Segment("idle", 1.0, Pose(force=1.0), Pose(force=1.0))
    with pytest.raises(ValueError, match="r2"):
        Pose(r1=5.0, r2=4.0)
    with pytest.raises(ValueError, match="force"):
        Pose(force=-1.0)


def test_builder_chains_poses_and_times() -> None:
    scene = (SceneBuilder(Pose(r1=10.0, x0=5.0, y0=10.0))
             .idle(0.5).press(0.5, force=1.0).roll(1.0, x0=15.0).hold(1.0).release(0.5)
             .build("t"))
    assert scene.duration == pytest.approx(3.5)
    assert [s.kind for s in scene.segments] == ["idle", "press", "roll", "hold", "release"]
    assert scene.contact_at(0.25) is None
    assert scene.contact_at(1.0).force == pytest.approx(1.0)
    assert scene.contact_at(1.5).x0 == pytest.approx(10.0)  # roll is linear
    assert scene.contact_at(2.5).x0 == pytest.approx(15.0)
    assert scene.contact_at(3.5) is None and scene.contact_at(100.0) is None
    # Each segment starts where the previous one ended.
    for prev, seg in zip(scene.segments, scene.segments[1:]):
        assert seg.start == prev.end


def test_hold_repeats_one_contact_exactly() -> None:
    scene = named_scene("hold")
    contacts = {scene.contact_at(t) for t in np.linspace(2.0, 300.0, 50)}
    assert len(contacts) == 1  # identical, so the simulator's prediction cache always hits
    (c,) = contacts
    assert c.force == pytest.approx(1.0) and (c.x0, c.y0) == pytest.approx(CENTRE)
    assert scene.duration > 290.0


def test_empty_scene_never_touches() -> None:
    scene = named_scene("empty")
    assert all(scene.contact_at(t) is None for t in np.linspace(-1, 5, 61))


def test_press_scene() -> None:
    scene = named_scene("press")
    assert scene.contact_at(0.1) is None
    c = scene.contact_at(1.5)
    assert c is not None and c.force == pytest.approx(1.0) and c.r1 == 10.0
    assert scene.contact_at(scene.duration - 0.01) is None


def test_demo_scene_shows_everything_promised() -> None:
    scene = named_scene("demo")
    kinds = {s.kind for s in scene.segments}
    assert kinds == {"approach", "press", "roll", "rotate", "hold", "release", "idle"}
    ts = np.arange(0.0, scene.duration, 0.01)
    contacts = [scene.contact_at(t) for t in ts]
    touching = [c for c in contacts if c is not None]
    cylinders = [c for c in touching if math.isinf(c.r2) and c.r1 == pytest.approx(10.0)]
    xs = [c.x0 for c in cylinders]
    assert max(xs) - min(xs) > 0.4 * Geometry().span_x  # rolled along x
    psis = [c.psi_deg for c in cylinders]
    assert min(psis) == pytest.approx(30.0, abs=0.5) and max(psis) == pytest.approx(150.0, abs=0.5)
    assert any(c.r1 == pytest.approx(c.r2) for c in touching)  # a sphere press
    assert any(c.r1 == pytest.approx(0.5) for c in touching)  # a knife-edge press
    # It loops seamlessly: untouched at both ends, in the same pose.
    assert contacts[0] is None and contacts[-1] is None
    assert scene.segments[0].start == scene.segments[-1].end


def test_named_scenes_and_specs() -> None:
    assert {"demo", "press", "hold", "empty"} <= set(SCENES)
    for name in SCENES:
        scene = scene_from_spec(name)
        assert isinstance(scene, (Scene, MultiScene)) and scene.name == name and scene.duration > 0
    assert scene_from_spec(" Press ").name == "press"
    with pytest.raises(ValueError, match="unknown scene 'nope'.*demo.*press"):
        scene_from_spec("nope")


def test_scenes_follow_the_geometry() -> None:
    small = Geometry(rows=4, cols=4)
    c = named_scene("press", small).contact_at(1.5)
    assert (c.x0, c.y0) == pytest.approx((small.span_x / 2, small.span_y / 2))

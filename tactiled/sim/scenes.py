"""Scenes: scripted indentor motions over time (approach, press, roll, rotate, hold, release,
idle) and the built-in ones (:data:`SCENES`), laid out relative to the array so they fit any
geometry.  A :class:`MultiScene` plays one scene per indentor on the same clock; the hand's six
parts (:data:`HAND_PARTS`, ``docs/performance/hand.md``) are such scenes.

Units: mm, N, degrees, seconds.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Union

import numpy as np

from tactiled.physics.contact import Contact
from tactiled.sensors.model import Geometry

#: Segment kinds.  ``approach`` and ``idle`` never touch (force 0 throughout); the others are
#: labels for what changes: ``press`` (force up), ``roll`` (x0, y0), ``rotate`` (psi),
#: ``hold`` (nothing), ``release`` (force down to 0).
SEGMENT_KINDS = ("approach", "press", "roll", "rotate", "hold", "release", "idle")
EASINGS = ("linear", "smooth")


@dataclass(frozen=True)
class Pose:
    """The indentor's state: a :class:`Contact`'s parameters, but ``force`` may be 0 (not
    touching).  Radii ``r1 <= r2`` in mm (``r2 = inf``: cylinder; ``r1 == r2``: sphere),
    ``psi_deg`` in degrees, ``force`` in N, contact centre ``(x0, y0)`` in mm."""

    r1: float = 10.0
    r2: float = math.inf
    psi_deg: float = 90.0
    force: float = 0.0
    x0: float = 0.0
    y0: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.force) and self.force >= 0):
            raise ValueError(f"force must be a finite non-negative force in N, got {self.force!r}")
        if not (math.isfinite(self.r1) and self.r1 > 0):
            raise ValueError(f"r1 must be a positive finite radius in mm, got {self.r1!r}")
        if math.isnan(self.r2) or self.r2 < self.r1:
            raise ValueError(f"r2 must be a radius >= r1 = {self.r1!r} mm (or inf), got {self.r2!r}")
        for name in ("psi_deg", "x0", "y0"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)!r}")

    def contact(self) -> Contact | None:
        """The contact this pose makes (``psi`` folded into [0, 180)), or ``None`` at zero force."""
        if self.force <= 0.0:
            return None
        return Contact(self.r1, self.r2, self.psi_deg % 180.0, self.force, self.x0, self.y0)


def _lerp_pose(a: Pose, b: Pose, s: float) -> Pose:
    """Pose a fraction ``s`` (0..1) of the way from ``a`` to ``b``.

    Radii are interpolated as curvatures (1/r), which handles ``r2 = inf`` (curvature 0) and
    keeps ``r1 <= r2`` (a convex combination keeps ``1/r1 >= 1/r2``).  ``psi`` is interpolated
    as given, so 30 -> 150 turns through 90 (write 150 -> 210 to turn the other way).
    """
    def lerp(p: float, q: float) -> float:
        return p + (q - p) * s  # exact p when p == q: a hold repeats one contact exactly

    ka = lerp(1.0 / a.r1, 1.0 / b.r1)
    kb = lerp(0.0 if math.isinf(a.r2) else 1.0 / a.r2, 0.0 if math.isinf(b.r2) else 1.0 / b.r2)
    r1 = 1.0 / ka
    r2 = math.inf if kb <= 0.0 else max(1.0 / kb, r1)  # max: rounding on a sphere
    return Pose(r1, r2, lerp(a.psi_deg, b.psi_deg), max(lerp(a.force, b.force), 0.0),
                lerp(a.x0, b.x0), lerp(a.y0, b.y0))


@dataclass(frozen=True)
class Segment:
    """One piece of a scene: ``duration`` seconds from pose ``start`` to pose ``end``.

    ``ease`` shapes the progress ``s`` of the interpolation over the segment's time fraction
    ``u``: ``"linear"`` (``s = u``, constant speed) or ``"smooth"`` (``s = 3u^2 - 2u^3``, zero
    speed at both ends, as a hand or a robot accelerates and stops).
    """

    kind: str
    duration: float
    start: Pose
    end: Pose
    ease: str = "smooth"

    def __post_init__(self) -> None:
        if self.kind not in SEGMENT_KINDS:
            raise ValueError(f"segment kind must be one of {', '.join(SEGMENT_KINDS)}, got {self.kind!r}")
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"{self.kind}: duration must be a positive time in s, got {self.duration!r}")
        if self.ease not in EASINGS:
            raise ValueError(f"{self.kind}: ease must be one of {', '.join(EASINGS)}, got {self.ease!r}")
        if self.kind in ("approach", "idle") and (self.start.force > 0 or self.end.force > 0):
            raise ValueError(f"{self.kind}: the indentor must not touch (force 0), got "
                             f"{self.start.force!r} -> {self.end.force!r} N")

    def pose_at(self, t: float) -> Pose:
        """Pose ``t`` seconds into the segment (clamped to ``[0, duration]``)."""
        if self.start == self.end:
            return self.start
        u = min(max(t / self.duration, 0.0), 1.0)
        s = u if self.ease == "linear" else u * u * (3.0 - 2.0 * u)
        return _lerp_pose(self.start, self.end, s)


class Scene:
    """A script of segments played back to back; ``contact_at(t)`` is the true contact.

    Times before 0 give the first pose, times after :attr:`duration` the last (looping is the
    player's business: :class:`FingerSimulator` wraps time when asked to).
    """

    def __init__(self, segments: Sequence[Segment], name: str = "") -> None:
        if not segments:
            raise ValueError("a scene needs at least one segment")
        self.segments: tuple[Segment, ...] = tuple(segments)
        self.name = name
        ends = np.cumsum([seg.duration for seg in self.segments])
        self._starts = [0.0] + [float(e) for e in ends[:-1]]
        self.duration: float = float(ends[-1])
        """Total length in seconds."""

    def segment_index(self, t: float) -> int:
        """Index of the segment playing at ``t`` seconds (the first/last outside the scene)."""
        return max(bisect.bisect_right(self._starts, t) - 1, 0)

    def pose_at(self, t: float) -> Pose:
        """The indentor's pose at ``t`` seconds."""
        i = self.segment_index(t)
        return self.segments[i].pose_at(t - self._starts[i])

    def contact_at(self, t: float) -> Contact | None:
        """The true contact at ``t`` seconds, ``None`` when nothing touches."""
        return self.pose_at(t).contact()

    def contacts_at(self, t: float) -> list[Contact]:
        """The true contacts at ``t`` seconds: this one's, or none (as :class:`MultiScene`)."""
        c = self.contact_at(t)
        return [] if c is None else [c]

    def segment_start(self, index: int) -> float:
        """Start time in seconds of segment ``index``."""
        return self._starts[index]

    def __repr__(self) -> str:
        kinds = ", ".join(seg.kind for seg in self.segments)
        return f"Scene({self.name!r}, {self.duration:g} s: {kinds})"


class SceneBuilder:
    """Writes a scene as a sequence of moves, each starting where the previous one ended::

        scene = (SceneBuilder(Pose(r1=10, x0=6, y0=13.65))
                 .idle(0.5).press(0.5, force=1.0).roll(2.0, x0=17).hold(1.0).release(0.5)
                 .build("mine"))

    Each method takes a duration in seconds and the pose fields that change (``r1``, ``r2``,
    ``psi_deg``, ``force``, ``x0``, ``y0``), plus optional ``ease``.
    """

    def __init__(self, start: Pose | None = None) -> None:
        self.pose = start or Pose()
        self.segments: list[Segment] = []

    def _move(self, kind: str, duration: float, ease: str, **changes: float) -> SceneBuilder:
        end = replace(self.pose, **changes)
        self.segments.append(Segment(kind, duration, self.pose, end, ease))
        self.pose = end
        return self

    def idle(self, duration: float) -> SceneBuilder:
        """Nothing touches; nothing moves."""
        return self._move("idle", duration, "linear")

    def approach(self, duration: float, ease: str = "smooth", **changes: float) -> SceneBuilder:
        """Move or change the indentor without touching (e.g. bring a sphere over a new spot)."""
        return self._move("approach", duration, ease, **changes)

    def press(self, duration: float, force: float, ease: str = "smooth", **changes: float) -> SceneBuilder:
        """Push to ``force`` N."""
        return self._move("press", duration, ease, force=force, **changes)

    def roll(self, duration: float, ease: str = "linear", **changes: float) -> SceneBuilder:
        """Move the contact centre (``x0``/``y0``, mm) at constant force."""
        return self._move("roll", duration, ease, **changes)

    def rotate(self, duration: float, psi_deg: float, ease: str = "linear", **changes: float) -> SceneBuilder:
        """Turn the indentor's axis to ``psi_deg`` degrees."""
        return self._move("rotate", duration, ease, psi_deg=psi_deg, **changes)

    def hold(self, duration: float) -> SceneBuilder:
        """Keep everything still."""
        return self._move("hold", duration, "linear")

    def release(self, duration: float, ease: str = "smooth", **changes: float) -> SceneBuilder:
        """Lift off: force down to 0 (while the other ``changes`` go on, e.g. a rolling lift-off)."""
        return self._move("release", duration, ease, force=0.0, **changes)

    def build(self, name: str = "") -> Scene:
        return Scene(self.segments, name)


class MultiScene:
    """Several indentors on one array at once: one :class:`Scene` per indentor (a *track*),
    all played on the same clock.  The strain is the sum of the tracks' strains (the physics
    is linear in the pressure: :func:`render_sum`).

    ``contacts_at(t)`` is the truth, the touching tracks' contacts in track order;
    ``contact_at(t)`` the one of them with the largest force (as an estimate's top-level
    fields).  The scene lasts as long as its longest track; a shorter one holds its last pose
    (which must then not touch, so that a looping scene starts and ends untouched).
    """

    def __init__(self, tracks: Sequence[Scene], name: str = "") -> None:
        if not tracks:
            raise ValueError("a scene of several contacts needs at least one track")
        self.tracks: tuple[Scene, ...] = tuple(tracks)
        self.name = name
        self.duration: float = max(tr.duration for tr in self.tracks)
        """Total length in seconds."""
        for i, tr in enumerate(self.tracks):
            if tr.duration < self.duration and tr.pose_at(tr.duration).force > 0:
                raise ValueError(f"track {i} ends at {tr.duration:g} s of {self.duration:g} s "
                                 "still touching: a shorter track must end released")

    def contacts_at(self, t: float) -> list[Contact]:
        """The true contacts at ``t`` seconds, in track order (empty when nothing touches)."""
        return [c for c in (tr.contact_at(t) for tr in self.tracks) if c is not None]

    def contact_at(self, t: float) -> Contact | None:
        """The touching contact of the largest force at ``t`` seconds (the first of equals),
        ``None`` when nothing touches."""
        return max(self.contacts_at(t), key=lambda c: c.force, default=None)

    def idle_spans(self) -> list[tuple[float, float]]:
        """``(start, end)`` seconds of the spans in which no track touches: the tracks'
        idle and approach segments intersected."""
        spans = [(0.0, self.duration)]
        for tr in self.tracks:
            free = [(tr.segment_start(i), tr.segment_start(i) + seg.duration)
                    for i, seg in enumerate(tr.segments) if seg.kind in ("idle", "approach")]
            if tr.duration < self.duration:
                free.append((tr.duration, self.duration))
            spans = [(max(a, c), min(b, d)) for a, b in spans for c, d in free
                     if min(b, d) > max(a, c)]
        return sorted(spans)

    def __repr__(self) -> str:
        return f"MultiScene({self.name!r}, {self.duration:g} s, {len(self.tracks)} tracks)"


#: What a simulated finger plays: one contact at a time, or several.
AnyScene = Union[Scene, MultiScene]


# -- built-in scenes (positions relative to the array, so they fit any geometry) -------------

def _centre(g: Geometry) -> tuple[float, float]:
    return g.span_x / 2.0, g.span_y / 2.0


def _demo(g: Geometry) -> Scene:
    """~20 s: a 10 mm cylinder pressed, rolled along x, turned, held and released; a sphere
    press; a knife edge (r1 = 0.5 mm) press.  Made to loop: it starts and ends untouched."""
    xc, yc = _centre(g)
    return (
        SceneBuilder(Pose(r1=10.0, psi_deg=90.0, x0=0.25 * g.span_x, y0=yc))
        .idle(0.5)
        .approach(0.5)
        .press(0.5, force=1.0)
        .roll(2.0, x0=0.75 * g.span_x)
        .roll(1.0, x0=xc)
        .rotate(1.0, psi_deg=30.0)
        .rotate(2.0, psi_deg=150.0)
        .rotate(1.0, psi_deg=90.0)
        .hold(2.0)
        .release(0.5)
        .idle(0.5)
        .approach(0.5, r1=8.0, r2=8.0)  # a sphere, same spot
        .press(0.5, force=1.5)
        .hold(1.0)
        .release(0.5)
        .idle(0.5)
        .approach(0.5, r1=0.5, r2=math.inf, psi_deg=60.0)  # a knife edge across the finger
        .press(0.5, force=0.8)
        .hold(1.0)
        .release(0.5)
        .idle(1.0)
        .approach(0.5, r1=10.0, psi_deg=90.0, x0=0.25 * g.span_x)  # back to the start pose
        .build("demo")
    )


def _press(g: Geometry) -> Scene:
    """3 s: a 10 mm cylinder at 90 deg pressed to 1 N at the array centre, held 1 s, released."""
    xc, yc = _centre(g)
    return (SceneBuilder(Pose(r1=10.0, psi_deg=90.0, x0=xc, y0=yc))
            .idle(0.5).press(0.5, force=1.0).hold(1.0).release(0.5).idle(0.5).build("press"))


def _hold(g: Geometry) -> Scene:
    """~5 min: the press scene's contact held for 300 s (60 zeroing time constants: a zeroer
    that tracked a held contact as drift would erase it well within that)."""
    xc, yc = _centre(g)
    return (SceneBuilder(Pose(r1=10.0, psi_deg=90.0, x0=xc, y0=yc))
            .idle(1.0).press(0.5, force=1.0).hold(300.0).release(0.5).idle(2.0).build("hold"))


def _empty(g: Geometry) -> Scene:
    """1 s of nothing (loops): drift, noise and zeroing only."""
    xc, yc = _centre(g)
    return SceneBuilder(Pose(x0=xc, y0=yc)).idle(1.0).build("empty")


def _sphere(g: Geometry) -> Scene:
    """3 s: an 8 mm sphere pressed to 1.5 N at the array centre."""
    xc, yc = _centre(g)
    return (SceneBuilder(Pose(r1=8.0, r2=8.0, x0=xc, y0=yc))
            .idle(0.5).press(0.5, force=1.5).hold(1.0).release(0.5).idle(0.5).build("sphere"))


def _edge(g: Geometry) -> Scene:
    """3 s: a knife edge (cylinder r1 = 0.5 mm) at 60 deg pressed to 0.8 N at the centre."""
    xc, yc = _centre(g)
    return (SceneBuilder(Pose(r1=0.5, psi_deg=60.0, x0=xc, y0=yc))
            .idle(0.5).press(0.5, force=0.8).hold(1.0).release(0.5).idle(0.5).build("edge"))


#: The ``moving`` scene's limits (on the default 8x8 array; positions scale with the array):
#: while touching, the contact centre always moves at 20-100 mm/s, the axis turns at up to
#: 180 deg/s, and the force stays within 0.3-2 N except on touch-down and lift-off ramps.
MOVING_SPEED_MM_S = (20.0, 100.0)
MOVING_TURN_DEG_S = 180.0
MOVING_FORCE_N = (0.3, 2.0)


def _moving(g: Geometry) -> Scene:
    """5.45 s of contacts that never rest: a 10 mm cylinder, then an 8 mm sphere, then a knife
    edge (r1 = 0.5 mm), each touching down while rolling, rolling at 20-100 mm/s with force
    ramps within 0.3-2 N, the cylinder and the edge also turning at 180 deg/s, lifted off for
    0.1 s while the indentor is changed, and for 0.65 s at the loop point.  Every touching segment is linear (constant speed:
    no easing to rest at its ends) and lasts a whole number of milliseconds, so at 1 kHz every
    frame differs from the one before by the scripted speeds.  Loops: it starts and ends
    untouched in the same pose."""
    xc, yc = _centre(g)
    d = Geometry()
    sx, sy = g.span_x / d.span_x, g.span_y / d.span_y  # mm on the default array -> this one

    def at(dx: float, dy: float) -> dict[str, float]:
        """Contact centre ``(dx, dy)`` mm from the array centre (default array)."""
        return {"x0": xc + dx * sx, "y0": yc + dy * sy}

    lin = "linear"
    return (
        SceneBuilder(Pose(r1=10.0, psi_deg=90.0, **at(-5.0, -3.0)))
        # Untouched for 0.65 s at the loop point (this idle and the last approach): the hand lets
        # go and grasps again.  The daemon's zeroer moves its baseline only while nothing
        # touches and starts it from an unloaded finger; 0.1 s lift-offs are too short for that.
        .idle(0.5)
        # -- cylinder: touch down rolling, rolls at 20, 50, 100 mm/s, turns at 180 deg/s
        .press(0.10, force=0.6, ease=lin, **at(-3.0, -3.0))  # 20 mm/s
        .roll(0.30, force=1.2, **at(3.0, -3.0))  # 20 mm/s, +2 N/s
        .roll(0.12, force=1.5, **at(-3.0, -3.0))  # 50 mm/s
        .roll(0.06, force=1.8, **at(3.0, -3.0))  # 100 mm/s
        .rotate(0.25, psi_deg=135.0, force=2.0, **at(3.0, 3.0))  # 180 deg/s, 24 mm/s
        .rotate(0.50, psi_deg=45.0, force=1.0, **at(-5.0, -3.0))  # 180 deg/s, 20 mm/s, -2 N/s
        .rotate(0.25, psi_deg=90.0, force=0.5, **at(0.0, 0.0))  # 180 deg/s, 23 mm/s
        .roll(0.20, force=0.3, **at(0.0, 6.0))  # 30 mm/s, light
        .release(0.08, ease=lin, **at(0.0, 4.4))  # lift off rolling at 20 mm/s
        .approach(0.10, r1=8.0, r2=8.0, **at(4.0, 4.0))  # 0.1 s in the air: now a sphere
        # -- sphere: rolls at 20-80 mm/s with force ramps of up to 5.3 N/s
        .press(0.10, force=0.8, ease=lin, **at(2.0, 4.0))  # 20 mm/s
        .roll(0.20, force=1.6, **at(2.0, -6.0))  # 50 mm/s
        .roll(0.25, force=0.6, **at(-3.0, 1.0))  # 34 mm/s
        .roll(0.10, force=0.9, **at(5.0, 1.0))  # 80 mm/s
        .roll(0.40, force=2.0, **at(-3.0, 1.0))  # 20 mm/s
        .roll(0.30, force=0.4, **at(3.0, -4.0))  # 26 mm/s
        .release(0.08, ease=lin, **at(4.6, -4.0))  # 20 mm/s
        .approach(0.10, r1=0.5, r2=math.inf, psi_deg=45.0, **at(4.0, 0.0))  # now an edge
        # -- knife edge: turns at 180 deg/s while rolling, rolls at up to 100 mm/s
        .press(0.10, force=0.5, ease=lin, psi_deg=63.0, **at(2.0, 0.0))  # 20 mm/s, 180 deg/s
        .rotate(0.40, psi_deg=135.0, force=1.2, **at(-5.0, 4.0))  # 180 deg/s, 20 mm/s
        .roll(0.15, force=1.5, **at(2.5, 4.0))  # 50 mm/s
        .rotate(0.50, psi_deg=45.0, force=0.8, **at(-3.0, -5.0))  # 180 deg/s, 21 mm/s
        .roll(0.08, force=0.4, **at(5.0, -5.0))  # 100 mm/s
        .release(0.08, ease=lin, **at(5.0, -3.4))  # 20 mm/s, from a light force: little hysteresis
        .approach(0.15, r1=10.0, r2=math.inf, psi_deg=90.0, **at(-5.0, -3.0))  # back to the start
        .build("moving")
    )


#: Built-in scenes by name (``sim://?scene=NAME``, ``tactiled simulate --scene NAME``).
def _temporal(g: Geometry) -> Scene:
    """~9.5 s of what a tracker must follow: a 10 mm cylinder at 60 deg pressed to 1.2 N at
    the centre and held 3 s, rolled 3 mm along x in 1 s, turned to 120 deg in 1 s, a 20 %
    force step, a 0.5 mm jump along y (each within one frame at 1 kHz), released."""
    xc, yc = _centre(g)
    step = 1e-3  # s: one frame at 1 kHz
    return (SceneBuilder(Pose(r1=10.0, psi_deg=60.0, x0=xc - 1.5, y0=yc))
            .idle(0.5).press(0.5, force=1.2).hold(3.0)
            .roll(1.0, x0=xc + 1.5).hold(0.5)
            .rotate(1.0, psi_deg=120.0).hold(0.5)
            .press(step, force=1.44, ease="linear").hold(0.5)
            .roll(step, y0=yc + 0.5).hold(0.5)
            .release(0.5).idle(0.5).build("temporal"))


# -- the hand: five fingertips and a palm, each its own device, grasping together ----------
#
# Every part plays the same 4 s on its own device's clock: 0.7 s free (the hand opens; long
# enough to tare in), the grasp closes in 0.3 s, 1.6 s of manipulation (the thumb and the index
# roll the object between them, the palm takes a third knuckle, the ring finger's contact
# turns), the grasp opens in 0.3 s, 1.1 s free.  Positions are fractions of the array's span.

HAND_OPEN_S = 0.7  # s free before the grasp closes
HAND_CLOSE_S = 0.3  # s to press (and to release)
HAND_MOVE_S = 1.6  # s of manipulation
HAND_DURATION_S = 4.0  # s per pass; loops


def _grasp(g: Geometry, start: tuple[float, float], pose: dict[str, float], force: float,
           moves: Sequence[tuple[str, float, dict[str, float]]] = (),
           at: float = HAND_OPEN_S, free_after: float | None = None) -> Scene:
    """One indentor of the hand: free until ``at`` s, pressed to ``force`` N at ``start``
    (fractions of the span) in :data:`HAND_CLOSE_S`, then ``moves`` (``(kind, seconds,
    changes)``, positions as fractions), held until ``free_after`` s (default: the end of the
    manipulation), released, free to the end of the pass."""
    def place(changes: dict[str, float]) -> dict[str, float]:
        out = dict(changes)
        if "x0" in out:
            out["x0"] *= g.span_x
        if "y0" in out:
            out["y0"] *= g.span_y
        return out

    b = SceneBuilder(Pose(**pose, x0=start[0] * g.span_x, y0=start[1] * g.span_y))
    b.idle(at).press(HAND_CLOSE_S, force=force)
    t = at + HAND_CLOSE_S
    for kind, seconds, changes in moves:
        getattr(b, kind)(seconds, **place(changes))
        t += seconds
    end = HAND_OPEN_S + HAND_CLOSE_S + HAND_MOVE_S if free_after is None else free_after
    if end > t + 1e-9:
        b.hold(end - t)
    b.release(HAND_CLOSE_S)
    rest = HAND_DURATION_S - (max(end, t) + HAND_CLOSE_S)
    if rest > 1e-9:
        b.idle(rest)
    return b.build()


def _hand_palm(g: Geometry) -> MultiScene:
    """The palm: two knuckles of the object (6 mm spheres, 2 and 1.5 N, 40 % of the span
    apart) press at once, the first sliding along y; a third (an 8 mm sphere, 1 N) comes and
    goes in the middle of the grasp."""
    knuckle = {"r1": 6.0, "r2": 6.0}
    return MultiScene([
        _grasp(g, (0.3, 0.3), knuckle, 2.0, [("roll", HAND_MOVE_S, {"y0": 0.45})]),
        _grasp(g, (0.7, 0.3), knuckle, 1.5),
        _grasp(g, (0.5, 0.75), {"r1": 8.0, "r2": 8.0}, 1.0, at=HAND_OPEN_S + 0.6,
               free_after=HAND_OPEN_S + 1.3),
    ], "hand-palm")


def _hand_finger(k: int) -> Callable[[Geometry], MultiScene]:
    """Fingertip ``k`` (1 thumb .. 5 little)."""
    def scene(g: Geometry) -> MultiScene:
        cyl, sphere = {"r1": 10.0, "psi_deg": 90.0}, {"r1": 8.0, "r2": 8.0}
        if k == 1:  # the thumb rolls the object along x
            tracks = [_grasp(g, (0.35, 0.5), cyl, 1.2, [("roll", HAND_MOVE_S, {"x0": 0.65})])]
        elif k == 2:  # the index rolls it the other way, and an edge of it presses higher up
            tracks = [_grasp(g, (0.65, 0.3), sphere, 1.0, [("roll", HAND_MOVE_S, {"x0": 0.35})]),
                      _grasp(g, (0.5, 0.78), {"r1": 0.5, "psi_deg": 30.0}, 0.6,
                             at=HAND_OPEN_S + 0.4, free_after=HAND_OPEN_S + 1.5)]
        elif k == 3:  # the middle finger holds
            tracks = [_grasp(g, (0.5, 0.5), sphere, 1.0)]
        elif k == 4:  # the ring finger's contact turns under it
            tracks = [_grasp(g, (0.5, 0.5), {"r1": 10.0, "psi_deg": 45.0}, 0.8,
                             [("rotate", HAND_MOVE_S, {"psi_deg": 90.0})])]
        else:  # the little finger touches lightly
            tracks = [_grasp(g, (0.5, 0.45), sphere, 0.5)]
        return MultiScene(tracks, f"hand-finger{k}")

    return scene


#: The hand's parts: name -> (scene, sensor description of its array).
HAND_PARTS: dict[str, tuple[str, str]] = {
    "palm": ("hand-palm", "flat16"),
    **{f"finger{k}": (f"hand-finger{k}", "fearing1988") for k in range(1, 6)},
}


SCENES: dict[str, Callable[[Geometry], AnyScene]] = {
    "demo": _demo,
    "press": _press,
    "hold": _hold,
    "empty": _empty,
    "sphere": _sphere,
    "edge": _edge,
    "moving": _moving,
    "temporal": _temporal,
    "hand-palm": _hand_palm,
    **{f"hand-finger{k}": _hand_finger(k) for k in range(1, 6)},
}


def named_scene(name: str, geometry: Geometry | None = None) -> AnyScene:
    """The built-in scene ``name`` laid out on ``geometry`` (default: the 8x8 array).

    ``ValueError`` names the known scenes if ``name`` is not one of them.
    """
    key = name.strip().lower()
    if key not in SCENES:
        raise ValueError(f"unknown scene {name!r}; known scenes: {', '.join(SCENES)}")
    return SCENES[key](geometry or Geometry())


def scene_from_spec(spec: str, geometry: Geometry | None = None) -> AnyScene:
    """The scene a URL or command line names (``sim://?scene=demo``, ``--scene demo``).

    A spec is a built-in scene name (see :data:`SCENES`), case-insensitive.
    """
    return named_scene(spec, geometry)

"""Scenes of the benchmarks that must keep the fitter busy (the soak, the worker-memory probe).

:func:`busy_scene` never holds still: a seeded random walk of the indentor that presses, rolls,
rotates and changes its shape all the time, so nearly every frame needs a fit.  It is registered
as :data:`BUSY_SCENE` (``busy``) by :func:`register_bench_scenes`, in the simulator processes
only (not in :data:`tactiled.sim.SCENES`).
"""
# Why: the built-in scenes of tactiled.sim show the daemon working; most of the demo scene is a
# contact held still or nothing at all, which the gate answers without a fit (unchanged,
# no_contact), so a soak on it measures a mostly idle fitter.  The busy walk goes through
# cylinder, general paraboloid, sphere and knife edge, at forces from light to firm, with a short
# release now and then, so the fitter keeps visiting new contact sizes, models and warm starts.
# The soak's --scene takes a built-in scene or this one.

from __future__ import annotations

import math

import numpy as np

from tactiled.sensors.model import Geometry
from tactiled.sim import SCENES, Pose, Scene, SceneBuilder

#: Name under which the soak's simulators know :func:`busy_scene`.
BUSY_SCENE = "busy"
#: Length of one pass of the busy scene (s); it loops after that.
BUSY_DURATION_S = 600.0

#: Indentor shapes the busy scene moves between: (r1, r2) in mm.
_SHAPES = (
    (10.0, math.inf),  # cylinder
    (6.0, math.inf),   # thinner cylinder
    (8.0, 8.0),        # sphere
    (12.0, 12.0),      # larger sphere
    (5.0, 20.0),       # general paraboloid
    (9.0, 40.0),       # flatter general paraboloid
    (0.5, math.inf),   # knife edge
)


def busy_scene(geometry: Geometry | None = None, seed: int = 7,
               duration_s: float = BUSY_DURATION_S) -> Scene:
    """A ``duration_s`` scene in which the contact never stays still (see the module
    docstring).  Deterministic given ``seed``; starts and ends untouched, so it loops."""
    g = geometry or Geometry()
    rng = np.random.default_rng(seed)
    margin_x, margin_y = 0.2 * g.span_x, 0.2 * g.span_y

    def spot() -> dict[str, float]:
        return {"x0": float(rng.uniform(margin_x, g.span_x - margin_x)),
                "y0": float(rng.uniform(margin_y, g.span_y - margin_y))}

    def shape() -> dict[str, float]:
        r1, r2 = _SHAPES[int(rng.integers(len(_SHAPES)))]
        return {"r1": r1, "r2": r2}

    def force() -> float:
        return float(np.exp(rng.uniform(math.log(0.4), math.log(2.0))))

    b = SceneBuilder(Pose(r1=10.0, psi_deg=90.0, **spot()))
    b.idle(0.2).approach(0.2).press(0.3, force=1.0)
    while sum(s.duration for s in b.segments) < duration_s - 1.5:
        roll = float(rng.uniform(0.4, 1.5))
        move = int(rng.integers(5))
        # Across the finger, never along it: an indentor parallel to the finger axis makes a
        # line contact longer than the finger, outside the model (and the simulator's range).
        psi = float(rng.uniform(35.0, 145.0))
        if move == 0:    # roll to a new spot, pressing harder or softer on the way
            b.roll(roll, force=force(), **spot())
        elif move == 1:  # turn while rolling
            b.rotate(roll, psi_deg=psi, **spot())
        elif move == 2:  # change shape while pressing and turning (the model changes)
            b.press(roll, force=force(), psi_deg=psi, **shape())
        elif move == 3:  # roll, turn and change shape at once
            b.roll(roll, psi_deg=psi, force=force(), **shape(), **spot())
        else:            # lift off, come down elsewhere with another indentor
            b.release(0.15).approach(0.1, psi_deg=psi, **shape(), **spot())
            b.press(0.25, force=force())
    b.release(0.3).idle(0.3)
    return b.build(BUSY_SCENE)


def register_bench_scenes() -> None:
    """Make ``busy`` a scene name in this process (``tactiled simulate --scene busy``,
    ``sim://?scene=busy``).  For the benchmarks' own simulator processes."""
    SCENES.setdefault(BUSY_SCENE, busy_scene)

"""The scene simulator: contacts to physics-true strain frames with the sensor's noise.

Used by ``tactiled simulate``, the benchmarks, the tests and the simulated-finger driver
(``sim://``).  :mod:`~tactiled.sim.frames` renders contacts to noisy strain frames,
:mod:`~tactiled.sim.scenes` scripts indentor motions, :mod:`~tactiled.sim.simulator` plays a
scene as a finger's counts, and :mod:`~tactiled.sim.shear` simulates 3-axis frames.  The
names below are the package's public API (``from tactiled.sim import FingerSimulator``).
"""

from tactiled.sim.frames import add_noise, as_line, line_length, render, render_sum, simulate_frames
from tactiled.sim.scenes import (
    EASINGS,
    HAND_CLOSE_S,
    HAND_DURATION_S,
    HAND_MOVE_S,
    HAND_OPEN_S,
    HAND_PARTS,
    MOVING_FORCE_N,
    MOVING_SPEED_MM_S,
    MOVING_TURN_DEG_S,
    SCENES,
    SEGMENT_KINDS,
    AnyScene,
    MultiScene,
    Pose,
    Scene,
    SceneBuilder,
    Segment,
    named_scene,
    scene_from_spec,
)
from tactiled.sim.simulator import (
    DEFAULT_DRIFT,
    DEFAULT_HYSTERESIS,
    DRIFT_UPDATE_S,
    SETTLED_RESIDUAL,
    DriftModel,
    FingerSimulator,
    FrameSchedule,
    HysteresisModel,
    Tick,
)

__all__ = [
    "DEFAULT_DRIFT", "DEFAULT_HYSTERESIS", "DRIFT_UPDATE_S", "EASINGS", "HAND_CLOSE_S",
    "HAND_DURATION_S", "HAND_MOVE_S", "HAND_OPEN_S", "HAND_PARTS", "MOVING_FORCE_N",
    "MOVING_SPEED_MM_S", "MOVING_TURN_DEG_S", "SCENES", "SEGMENT_KINDS", "SETTLED_RESIDUAL", "AnyScene", "DriftModel", "FingerSimulator", "FrameSchedule",
    "HysteresisModel", "MultiScene", "Pose", "Scene", "SceneBuilder", "Segment", "Tick",
    "add_noise", "as_line", "line_length", "named_scene", "render", "render_sum",
    "scene_from_spec", "simulate_frames",
]

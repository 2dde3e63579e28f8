"""The golden replays' estimates judged against the simulator's truth, not only against the
files the code wrote (test_golden_replay.py compares them with themselves).

Each golden session was recorded from the scene simulator (``regen_golden.SESSIONS``: the
paper's finger, its default drift and hysteresis, 30 frames/s); the same scene played without
noise, drift or hysteresis gives the true contact at every frame.  Every value the daemon
published for a frame with a true contact (fitted, tracked or carried for an unchanged frame)
is compared with it, in units of its own reported sigma.

What the truth leaves out is in the recordings: the rubber's hysteresis (5 % of the released
strain, decaying over 0.5 s) and the drift the zeroer holds frozen under a contact add strain
during a release that the indentor's force does not have, and the daemon cannot know either
before it has learnt it (docs/concepts/tracking.md).  So the frames of a release (the true
force falling) are not held to the bars, nor the frames after the true contact ended (the
rubber springing back: no true value).  Every other frame's values meet these bars: at most
1 % of published values beyond 4 sigma of the truth and none beyond 6 (honest Gaussian
sigmas: 6e-5 and 2e-9), at least 85 % within 2 sigma (95 % for exactly Gaussian sigmas; the
drift and hysteresis the daemon has not learnt in a 3 s session cost some: the sphere's
session has 89 %).
"""

from __future__ import annotations

import json
import math

import pytest
import regen_golden as g

from tactiled.sensors.model import SensorModel
from tactiled.sim import FingerSimulator, named_scene

KEYS = ("x_mm", "y_mm", "force_n", "r1_mm", "angle_deg")
RATE = 30.0


def _truth(scene: str, ticks: int) -> list[list]:
    sim = FingerSimulator(SensorModel(), scene, rate_hz=RATE, noise=0.0, drift=None,
                          hysteresis=None, loop=False)
    return [list(sim.step().contacts) for _ in range(ticks)]


def _scored(name: str) -> list[tuple[int, str, float]]:
    """``(frame, key, |error| / sigma)`` of every published value of session ``name`` on a
    frame with a true contact that is not being released."""
    lines = [json.loads(t) for t in g.golden(name).read_text().splitlines()]
    truth = _truth(name, len(lines) + 1)
    out = []
    for e in lines:
        if not e.get("contact"):
            continue
        tick = round(e["device_time_us"] * 1e-6 * RATE)
        if not truth[tick]:
            continue
        c = truth[tick][0]
        before = truth[tick - 1] if tick else []
        if before and c.force < before[0].force:
            continue  # a release: see the module's doc
        true = {"x_mm": c.x0, "y_mm": c.y0, "force_n": c.force, "r1_mm": c.r1,
                "angle_deg": c.psi_deg}
        for key in KEYS:
            v, sd = e.get(key), (e.get("std") or {}).get(key)
            if v is None or not math.isfinite(true[key]):
                continue
            assert sd is not None and sd > 0.0, (name, tick, key, "a value without its sigma")
            err = v - true[key]
            if key == "angle_deg":
                err = (err + 90.0) % 180.0 - 90.0
            out.append((tick, key, abs(err) / sd))
    return out


def test_the_sessions_are_the_scenes_the_truth_is_played_from() -> None:
    for name, url in g.SESSIONS.items():
        assert f"scene={name}" in url and "rate=30" in url, url
        named_scene(name, SensorModel().geometry)  # a scene the simulator knows


@pytest.mark.parametrize("name", list(g.SESSIONS))
def test_published_values_are_covered_by_their_sigma(name: str) -> None:
    z = _scored(name)
    assert len(z) >= 100, f"{name}: only {len(z)} values scored"
    far = [s for s in z if s[2] > 4.0]
    within = sum(s[2] <= 2.0 for s in z) / len(z)
    assert len(far) <= 0.01 * len(z), f"{name}: {len(far)} of {len(z)} beyond 4 sigma: {far[:8]}"
    assert not [s for s in z if s[2] > 6.0], f"{name}: beyond 6 sigma: {[s for s in z if s[2] > 6.0]}"
    assert within >= 0.85, f"{name}: {100 * within:.1f} % within 2 sigma"

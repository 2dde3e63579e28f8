"""Several contacts tracked through time, through the whole daemon (part of ``tactiled bench
--suite contacts``).

The ``hand-palm`` scene (up to three contacts) is played once at 1 kHz through the daemon in
lossless mode, model ``auto``, and each listed contact is matched to the nearest true contact:
how frames were answered, missed and phantom contact-frames, and per value the error over the
reported sigma, held and overall.  Deterministic (seeded scene noise, lossless).
"""
# The scene: two knuckles pressed at once, the first sliding, a third coming and going;
# positions are fractions of the array, so it plays on any description; no drift or hysteresis.
# Path: wire bytes -> decoder -> zeroing -> detector -> fits in real worker processes -> each
# contact's filter.  Scores:
# * how the contact frames were answered: fitted, or every contact measured by its filter
#   (frames_used > 1), and the frames of several contacts among them;
# * matching within MATCH_PITCHES pitches: missed and phantom contact-frames;
# * per value, the RMS of the error over the reported sigma and the share within twice the
#   sigma, over the contacts held (force and place unchanged over the last HELD_S) and over all
#   contact frames (presses, the slide and releases included: a filter's constant-velocity model
#   lags a press's ramp, for one contact as for several: docs/concepts/tracking.md).

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tactiled_bench.lossless import play_lossless
from tactiled.sensors import SensorDescription

SCENE = "hand-palm"
RATE = 1000.0
SECONDS = 4.0  # the scene's pass (docs/performance/hand.md)
HELD_S = 0.05
MATCH_PITCHES = 1.5
KEYS = ("force_n", "x_mm", "y_mm", "r1_mm")


def _play(desc: SensorDescription, seed: int) -> list[tuple[int, dict[str, Any], str]]:
    """The daemon's estimates of one pass: ``(tick, fit dict, gate)``."""
    url = (f"sim://?scene={SCENE}&sensor={desc.name}&seed={seed}&rate={RATE:g}&speed=0&loop=0"
           "&drift=0&hysteresis=0")
    overrides = {"sensor[0].url": url, "sensor[0].description": desc.name, "fit.workers": 1}
    return [(round(it.device_time_us * 1e-6 * RATE), it.fit, it.gate) for it in play_lossless(overrides)]


def _truth(desc: SensorDescription, ticks: int) -> list[list[Any]]:
    from tactiled.sim import FingerSimulator

    sim = FingerSimulator(desc.sensor_model(), SCENE, rate_hz=RATE, noise=0.0, drift=None,
                          hysteresis=None, loop=False)
    return [list(sim.step().contacts) for _ in range(ticks)]


def _value(c: Any, key: str) -> float | None:
    return {"force_n": c.force, "x_mm": c.x0, "y_mm": c.y0, "r1_mm": c.r1}.get(key)


def score(desc: SensorDescription, seed: int = 1) -> dict[str, Any]:
    """The tracked-contacts figures of one description (see the module's doc)."""
    estimates = _play(desc, seed)
    truth = _truth(desc, int(SECONDS * RATE) + 1)
    lag = int(HELD_S * RATE)
    match = MATCH_PITCHES * max(desc.pitch_x_mm, desc.pitch_y_mm)
    n = {"contact_frames": 0, "fitted": 0, "filtered": 0, "several": 0, "several_filtered": 0,
         "true_contacts": 0, "missed": 0, "phantom": 0}
    z: dict[str, dict[str, list[float]]] = {"held": {k: [] for k in KEYS}, "all": {k: [] for k in KEYS}}
    for tick, fit, gate in estimates:
        if not 0 <= tick < len(truth):
            continue
        true = truth[tick]
        listed = [c for c in fit.get("contacts") or []
                  if c.get("x_mm") is not None and c.get("y_mm") is not None]
        n["true_contacts"] += len(true)
        if not fit.get("contact"):
            n["missed"] += len(true)
            continue
        n["contact_frames"] += 1
        n["fitted"] += gate == "fit"
        filtered = all((c.get("frames_used") or 0) > 1 for c in listed)
        n["filtered"] += filtered and gate != "fit"
        if len(listed) > 1:
            n["several"] += 1
            n["several_filtered"] += filtered and gate != "fit"
        found = set()
        for c in listed:
            near = min(range(len(true)), key=lambda i: math.dist((true[i].x0, true[i].y0),
                                                                 (c["x_mm"], c["y_mm"])), default=None)
            if near is None or math.dist((true[near].x0, true[near].y0), (c["x_mm"], c["y_mm"])) > match:
                n["phantom"] += 1
                continue
            found.add(near)
            a = true[near]
            held = tick >= lag and any(b.force == a.force and b.x0 == a.x0 and b.y0 == a.y0
                                       for b in truth[tick - lag])
            for key in KEYS:
                v, sd, t = c.get(key), (c.get("std") or {}).get(key), _value(true[near], key)
                if v is None or not sd or t is None or not math.isfinite(t):
                    continue
                e = (v - t) / sd
                z["all"][key].append(e)
                if held:
                    z["held"][key].append(e)
        n["missed"] += len(true) - len(found)
    return {"counts": n, "z": z}


def report(desc: SensorDescription, s: dict[str, Any]) -> list[str]:
    """Markdown lines of one description's :func:`score`."""
    n = s["counts"]
    cf = max(n["contact_frames"], 1)
    out = [f"tracked through time (`{SCENE}`, {SECONDS:g} s at {RATE:g} Hz through the daemon, "
           f"lossless): {n['contact_frames']} contact frames, {100 * n['fitted'] / cf:.1f} % fitted, "
           f"{100 * n['filtered'] / cf:.1f} % measured by every contact's filter; "
           f"{n['several']} frames of several contacts, {100 * n['several_filtered'] / max(n['several'], 1):.1f} % "
           f"of them filtered; contacts missed {100 * n['missed'] / max(n['true_contacts'], 1):.1f} % "
           f"of {n['true_contacts']}, phantom {n['phantom']}", "",
           "| value | held: RMS error/sigma | held: 2-sigma | held: n | all: RMS error/sigma | all: 2-sigma | all: n |",
           "|---|---|---|---|---|---|---|"]
    for key in KEYS:
        cells = []
        for part in ("held", "all"):
            e = np.asarray(s["z"][part][key])
            cells += (["-", "-", "0"] if not e.size else
                      [f"{math.sqrt(float(np.mean(e * e))):.2f}", f"{100 * float(np.mean(np.abs(e) <= 2)):.0f} %",
                       str(e.size)])
        out.append(f"| {key} | " + " | ".join(cells) + " |")
    return out + [""]

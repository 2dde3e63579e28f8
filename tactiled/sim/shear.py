"""Simulated 3-axis frames: a sphere pressed on a 3-axis array and loaded tangentially
(docs/concepts/shear.md).  Used by ``tactiled simulate --sensor NAME`` on a 3-axis description,
the ``shear`` bench and the tests.
"""

# Two kinds of output, both ``(N, rows, cols, 3)`` readings (x, y, z; the description's gains and
# Gaussian noise of its ``axis_noise``) with the truth per frame:
#
# * :func:`random_frames`: independent frames, each a sphere of random radius, force, centre,
#   tangential force ``Q = lam mu P`` in a random direction, torsion, friction coefficient;
# * :func:`sequence`: a scene at ``rate_hz`` (1 kHz by default): the sphere pressed (50 ms),
#   held (20 ms), then loaded:
#
#   - ``push``: ``Q`` ramps to ``0.8 mu P`` over 200 ms and holds 100 ms (stick only);
#   - ``twist``: the torsion ramps to half Lubkin's gross-slip torque ``3 pi mu P a / 16`` over
#     200 ms and holds 100 ms (stick only);
#   - ``limit``: ``Q`` ramps toward ``1.5 mu P`` over 300 ms and stays at ``mu P`` from when it
#     reaches it (the true onset): the stick zone shrinks to nothing (``lam = 1``, the traction
#     ``mu p``) and the contact stays put (a quasi-static pull: the friction holds the object
#     at its limit, no motion and no drop of the force shows the onset);
#   - ``pull``: ``Q`` ramps to ``1.5 mu P`` over 300 ms; when it reaches ``mu P`` (``mu`` the
#     static coefficient) the contact slides (the true slip onset): the friction becomes kinetic,
#     ``Q = kinetic mu P`` (``kinetic`` 0.8 by default; 1 for none), the traction is
#     ``kinetic mu p`` (gross slip, ``lam = 1``) and the object moves over the skin along ``Q``
#     from rest at ``accel`` mm/s^2 (default 5000 mm/s^2: 0.2 mu P of unbalanced force on some
#     20-60 g) for the rest of the scene.
#
# Truth keys: ``true_r1`` (the sphere's radius), ``true_force``, ``true_x``, ``true_y``,
# ``true_fx``, ``true_fy``, ``true_torque``, ``true_mu``, ``true_lam`` (``Q / (mu P)``),
# ``true_slip`` (1 while sliding) and, for a sequence, ``true_onset`` (the first sliding frame,
# -1 for none).

from __future__ import annotations

import math

import numpy as np

from tactiled.physics.threeaxis import ShearContact, ThreeAxisModel, lam_for
from tactiled.sensors.description import SensorDescription

SEQUENCES = ("push", "twist", "pull", "limit")
TRUTH = ("true_r1", "true_force", "true_x", "true_y", "true_fx", "true_fy", "true_torque",
         "true_mu", "true_lam", "true_slip")
#: The default ranges of :func:`random_frames` (radius log-uniform).
RANGES = {"r1": (5.0, 20.0), "force": (0.5, 2.0), "mu": (0.3, 1.0), "lam": (0.0, 0.95),
          "torque": (-0.3, 0.3)}


def _noisy(model: ThreeAxisModel, clean: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return clean + rng.normal(size=clean.shape) * model.noise


def _record(truth: dict[str, np.ndarray], i: int, c: ShearContact, mu: float, slip: bool) -> None:
    for k, v in zip(TRUTH, (c.r_mm, c.force, c.x0, c.y0, c.fx, c.fy, c.torque, mu, c.lam, float(slip))):
        truth[k][i] = v


def random_frames(desc: SensorDescription, n: int, rng: np.random.Generator,
                  ranges: dict[str, tuple[float, float]] | None = None,
                  centre: tuple[tuple[float, float], tuple[float, float]] | None = None
                  ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """``n`` independent noisy frames and their truth (``ranges`` overrides :data:`RANGES`;
    ``centre`` the x and y ranges of the contact's centre, default the array's central pitch)."""
    model = ThreeAxisModel(desc)
    r = {**RANGES, **(ranges or {})}
    cx, cy = model.centre()
    if centre is None:
        centre = ((cx - desc.pitch_x_mm / 2, cx + desc.pitch_x_mm / 2),
                  (cy - desc.pitch_y_mm / 2, cy + desc.pitch_y_mm / 2))
    frames = np.empty((n, *model.shape))
    truth = {k: np.empty(n) for k in TRUTH}
    for i in range(n):
        lo, hi = r["r1"]
        radius = math.exp(rng.uniform(math.log(lo), math.log(hi)))
        force, mu, lam = rng.uniform(*r["force"]), rng.uniform(*r["mu"]), rng.uniform(*r["lam"])
        q, phi = lam * mu * force, rng.uniform(0, 2 * math.pi)
        c = ShearContact(radius, force, rng.uniform(*centre[0]), rng.uniform(*centre[1]),
                         q * math.cos(phi), q * math.sin(phi), rng.uniform(*r["torque"]), lam)
        frames[i] = _noisy(model, model.frame(c), rng)
        _record(truth, i, c, mu, False)
    return frames, truth


def sequence(desc: SensorDescription, kind: str, rng: np.random.Generator, rate_hz: float = 1000.0,
             accel: float = 5000.0, kinetic: float = 0.8, ramp_s: float | None = None,
             hold: float = 0.8, force_change: float = 0.0) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """One scene (:data:`SEQUENCES`) of noisy frames at ``rate_hz`` and its truth.  ``ramp_s``
    replaces the loading ramp's duration (s; 0.3 for a pull or a limit, 0.2 else), ``hold`` a push's
    level (a fraction of ``mu P``), ``force_change`` the normal force's relative change over
    the ramp (-0.3: it falls to 70 %; the pull then slides sooner)."""
    if kind not in SEQUENCES:
        raise ValueError(f"no shear scene {kind!r} (scenes: {', '.join(SEQUENCES)})")
    if kind == "limit":  # a pull held at the friction's limit: no kinetic drop, no motion
        kind, kinetic, accel = "pull", 1.0, 0.0
    model = ThreeAxisModel(desc)
    radius = math.exp(rng.uniform(math.log(5.0), math.log(20.0)))
    force, mu = rng.uniform(0.8, 2.0), rng.uniform(0.3, 1.0)
    phi = rng.uniform(0, 2 * math.pi)
    cx, cy = model.centre()
    x0 = cx + rng.uniform(-0.5, 0.5) * desc.pitch_x_mm
    y0 = cy + rng.uniform(-0.5, 0.5) * desc.pitch_y_mm
    dt = 1.0 / rate_hz
    press, rest = round(0.05 * rate_hz), round(0.02 * rate_hz)
    ramp = round((ramp_s if ramp_s is not None else 0.3 if kind == "pull" else 0.2) * rate_hz)
    tail = round(0.1 * rate_hz)
    n = press + rest + ramp + (0 if kind == "pull" else tail)
    frames = np.empty((n, *model.shape))
    truth = {k: np.empty(n) for k in TRUTH}
    onset, slid = -1, 0.0
    a = model.ellipse(radius, force).a
    for i in range(n):
        s = min(1.0, max(0.0, (i - press - rest + 1) / ramp))
        p = force * min(1.0, (i + 1) / press) * (1.0 + force_change * s)
        q = t = 0.0
        if kind == "push":
            q = hold * mu * p * s
        elif kind == "twist":
            t = 0.5 * 3 * math.pi * mu * force * a / 16 * s
        else:
            q = 1.5 * mu * force * s
        sliding = kind == "pull" and q >= mu * p
        if sliding:
            if onset < 0:
                onset = i
            q = kinetic * mu * p
            slid = 0.5 * accel * ((i - onset + 1) * dt) ** 2
        lam = 1.0 if sliding else lam_for(q, mu, p)
        c = ShearContact(radius, p, x0 + slid * math.cos(phi), y0 + slid * math.sin(phi),
                         q * math.cos(phi), q * math.sin(phi), t, lam)
        frames[i] = _noisy(model, model.frame(c), rng)
        _record(truth, i, c, mu, sliding)
    truth["true_onset"] = np.array(onset)
    return frames, truth

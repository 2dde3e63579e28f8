"""The seeded benchmark suite: simulated scenes with ground truth.

A scene is a short burst of frames of one persisting contact that drifts slightly from frame to
frame (a hand holding an object), so cold and warm starts can be compared on the same frames.
Contacts span cylinders (psi 30-150 deg), spheres, general ellipsoids and edges (r1 < 1 mm),
forces 0.1-3 N and centres over the whole array (tactel pitch inside the array's edge).  Frames
carry the noise of the issue's noisy case: Gaussian 0.0003 plus quantisation to 0.001.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from tactiled.sensors.model import NoiseModel, SensorModel
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
from tactiled.sim import add_noise

BENCH_NOISE = NoiseModel(sigma=0.0003, quantum=0.001)
KINDS = ("cylinder", "edge", "sphere", "general")


@dataclass
class BenchFrame:
    scene: int
    kind: str
    contact: Contact
    clean: np.ndarray
    strain: np.ndarray


def random_contact(rng: np.random.Generator, kind: str, sensor: SensorModel) -> Contact:
    g = sensor.geometry
    force = float(math.exp(rng.uniform(math.log(0.1), math.log(3.0))))
    x0 = float(rng.uniform(0.5 * g.dx, g.span_x - 0.5 * g.dx))
    y0 = float(rng.uniform(0.5 * g.dy, g.span_y - 0.5 * g.dy))
    if kind == "cylinder":
        r1 = float(math.exp(rng.uniform(0.0, math.log(50.0))))
        return Contact(r1, math.inf, float(rng.uniform(30.0, 150.0)), force, x0, y0)
    if kind == "edge":
        r1 = float(rng.uniform(0.1, 1.0))
        return Contact(r1, math.inf, float(rng.uniform(30.0, 150.0)), force, x0, y0)
    if kind == "sphere":
        r = float(math.exp(rng.uniform(0.0, math.log(30.0))))
        return Contact(r, r, 0.0, force, x0, y0)
    r1 = float(math.exp(rng.uniform(0.0, math.log(20.0))))
    r2 = r1 * float(math.exp(rng.uniform(math.log(1.5), math.log(10.0))))
    return Contact(r1, r2, float(rng.uniform(0.0, 180.0)), force, x0, y0)


def issue_cylinder(rng: np.random.Generator, force: float | None = None) -> Contact:
    """A cylinder from the issues' range: R 1-50 mm (log-uniform), psi 30-150 deg, force
    0.5-2 N (or ``force``), centre a pitch or more inside the array (x 5-18, y 6-21 mm)."""
    r = float(math.exp(rng.uniform(0.0, math.log(50.0))))
    psi = float(rng.uniform(30.0, 150.0))
    f = float(rng.uniform(0.5, 2.0)) if force is None else force
    return Contact(r, math.inf, psi, f, float(rng.uniform(5.0, 18.0)), float(rng.uniform(6.0, 21.0)))


def build_suite(
    scenes: int,
    frames_per_scene: int = 4,
    kinds: tuple[str, ...] = KINDS,
    seed: int = 1,
    sensor: SensorModel | None = None,
    noise: NoiseModel = BENCH_NOISE,
) -> list[BenchFrame]:
    """``scenes`` scenes cycling over ``kinds``, each ``frames_per_scene`` frames long."""
    sensor = sensor or SensorModel()
    model = StrainModel(sensor, tol=1e-9)
    rng = np.random.default_rng(seed)
    out: list[BenchFrame] = []
    for s in range(scenes):
        kind = kinds[s % len(kinds)]
        c = random_contact(rng, kind, sensor)
        for _ in range(frames_per_scene):
            clean = model.predict(c)
            out.append(BenchFrame(s, kind, c, clean, add_noise(clean, noise, rng)))
            # the hand moves a little between frames: 20 um, 1 % force, 0.2 deg
            c = replace(
                c,
                x0=c.x0 + float(rng.normal(0, 0.02)),
                y0=c.y0 + float(rng.normal(0, 0.02)),
                force=c.force * float(math.exp(rng.normal(0, 0.01))),
                psi_deg=(c.psi_deg + float(rng.normal(0, 0.2))) % 180.0 if kind != "sphere" else 0.0,
            )
    return out

"""The foundation benchmarks: how good the fitter is against its bars.

Noise-free recovery from the independent reference integration, noisy efficiency (RMS error
over the Cramer-Rao bound, 2-sigma coverage), the paper's Table 1 in simulation, and speed.
"""
# 1. Noise-free frames: worst recovery errors of cylinders R 1-50 mm, psi 30-150 deg, 0.5-2 N
#    (bars: R 1 %, psi 0.2 deg, F 0.5 %, x/y 5 um).
# 2. Noisy frames (quantised to 0.001 plus Gaussian 0.0003): each parameter's RMS error over its
#    Cramer-Rao bound at F >= 0.5 N (bar: 1.2) and the fraction of errors inside 2 reported sigma
#    (bar: 93 %).
# 3. The paper's Table 1 in simulation: cylinders at 90 deg over tactel [2, 4].
# 4. Speed: cold cylinder fits (median, p99), general fits, warm cylinder fits.

from __future__ import annotations

import itertools
import math
import time

import numpy as np

from tactiled_bench.runner import Progress
from tactiled_bench.suite import BENCH_NOISE, issue_cylinder
from tactiled.sensors.model import SensorModel
from tactiled.fit.fitter import Fitter
from tactiled.fit.models import get_model
from tactiled.physics.contact import Contact
from tactiled.physics.reference import reference_strain
from tactiled.physics.strain import StrainModel
from tactiled.sim import add_noise

PARAMS = ("r1_mm", "angle_deg", "force_n", "x_mm", "y_mm")
UNITS = {"r1_mm": "%", "angle_deg": "deg", "force_n": "%", "x_mm": "um", "y_mm": "um"}

#: The paper's Table 1: true diameter (mm), force (N), its estimated diameter (mm).
PAPER_TABLE1 = [(0.3, 0.5, 1.1), (3, 0.5, 4.5), (7, 1.0, 7.0), (10, 1.0, 11.6), (14, 1.0, 14.2),
                (25, 1.0, 27.0), (32, 1.0, 30.8), (38, 1.0, 37.7), (66, 1.0, 60.6)]


def _err(k: str, est: float, true: float) -> float:
    if k in ("r1_mm", "force_n"):
        return 100.0 * (est / true - 1.0)
    if k == "angle_deg":
        return (est - true + 90.0) % 180.0 - 90.0
    return 1000.0 * (est - true)


def reference_cylinders(quick: bool) -> tuple[list[np.ndarray], list[float]]:
    """Noise-free frames of cylinders from the reference integration, and their radii."""
    rng = np.random.default_rng(5)
    frames, radii = [], []
    for r, psi, f in itertools.product((1.0, 5.0, 20.0, 50.0) if quick else (1.0, 3.0, 10.0, 25.0, 50.0),
                                       (30.0, 90.0, 150.0), (0.5, 2.0)):
        c = Contact(r, math.inf, psi, f, float(rng.uniform(4.0, 19.0)), float(rng.uniform(4.0, 23.0)))
        frames.append(reference_strain(c))
        radii.append(r)
    return frames, radii


def noise_free_recovery(quick: bool, progress: bool | None) -> str:
    radii = (1.0, 3.0, 10.0, 25.0, 50.0) if quick else (1.0, 2.0, 5.0, 10.0, 20.0, 35.0, 50.0)
    angles = (30.0, 90.0, 150.0) if quick else (30.0, 60.0, 90.0, 120.0, 150.0)
    forces = (0.5, 2.0) if quick else (0.5, 1.0, 2.0)
    rng = np.random.default_rng(4)
    fitter = Fitter()
    worst = dict.fromkeys(PARAMS, 0.0)
    where: dict[str, str] = {}
    cases = list(itertools.product(radii, angles, forces))
    bar = Progress(len(cases), "noise-free recovery", progress)
    for r, psi, f in cases:
        c = Contact(r, math.inf, psi, f, float(rng.uniform(4.0, 19.0)), float(rng.uniform(4.0, 23.0)))
        res = fitter.fit(reference_strain(c), "cylinder")
        truth = {"r1_mm": r, "angle_deg": psi, "force_n": f, "x_mm": c.x0, "y_mm": c.y0}
        for k in PARAMS:
            v = res.values[k]
            e = abs(_err(k, v, truth[k])) if v is not None else math.inf
            if e > worst[k]:
                worst[k], where[k] = e, f"R {r:g}, psi {psi:g}, F {f:g}"
        bar.step()
    bars = {"r1_mm": 1.0, "angle_deg": 0.2, "force_n": 0.5, "x_mm": 5.0, "y_mm": 5.0}
    lines = [f"{len(cases)} cylinders from the reference integration (R {min(radii):g}-{max(radii):g} mm, "
             f"psi {min(angles):g}-{max(angles):g} deg, F {min(forces):g}-{max(forces):g} N, random centres):", "",
             "| parameter | worst error | bar | worst case | pass |", "|---|---|---|---|---|"]
    for k in PARAMS:
        lines.append(f"| {k} | {worst[k]:.4f} {UNITS[k]} | {bars[k]:g} {UNITS[k]} | {where.get(k, '')} | "
                     f"{'yes' if worst[k] <= bars[k] else 'NO'} |")
    return "\n".join(lines)


def noisy_efficiency(quick: bool, progress: bool | None) -> tuple[str, dict[str, list[float]]]:
    sensor = SensorModel(noise=BENCH_NOISE)
    fitter = Fitter(sensor)
    model = StrainModel(sensor)
    rng = np.random.default_rng(8)
    scenes = 40 if quick else 200
    per_scene = 10 if quick else 20
    ratios = {k: [] for k in PARAMS}
    inside = {k: [] for k in PARAMS}
    times: list[float] = []
    bar = Progress(scenes, "noisy frames vs Cramer-Rao", progress)
    for _ in range(scenes):
        c = issue_cylinder(rng)
        clean = model.predict(c)
        truth = {"r1_mm": c.r1, "angle_deg": c.psi_deg, "force_n": c.force, "x_mm": c.x0, "y_mm": c.y0}
        p_true = get_model("cylinder").from_values(c.r1, c.r2, c.psi_deg, c.force, c.x0, c.y0)
        crb = fitter.cramer_rao(clean, "cylinder", p_true)
        errs = {k: [] for k in PARAMS}
        for _ in range(per_scene):
            t0 = time.perf_counter()
            res = fitter.fit(add_noise(clean, BENCH_NOISE, rng), "cylinder")
            times.append((time.perf_counter() - t0) * 1e3)
            for k in PARAMS:
                v, s = res.values[k], res.std[k]
                if v is None or s is None:
                    errs[k].append(math.inf)
                    inside[k].append(0.0)
                    continue
                e = v - truth[k]
                if k == "angle_deg":
                    e = (e + 90.0) % 180.0 - 90.0
                errs[k].append(e)
                inside[k].append(float(abs(e) < 2 * s))
        for k in PARAMS:
            e = np.array(errs[k])
            ratios[k].append(float(np.sqrt(np.mean(e * e))) / crb[k])
        bar.step()
    lines = [f"{scenes} cylinders (R 1-50 mm, psi 30-150 deg, F 0.5-2 N) x {per_scene} noisy frames each "
             "(Gaussian 0.0003 + quantisation 0.001; fitter sigma = sqrt(0.0003^2 + 0.001^2/12)):", "",
             "| parameter | RMS error / CRB, median over scenes | 90th pct | pooled | inside 2 reported sigma |",
             "|---|---|---|---|---|"]
    for k in PARAMS:
        r = np.array(ratios[k])
        pooled = float(np.sqrt(np.mean(r * r)))
        lines.append(f"| {k} | {np.median(r):.3f} | {np.percentile(r, 90):.3f} | {pooled:.3f} | "
                     f"{100 * np.mean(inside[k]):.1f} % |")
    return "\n".join(lines), {"times": times}


def paper_table1(quick: bool, progress: bool | None) -> str:
    sensor = SensorModel(noise=BENCH_NOISE)
    fitter = Fitter(sensor)
    model = StrainModel(sensor)
    rng = np.random.default_rng(11)
    n = 30 if quick else 200
    g = sensor.geometry
    lines = [f"Cylinders at 90 deg over tactel [2, 4] (x0 = {2 * g.dx:.1f}, y0 = {4 * g.dy:.1f} mm), "
             f"{n} noisy frames each (Gaussian 0.0003 + quantisation 0.001), cylinder model, 4x4 window:", "",
             "| true diam. mm | force N | est. diam. mean | sd | CRB sd | est. force mean | paper's est. diam. |",
             "|---|---|---|---|---|---|---|"]
    bar = Progress(len(PAPER_TABLE1), "paper's Table 1", progress)
    for diam, force, paper in PAPER_TABLE1:
        c = Contact(diam / 2, math.inf, 90.0, force, 2 * g.dx, 4 * g.dy)
        clean = model.predict(c)
        crb = fitter.cramer_rao(clean, "cylinder", get_model("cylinder").from_values(c.r1, c.r2, 90.0, force, c.x0, c.y0))
        d_est, f_est = [], []
        withheld = 0
        for _ in range(n):
            res = fitter.fit(add_noise(clean, BENCH_NOISE, rng), "cylinder")
            if res.values["r1_mm"] is None:
                withheld += 1
                continue
            d_est.append(2 * res.values["r1_mm"])
            f_est.append(res.values["force_n"])
        d = np.array(d_est)
        note = f" ({withheld} withheld)" if withheld else ""
        lines.append(f"| {diam:g} | {force:g} | {d.mean():.2f}{note} | {d.std():.2f} | {2 * crb['r1_mm']:.2f} | "
                     f"{np.mean(f_est):.3f} | {paper:g} |")
        bar.step()
    return "\n".join(lines)


def speed(quick: bool, progress: bool | None) -> str:
    sensor = SensorModel(noise=BENCH_NOISE)
    fitter = Fitter(sensor)
    model = StrainModel(sensor)
    rng = np.random.default_rng(21)
    n = 300 if quick else 2000
    frames = []
    for _ in range(n):
        c = issue_cylinder(rng)
        frames.append((c, add_noise(model.predict(c), BENCH_NOISE, rng)))
    out: dict[str, tuple[list[float], list[float]]] = {}
    bar = Progress(4, "speed", progress)

    def timed(fn) -> tuple[float, float]:
        w0, c0 = time.perf_counter(), time.thread_time()
        fn()
        return (time.thread_time() - c0) * 1e3, (time.perf_counter() - w0) * 1e3

    for label, mdl in (("cylinder, cold start", "cylinder"), ("general, cold start", "general"),
                       ("sphere, cold start", "sphere")):
        cpu, wall = [], []
        for _, f in frames:
            c, w = timed(lambda: fitter.fit(f, mdl))
            cpu.append(c)
            wall.append(w)
        out[label] = (cpu, wall)
        bar.step()
    # warm: the next frame of the same contact (fresh noise), started from the previous solution
    cpu, wall = [], []
    for c, f in frames:
        prev = fitter.fit(f, "cylinder")
        again = add_noise(model.predict(c), BENCH_NOISE, rng)
        ct, wt = timed(lambda: fitter.fit(again, "cylinder", start=np.array(prev.params)))
        cpu.append(ct)
        wall.append(wt)
    out["cylinder, warm start"] = (cpu, wall)
    bar.step()
    lines = [f"{n} noisy frames (cylinders R 1-50 mm, psi 30-150, 0.5-2 N), one thread; CPU time of the "
             "thread (what one core spends) and wall time (which also counts time the shared machine gave "
             "to other processes):", "",
             "| fit | CPU median ms | CPU p99 ms | wall median ms | wall p99 ms |", "|---|---|---|---|---|"]
    for label, (cpu, wall) in out.items():
        lines.append(f"| {label} | {np.median(cpu):.3f} | {np.percentile(cpu, 99):.3f} | "
                     f"{np.median(wall):.3f} | {np.percentile(wall, 99):.3f} |")
    return "\n".join(lines)

"""``tactiled bench --suite unexplained``: the fit's cost on frames the contact model cannot
explain, with its budget (:mod:`tactiled.fit.budget`) and without.

Seeded frame sets (simulated contacts, blobs, a hand print, random and saturated patterns, and
line sums on ``flat32``) are fitted as the daemon fits by two fitters taking turns frame by
frame, one with the default budget and one with none.  Figures are the fitting thread's CPU
time; ratios within one run are what compare.
"""
# Each set is fitted with model auto, the daemon's options and the sensor's learning on; the
# flat field's deferred re-solve runs outside the timing, as a worker runs it after its answer.
# - contacts: the simulated suite (cylinders, edges, spheres, ellipsoids; cold fits);
# - blobs: sums of 2-4 simulated contacts pressed at once, on the paper's 8x8 finger and on a
#   32x32 array;
# - hand print: a palm and four or five fingers' pads on a 32x32 array (2.5 mm pitch);
# - random: every tactel random (uniform strain up to a random level);
# - saturated: contacts clipped flat at 30-70 % of their peak (an array at the end of its
#   range), and rectangular steps of uniform strain;
# - on the built-in flat 32x32 mat (flat32): lines, sums of 2-3 cylinders pressed at once (line
#   contacts), and random patterns.
# Turns frame by frame, so a busy spell of a shared machine falls on both fitters.

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from tactiled_bench.runner import Progress
from tactiled_bench.suite import BENCH_NOISE, KINDS, build_suite, random_contact
from tactiled.sensors.model import Geometry, SensorModel
from tactiled.fit.budget import budget_spent
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.result import FitResult
from tactiled.fit.params import VALUE_KEYS
from tactiled.physics.contact import Contact, LineContact
from tactiled.physics.strain import StrainModel
from tactiled.sim import add_noise

#: A 32x32 array: a glove's or a palm's (2.5 mm pitch, nearly flat: a 1 m radius).
ARRAY_32 = SensorModel(geometry=Geometry(rows=32, cols=32, dx=2.5, dy=2.5, finger_radius=1000.0),
                       noise=BENCH_NOISE)
FINGER_8 = SensorModel(noise=BENCH_NOISE)


def blobs(sensor: SensorModel, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Sums of 2-4 random contacts (any kind) pressed at once."""
    model = StrainModel(sensor)
    out = []
    for _ in range(n):
        s = sum(model.predict(random_contact(rng, str(rng.choice(KINDS)), sensor))
                for _ in range(int(rng.integers(2, 5))))
        out.append(add_noise(s, sensor.noise, rng))
    return out


def hand_prints(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """A palm (a broad, soft ellipsoid) and 4-5 finger pads (ellipsoids along the fingers)
    on the 32x32 array, at random places, sizes and loads."""
    sensor = ARRAY_32
    model = StrainModel(sensor)
    g = sensor.geometry
    out = []
    for _ in range(n):
        cx = g.span_x * rng.uniform(0.35, 0.65)
        cy = g.span_y * rng.uniform(0.3, 0.5)
        parts = [Contact(float(rng.uniform(30, 80)), float(rng.uniform(60, 200)),
                         float(rng.uniform(0, 180)), float(rng.uniform(3, 12)), cx, cy)]
        for k in range(int(rng.integers(4, 6))):
            spread = (k - 2) * rng.uniform(6, 9)
            parts.append(Contact(float(rng.uniform(5, 12)), float(rng.uniform(15, 40)),
                                 float(rng.uniform(70, 110)), float(rng.uniform(0.3, 3)),
                                 cx + spread, cy + float(rng.uniform(22, 35))))
        s = sum(model.predict(c) for c in parts)
        out.append(add_noise(s, sensor.noise, rng))
    return out


def flat32() -> SensorModel:
    """The built-in flat 32x32 mat with the bench's noise."""
    from tactiled.sensors import load_description

    return replace(load_description("flat32").sensor_model(), noise=BENCH_NOISE)


def lines(sensor: SensorModel, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Sums of 2-3 cylinders pressed at once on a flat array (line contacts across it)."""
    model = StrainModel(sensor)
    g = sensor.geometry
    out = []
    for _ in range(n):
        s = sum(model.predict(LineContact(float(np.exp(rng.uniform(0.0, np.log(50.0)))),
                                          float(rng.uniform(0.0, 180.0)),
                                          float(rng.uniform(0.02, 0.3)),
                                          float(rng.uniform(0.2, 0.8) * g.span_x),
                                          float(rng.uniform(0.2, 0.8) * g.span_y)))
                for _ in range(int(rng.integers(2, 4))))
        out.append(add_noise(s, sensor.noise, rng))
    return out


def random_patterns(sensor: SensorModel, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    g = sensor.geometry
    return [rng.uniform(0.0, float(rng.uniform(0.005, 0.2)), (g.rows, g.cols)) for _ in range(n)]


def saturated(sensor: SensorModel, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Half contacts clipped flat at 30-70 % of their peak, half rectangles of uniform strain."""
    model = StrainModel(sensor)
    g = sensor.geometry
    out = []
    for i in range(n):
        if i % 2 == 0:
            c = random_contact(rng, str(rng.choice(KINDS)), sensor)
            c = replace(c, force=c.force * 3.0)
            s = model.predict(c)
            s = np.minimum(s, float(rng.uniform(0.3, 0.7)) * float(s.max()))
        else:
            s = np.zeros((g.rows, g.cols))
            r0, c0 = int(rng.integers(0, g.rows - 1)), int(rng.integers(0, g.cols - 1))
            s[r0:r0 + int(rng.integers(2, g.rows + 1)), c0:c0 + int(rng.integers(2, g.cols + 1))] = \
                float(rng.uniform(0.02, 0.3))
        out.append(add_noise(s, sensor.noise, rng))
    return out


def frame_sets(quick: bool, seed: int = 5) -> list[tuple[str, SensorModel, list[np.ndarray]]]:
    """``(name, sensor, frames)`` of every set the bench fits."""
    n = 20 if quick else 300
    rng = np.random.default_rng(seed)
    flat = flat32()
    contacts = [bf.strain for bf in build_suite(n // 2, 4, seed=seed,
                                                sensor=FINGER_8)]
    return [
        ("contacts 8x8", FINGER_8, contacts),
        ("blobs 8x8", FINGER_8, blobs(FINGER_8, rng, n)),
        ("blobs 32x32", ARRAY_32, blobs(ARRAY_32, rng, n)),
        ("hand print 32x32", ARRAY_32, hand_prints(rng, n)),
        ("random 8x8", FINGER_8, random_patterns(FINGER_8, rng, n)),
        ("random 32x32", ARRAY_32, random_patterns(ARRAY_32, rng, n)),
        ("saturated 8x8", FINGER_8, saturated(FINGER_8, rng, n)),
        ("saturated 32x32", ARRAY_32, saturated(ARRAY_32, rng, n)),
        ("lines flat32", flat, lines(flat, rng, n)),
        ("random flat32", flat, random_patterns(flat, rng, n)),
    ]


def daemon_options(**budget) -> FitOptions:
    """The daemon's fit options (``tactiled.pipeline.sensor.worker_fit_options``) with
    ``budget`` (``budget_iterations``, ``budget_work``) overriding the defaults."""
    from tactiled.pipeline.sensor import worker_fit_options

    return FitOptions(**{**dict(worker_fit_options(4)), **budget})


def _stats(times: list[float]) -> str:
    t = np.array(times)
    return f"{np.median(t):.3f} | {np.percentile(t, 99):.3f} | {t.max():.3f}"


def run(quick: bool, progress: bool | None) -> str:
    sets = frame_sets(quick)
    configs = (("budget", {}), ("none", {"budget_iterations": None, "budget_work": None}))
    opts = daemon_options()
    lines = [f"Each set fitted as the daemon fits (model auto; budget: {opts.budget_iterations} "
             f"iterations, {opts.budget_work} work units per fit), CPU ms of the fitting thread; "
             "'none': no budget (every fit before it).  converged / budget / withheld: share of "
             "the contact fits converged, stopped by their budget, with every value withheld.", "",
             "| frames | n | budget | CPU ms median | p99 | max | iterations max | converged | "
             "budget spent | withheld |", "|---|---|---|---|---|---|---|---|---|---|"]
    bar = Progress(sum(len(f) for _, _, f in sets), "unexplained", progress)
    for name, sensor, frames in sets:
        fitters = [Fitter(sensor, daemon_options(**cfg)) for _, cfg in configs]
        acc = [{"t": [], "it": [], "conv": 0, "spent": 0, "withheld": 0, "n": 0} for _ in configs]
        order = np.random.default_rng(0)
        for frame in frames:
            for i in order.permutation(len(configs)):
                fitter, a = fitters[i], acc[i]
                t0 = time.thread_time()
                res = fitter.fit(frame, "auto")
                a["t"].append((time.thread_time() - t0) * 1e3)
                fitter.catch_up()  # a worker's learning, after its answer: not the fit's time
                if not res.contact:
                    continue
                a["n"] += 1
                a["it"].append(res.iterations)
                a["conv"] += res.converged
                a["spent"] += budget_spent(res.reasons)
                a["withheld"] += all(res.values.get(k) is None for k in VALUE_KEYS)
            bar.step()
        for (label, _), a in zip(configs, acc):
            m = max(a["n"], 1)
            lines.append(f"| {name} | {len(frames)} | {label} | {_stats(a['t'])} | "
                         f"{max(a['it'], default=0)} | {100 * a['conv'] / m:.0f} % | "
                         f"{100 * a['spent'] / m:.0f} % | {100 * a['withheld'] / m:.0f} % |")
    bar.finish("unexplained: done")
    return "\n".join(lines)


def budget_check(quick: bool = True, seed: int = 5,
                 results: list[tuple[str, FitResult]] | None = None) -> list[str]:
    """Every budgeted fit of the frame sets (``frame_sets(quick, seed)``) against its budget:
    the problems found (empty when each fit stayed within its iterations and work, and each fit
    the budget stopped says so, not converged, with its values withheld or its sigmas
    widened).  ``results``, if given, receives each fit's ``(set name, result)``."""
    problems = []
    opts = daemon_options()
    for name, sensor, frames in frame_sets(quick, seed):
        fitter = Fitter(sensor, opts)
        for i, frame in enumerate(frames):
            res = fitter.fit(frame, "auto")
            if results is not None:
                results.append((name, res))
            fitter.catch_up()
            its, work = fitter.spent
            max_its, max_work = fitter.budget_limits  # a flat array's are larger
            where = f"{name} frame {i}"
            if res.iterations > max_its or its > max_its:
                problems.append(f"{where}: {res.iterations} iterations over the budget")
            if work > max_work:
                problems.append(f"{where}: work {work:.0f} over the budget")
            if budget_spent(res.reasons) and res.converged:
                problems.append(f"{where}: budget spent yet converged")
            if not math.isfinite(res.fit_ms):
                problems.append(f"{where}: no fit time")
    return problems

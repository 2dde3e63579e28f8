"""Where a fit worker's memory goes: many varied fits in one process, measured as they run.

    python -m tactiled_bench.worker_memory --fits 20000 --every 1000
    python -m tactiled_bench.worker_memory --fits 5000 --tracemalloc --json

Fits the busy scene as a fit worker does and, every ``--every`` fits, records RSS, the malloc
books, the largest Python allocation growth and the cache sizes; growth is the slope after
``--warmup`` fits, in MB per 1000 fits.
"""
# The probe builds the fitter a worker (tactiled.pipeline.worker, a process doing nothing but
# Fitter.fit) builds for a default sensor (window 4, radius withheld beyond 0.5 relative sigma),
# and feeds it tactiled_bench.scenes.busy_scene (pressing, rolling, turning and changing shape
# all the time, so nearly every frame is a fit meeting new contact sizes and models), with warm
# starts as the daemon gives them.  Each sample:
# * the RSS, glibc malloc's books (bytes in use, free but kept, mmapped, arenas) and pymalloc's
#   (arenas, live bytes): tactiled.heapstats;
# * with --tracemalloc, the Python allocations that grew most since the first sample (by file
#   and line);
# * the sizes of the quadrature-rule caches (tactiled.physics.strain) and the start tables.
# The warm-up lets caches that fill on first use fill; the slope is a line fitted to the later
# samples.

from __future__ import annotations

import argparse
import gc
import json
import sys
import time
import tracemalloc
from typing import Any

import numpy as np

SKIP = 5  # fit every 5th tick of a 1 kHz finger: what latest-wins leaves a busy worker


def frames(count: int, seed: int = 1) -> Any:
    """Zeroed strain frames of the busy scene (every ``SKIP``-th tick at 1 kHz), with the true
    contact: ``(strain, contact)`` pairs, generated lazily."""
    from tactiled_bench.scenes import busy_scene
    from tactiled.sim import FingerSimulator

    sim = FingerSimulator(scene=busy_scene(), seed=seed, rate_hz=1000.0, drift=None, loop=True)
    for _ in range(count):
        tick = sim.step()
        sim.skip(SKIP - 1)
        yield np.array(tick.strain), tick.contact


def _slope(points: list[tuple[float, float]]) -> float | None:
    if len(points) < 3:
        return None
    xs = np.array([p[0] for p in points])
    ys = np.array([p[1] for p in points])
    return float(np.polyfit(xs, ys, 1)[0])


def probe(fits: int, every: int, warmup: int, use_tracemalloc: bool = False,
          model: str = "auto", seed: int = 1, top: int = 12) -> dict[str, Any]:
    """Run ``fits`` fits, sampling every ``every``; a JSON-ready report."""
    from tactiled.sensors.model import NoiseModel, SensorModel
    from tactiled.fit.fitter import FitOptions, Fitter
    from tactiled.pipeline.sensor import worker_fit_options
    from tactiled.heapstats import fitter_cache_figures, heap_figures

    sensor = SensorModel(noise=NoiseModel(sigma=0.0005))
    fitter = Fitter(sensor, FitOptions(**dict(worker_fit_options(4))))  # the daemon's workers' options
    if use_tracemalloc:
        tracemalloc.start(8)
    warm = None
    samples: list[dict[str, Any]] = []
    first_snapshot = None
    t0 = time.perf_counter()
    done = 0
    models: dict[str, int] = {}
    for strain, contact in frames(10**12, seed):
        if contact is None:  # the gate answers these without a fit
            warm = None
            continue
        res = fitter.fit(strain, model, warm=warm, budget_s=0.5)
        models[str(res.model)] = models.get(str(res.model), 0) + 1
        warm = (res.model, res.params) if res.converged and res.params and res.model else None
        done += 1
        if done % every == 0 or done == fits:
            gc.collect()
            row: dict[str, Any] = {"fits": done, "s": round(time.perf_counter() - t0, 1),
                                   **heap_figures(), "objects": len(gc.get_objects())}
            row.update(fitter_cache_figures())
            if use_tracemalloc:
                row["traced_mb"] = round(tracemalloc.get_traced_memory()[0] / 2**20, 3)
                if done >= warmup and first_snapshot is None:
                    first_snapshot = tracemalloc.take_snapshot()
            samples.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
        if done >= fits:
            break
    report: dict[str, Any] = {"fits": done, "every": every, "warmup_fits": warmup,
                              "model": model, "fitted_models": models,
                              "seconds": round(time.perf_counter() - t0, 1),
                              "samples": samples,
                              "caches": fitter_cache_figures()}
    later = [s for s in samples if s["fits"] >= warmup]
    report["slope_mb_per_1000_fits"] = {
        key: (None if (v := _slope([(s["fits"] / 1000.0, s[key]) for s in later if key in s]))
              is None else round(v, 4))
        for key in ("rss_mb", "rss_anon_mb", "rss_file_mb", "cache_rule_mb", "malloc_in_use_mb", "malloc_free_kept_mb", "malloc_mmapped_mb",
                    "malloc_arena_system_mb", "pymalloc_live_mb", "traced_mb")
        if any(key in s for s in later)}
    if use_tracemalloc and first_snapshot is not None:
        last = tracemalloc.take_snapshot()
        stats = last.compare_to(first_snapshot, "lineno")
        report["tracemalloc_growth"] = [
            {"where": str(st.traceback[0]), "size_diff_kb": round(st.size_diff / 1024, 1),
             "count_diff": st.count_diff} for st in stats[:top]]
        tracemalloc.stop()
    return report


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fits", type=int, default=20000, help="fits to run (default 20000)")
    p.add_argument("--every", type=int, default=1000, help="sample every N fits")
    p.add_argument("--warmup", type=int, default=2000,
                   help="fits before growth is judged (default 2000)")
    p.add_argument("--model", default="auto", help="model to fit (default auto)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--tracemalloc", action="store_true",
                   help="trace Python allocations (slower) and report the lines that grew")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    args = p.parse_args(argv)
    report = probe(args.fits, args.every, args.warmup, args.tracemalloc, args.model, args.seed)
    if args.json:
        print(json.dumps(report))
    else:
        print(f"{report['fits']} fits in {report['seconds']} s ({report['fitted_models']})")
        print("slopes after warm-up, MB per 1000 fits:", report["slope_mb_per_1000_fits"])
        print("caches:", report["caches"])
        for row in report.get("tracemalloc_growth", []):
            print(f"  {row['size_diff_kb']:>9} KB {row['count_diff']:>7} blocks  {row['where']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

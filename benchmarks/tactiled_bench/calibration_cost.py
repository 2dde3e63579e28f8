"""Per-frame cost of the calibration stage: ``python -m tactiled_bench.calibration_cost`` (or
``tactiled calibrate --bench``).

Each timing is the minimum, over many short bursts of distinct pre-generated frames, of the
mean time per frame in a burst (the ``timeit`` convention: the code's cost, not the machine's
load); the median burst is reported too, as what a loaded machine gives.
"""
# Bursts are `burst` frames, about a millisecond each; longer or averaged runs also measure
# whatever else the machine was doing.  Speed is shown here, not asserted in tests, where shared
# CI machines make timings meaningless.

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from tactiled.calibration.detection import ContactDetector
from tactiled.calibration.lut import LookupTable
from tactiled.calibration.zeroing import Zeroer

BUDGET_LINEARISE_US = 20.0  # the requirement for one 8x8 frame


def _table(knots: int, rows: int, cols: int, seed: int) -> LookupTable:
    rng = np.random.default_rng(seed)
    counts, strain = [], []
    for _ in range(rows * cols):
        knot_counts = rng.choice(np.arange(5000, 40000), knots, replace=False)
        counts.append(np.sort(knot_counts).astype(float))
        strain.append(np.sort(rng.uniform(0.0, 0.2, knots)))
    return LookupTable(rows, cols, counts, strain)


def _timed_us(fn: Callable[[np.ndarray], object], frames: list[np.ndarray], repeats: int,
              burst: int = 100) -> tuple[float, float]:
    """(best, median) microseconds per call over ``repeats`` passes of bursts of ``burst``."""
    for f in frames[:burst]:  # warm caches and lazily built state
        fn(f)
    per_call = []
    for _ in range(repeats):
        for start in range(0, len(frames) - burst + 1, burst):
            chunk = frames[start:start + burst]
            t0 = time.perf_counter()
            for f in chunk:
                fn(f)
            per_call.append((time.perf_counter() - t0) / burst)
    return min(per_call) * 1e6, float(np.median(per_call)) * 1e6


def bench_linearise(
    knots: int = 8, n_frames: int = 2000, repeats: int = 10, rows: int = 8, cols: int = 8,
    seed: int = 0,
) -> float:
    """Microseconds to linearise one ``(rows, cols)`` uint16 frame with ``knots`` knots per
    tactel (random monotone tables, random counts covering and exceeding the knots): the best
    burst (see the module docstring)."""
    return bench_linearise_stats(knots, n_frames, repeats, rows, cols, seed)[0]


def bench_linearise_stats(
    knots: int = 8, n_frames: int = 2000, repeats: int = 10, rows: int = 8, cols: int = 8,
    seed: int = 0,
) -> tuple[float, float]:
    """``(best, median)`` microseconds per frame; arguments as :func:`bench_linearise`."""
    table = _table(knots, rows, cols, seed)
    rng = np.random.default_rng(seed + 1)
    frames = list(rng.integers(0, 1 << 16, (n_frames, rows, cols), dtype=np.uint16))
    return _timed_us(table.to_strain, frames, repeats)


def bench_all(n_frames: int = 2000, repeats: int = 10, seed: int = 0
              ) -> dict[str, tuple[float, float]]:
    """``(best, median)`` per-frame microseconds of each calibration step on 8x8 frames."""
    rng = np.random.default_rng(seed)
    out = {f"linearise ({k} knots/tactel)": bench_linearise_stats(k, n_frames, repeats, seed=seed)
           for k in (2, 8, 32)}
    table = LookupTable.linear()
    strain = list(rng.normal(0.0, 0.0005, (n_frames, 8, 8)))
    out["to_counts (inverse, 2 knots)"] = _timed_us(table.to_counts, strain, repeats)
    detector = ContactDetector()
    out["contact decision, empty frame"] = _timed_us(detector.update, strain, repeats)
    zeroer = Zeroer(settle=0.0)  # time the steady state, with the detector running
    clock = iter(range(10**9))
    out["zeroing incl. contact decision"] = _timed_us(
        lambda f: zeroer.update(f, next(clock) * 0.001), strain, repeats)
    return out


def main() -> int:
    results = bench_all()
    print(f"{'8x8 frame, per call':34s} {'best':>8s} {'median':>8s}")
    for name, (best, median) in results.items():
        print(f"{name:34s} {best:6.2f}us {median:6.2f}us")
    lin = results["linearise (8 knots/tactel)"][0]
    verdict = "within" if lin <= BUDGET_LINEARISE_US else "OVER"
    print(f"linearisation budget {BUDGET_LINEARISE_US:.0f} us/frame: {verdict} ({lin:.2f} us)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

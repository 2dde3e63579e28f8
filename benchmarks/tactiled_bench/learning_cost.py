"""What learning the finger costs a daemon worker's fits (docs/performance/benchmarks.md).

    python -m tactiled_bench.learning_cost [--fits 1000] [--rounds 4] [--warmup 2000]

CPU time per cylinder fit of a learning fitter with its flat field and without, in interleaved
rounds; the ratio is what counts.  Run it as a worker runs (``OPENBLAS_NUM_THREADS=1``).
"""
# A worker's fitter learns its finger as it fits (FitOptions(learn_floor=True): the model-error
# floor, tactiled.fit.floor, and the flat field, tactiled.fit.flatfield).  Fingers: the paper's
# (the flat field stays off: what it costs to watch) and one with 5 % gains and 0.1 mm
# displacements (on: what correcting costs), after --warmup fits.  OPENBLAS_NUM_THREADS=1 is
# what the worker pool sets: a BLAS thread pool spins on the other core and bills this process.

from __future__ import annotations

import argparse
import time

import numpy as np


def measure(fits: int, rounds: int, warmup: int) -> list[str]:
    """Markdown table rows: per finger, ms of CPU per fit with and without the flat field."""
    from tactiled_bench.identify import FRAME_SIGMA, nominal_fitter, test_cylinder
    from tactiled.sensors.model import NoiseModel
    from tactiled.sensors.finger import FingerSpec
    from tactiled.physics.strain import StrainModel

    rows = ["| finger | flat field | ms per fit, with it | without it | ratio | rounds with / without |",
            "|---|---|---|---|---|---|"]
    fingers = (("the paper's", FingerSpec()),
               ("5 % gains, 0.1 mm", FingerSpec(gain_error=0.05, position_error=0.1, seed=6)))
    for name, spec in fingers:
        truth = StrainModel(spec.sensor(noise=NoiseModel(FRAME_SIGMA)))
        linearise = nominal_fitter(spec)[1]
        rng = np.random.default_rng(1)
        frames = [linearise(spec.to_counts(truth.predict(test_cylinder(rng))
                                           + rng.normal(0.0, FRAME_SIGMA, (8, 8))))
                  for _ in range(warmup + fits)]
        fitters = {}
        for label in ("with", "without"):
            fitter = nominal_fitter(spec)[0]
            if label == "without":
                fitter.flat = None
            for frame in frames[:warmup]:
                fitter.fit(frame, "cylinder")
            fitters[label] = fitter
        took: dict[str, list[float]] = {"with": [], "without": []}
        for r in range(rounds):
            for label in (("with", "without") if r % 2 == 0 else ("without", "with")):
                fitter = fitters[label]
                t0 = time.process_time()
                for frame in frames[warmup:]:
                    fitter.fit(frame, "cylinder")
                took[label].append((time.process_time() - t0) / fits * 1e3)
        w, wo = float(np.median(took["with"])), float(np.median(took["without"]))
        state = "on" if fitters["with"].flat.active else "off"
        rows.append(f"| {name} | {state} | {w:.3f} | {wo:.3f} | {w / wo:.2f} | "
                    + " ".join(f"{v:.3f}" for v in took["with"]) + " / "
                    + " ".join(f"{v:.3f}" for v in took["without"]) + " |")
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fits", type=int, default=1000, help="fits per round (default 1000)")
    p.add_argument("--rounds", type=int, default=4, help="rounds of each, alternating (default 4)")
    p.add_argument("--warmup", type=int, default=2000,
                   help="fits before measuring (default 2000: the flat field's solves settled)")
    args = p.parse_args(argv)
    print("\n".join(measure(args.fits, args.rounds, args.warmup)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

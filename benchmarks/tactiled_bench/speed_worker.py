"""A fit server for ``tactiled bench --suite speed``: times fits of whatever ``tactiled`` is
importable (this tree, or a baseline revision's checkout on PYTHONPATH).

``python speed_worker.py FRAMES.npz`` answers each stdin line ``KIND START STOP`` with one JSON
line: the CPU time (ms, ``time.thread_time``) and model evaluations of every fit of that kind on
frames ``START:STOP``, and the CPU time of one forward-model evaluation at the solution.
"""
# It uses only the fitter's long-stable public API (Fitter(sensor).fit(frame, model, start=,
# warm=)), so an older revision runs it unchanged.

from __future__ import annotations

import json
import sys
import time

if __name__ == "__main__":
    sys.path.pop(0)  # this file's folder is not where tactiled is to be found

import numpy as np  # noqa: E402

KINDS = ("cylinder-cold", "cylinder-warm", "general-cold", "auto-cold", "auto-warm")


def main(path: str) -> int:
    from tactiled_bench.suite import BENCH_NOISE
    from tactiled.sensors.model import SensorModel
    from tactiled.fit.fitter import Fitter
    from tactiled.fit.models import get_model

    data = np.load(path)
    frames, again = data["frames"], data["again"]
    fitter = Fitter(SensorModel(noise=BENCH_NOISE))

    def eval_cost(frame: np.ndarray, model: str, params) -> float:
        if not params:
            return float("nan")
        residual = fitter._problem(frame, get_model(model), None)[0]
        p = np.asarray(params, dtype=float)
        residual(p)
        c0 = time.thread_time()
        for _ in range(20):
            residual(p)
        return (time.thread_time() - c0) / 20 * 1e3

    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        kind, lo, hi = line.split()
        cpu, evals, cost = [], [], []
        for i in range(int(lo), int(hi)):
            model = kind.split("-")[0]
            if kind.endswith("warm"):  # the next frame of the same contact, from this one's fit
                prev = fitter.fit(frames[i], model)
                frame = again[i]
                kw = ({"warm": (prev.model, prev.params)} if model == "auto"
                      else {"start": np.array(prev.params)})
            else:
                frame, kw = frames[i], {}
            c0 = time.thread_time()
            res = fitter.fit(frame, model, **kw)
            cpu.append((time.thread_time() - c0) * 1e3)
            evals.append(res.evaluations)
            if i % 10 == 0:
                cost.append(eval_cost(frame, res.model or "cylinder", res.params))
        print(json.dumps({"cpu": cpu, "evals": evals, "eval_ms": cost}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))

"""``tactiled bench --suite speed [--baseline REV]``: the fitter's CPU time per fit, against a
baseline revision, interleaved in one run.

Two fit servers (``speed_worker.py``), this tree and a ``git archive`` of ``REV``, fit the same
noisy frames in alternating batches, so whatever else the machine does falls on both; the ratios
are what count.
"""
# Frames: cylinders R 1-50 mm, psi 30-150 deg, 0.5-2 N, as the foundation bench.  REV is archived
# into a temporary folder, so the repository's own worktree is not touched.  Batches of 25 frames
# alternate kind by kind.  Per kind: median and p99 CPU ms, the median number of model
# evaluations, the CPU time of one evaluation at the solution, and their product: the floor a
# fit of that many evaluations could reach with nothing else to do.

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from tactiled_bench.checkout import build, checkout, checkout_env
from tactiled_bench.runner import Progress
from tactiled_bench.speed_worker import KINDS
from tactiled_bench.suite import BENCH_NOISE, issue_cylinder
from tactiled.sensors.model import SensorModel
from tactiled.physics.strain import StrainModel
from tactiled.sim import add_noise

BATCH = 25
HERE = Path(__file__).resolve()
ROOT = HERE.parents[2]


class _Server:
    def __init__(self, tree: str, frames: str, label: str) -> None:
        env = checkout_env(tree, build(tree))
        self.label = label
        self.proc = subprocess.Popen([sys.executable, str(HERE.with_name("speed_worker.py")), frames],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env,
                                     cwd=tree)
        ready = self.proc.stdout.readline()
        if not ready:
            raise RuntimeError(f"the {label} fit server did not start")

    def run(self, kind: str, lo: int, hi: int) -> dict:
        self.proc.stdin.write(f"{kind} {lo} {hi}\n")
        self.proc.stdin.flush()
        return json.loads(self.proc.stdout.readline())

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=30)


def run(quick: bool, progress: bool | None, baseline: str | None) -> str:
    n = 300 if quick else 2000
    rng = np.random.default_rng(21)
    model = StrainModel(SensorModel(noise=BENCH_NOISE))
    frames, again = [], []
    for _ in range(n):
        c = issue_cylinder(rng)
        clean = model.predict(c)
        frames.append(add_noise(clean, BENCH_NOISE, rng))
        again.append(add_noise(clean, BENCH_NOISE, rng))
    with tempfile.TemporaryDirectory(prefix="tactiled-speed-") as tmp:
        path = str(Path(tmp) / "frames.npz")
        np.savez(path, frames=np.array(frames), again=np.array(again))
        servers = [_Server(str(ROOT), path, "this tree")]
        if baseline:
            servers.append(_Server(checkout(baseline, tmp), path, f"baseline {baseline}"))
        out: dict[tuple[str, str], dict[str, list[float]]] = {}
        bar = Progress(len(KINDS) * n * len(servers), "speed", progress)
        try:
            for kind in KINDS:
                for lo in range(0, n, BATCH):
                    hi = min(n, lo + BATCH)
                    order = servers if (lo // BATCH) % 2 == 0 else servers[::-1]
                    for srv in order:
                        got = srv.run(kind, lo, hi)
                        acc = out.setdefault((kind, srv.label), {"cpu": [], "evals": [], "eval_ms": []})
                        for key in acc:
                            acc[key] += got[key]
                        bar.step(hi - lo)
        finally:
            for srv in servers:
                srv.close()
    lines = [f"{n} noisy frames (cylinders R 1-50 mm, psi 30-150 deg, 0.5-2 N; noise as the foundation "
             f"bench), batches of {BATCH} alternating between the fit servers; CPU time of the fitting "
             "thread:", "",
             "| fit | code | CPU median ms | CPU p99 ms | ratio to baseline (median) | evaluations (median) "
             "| one evaluation ms | floor = evaluations x evaluation ms |",
             "|---|---|---|---|---|---|---|---|"]
    for kind in KINDS:
        base = out.get((kind, servers[-1].label)) if baseline else None
        for srv in servers:
            d = out[(kind, srv.label)]
            med = float(np.median(d["cpu"]))
            ratio = f"{med / float(np.median(base['cpu'])):.2f}" if base and srv is not servers[-1] else ""
            ev = float(np.median(d["evals"]))
            one = float(np.nanmedian(d["eval_ms"])) if d["eval_ms"] else float("nan")
            lines.append(f"| {kind} | {srv.label} | {med:.3f} | {float(np.percentile(d['cpu'], 99)):.3f} | "
                         f"{ratio} | {ev:g} | {one:.4f} | {ev * one:.3f} |")
    return "\n".join(lines)

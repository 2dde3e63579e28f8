"""Run estimators over a suite and summarise run time against error."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from tactiled_bench.estimators import Estimator
from tactiled_bench.suite import BenchFrame
from tactiled.fit.fitter import Fitter
from tactiled.fit.models import get_model
from tactiled.progress import Progress  # the suites import it from here too

PARAMS = ("r1_mm", "angle_deg", "force_n", "x_mm", "y_mm")


@dataclass
class Truth:
    """Ground truth of a frame in user units and its Cramer-Rao bounds (at the truth)."""

    values: dict[str, float | None]
    crb: dict[str, float | None]


def truth_of(frame: BenchFrame, fitter: Fitter) -> Truth:
    c = frame.contact
    model = "sphere" if frame.kind == "sphere" else ("general" if frame.kind == "general" else "cylinder")
    p = get_model(model).from_values(c.r1, c.r2, c.psi_deg, c.force, c.x0, c.y0)
    crb = fitter.cramer_rao(frame.strain, model, p)
    values = {"r1_mm": c.r1, "angle_deg": c.psi_deg if frame.kind in ("cylinder", "edge", "general") else None,
              "force_n": c.force, "x_mm": c.x0, "y_mm": c.y0,
              "r2_mm": c.r2 if frame.kind == "general" else None}
    return Truth(values, crb)


def error(key: str, est: float | None, true: float | None) -> float | None:
    """Signed error in reporting units: % for radius and force, degrees, micrometres."""
    if est is None or true is None:
        return None
    if key in ("r1_mm", "r2_mm", "force_n"):
        return 100.0 * (est / true - 1.0)
    if key == "angle_deg":
        return (est - true + 90.0) % 180.0 - 90.0
    return 1000.0 * (est - true)


def crb_in_units(key: str, crb: float | None, true: float | None) -> float | None:
    if crb is None or true is None:
        return None
    if key in ("r1_mm", "r2_mm", "force_n"):
        return 100.0 * crb / true
    if key == "angle_deg":
        return crb
    return 1000.0 * crb


#: Where the truth's own bound says a quantity is not measurable, its error says nothing about
#: an estimator; such frames are left out of that quantity's statistics (and counted).
OBSERVABLE_RELATIVE = 0.5  # radius: bound below 50 % of the radius
OBSERVABLE_ANGLE = 20.0  # degrees


@dataclass
class Row:
    name: str
    description: str
    times_ms: list[float] = field(default_factory=list)  # CPU time of this thread
    wall_ms: list[float] = field(default_factory=list)
    errors: dict[str, list[float]] = field(default_factory=lambda: {k: [] for k in PARAMS})
    ratios: dict[str, list[float]] = field(default_factory=lambda: {k: [] for k in PARAMS})
    missing: dict[str, int] = field(default_factory=lambda: dict.fromkeys(PARAMS, 0))
    #: worst radius error (%) on noise-free frames from the reference integration: the model's
    #: own bias, which noisy frames hide
    noise_free_radius: float | None = None

    def time_stats(self) -> tuple[float, float]:
        """Median and 99th percentile of CPU time per frame (ms)."""
        t = np.array(self.times_ms)
        return float(np.median(t)), float(np.percentile(t, 99))

    def wall_median(self) -> float:
        return float(np.median(self.wall_ms))

    def err_stats(self, key: str) -> tuple[float, float] | None:
        e = np.abs(np.array(self.errors[key]))
        if e.size == 0:
            return None
        return float(np.median(e)), float(np.percentile(e, 90))

    def rms_over_crb(self) -> float:
        """Root-mean-square of error / Cramer-Rao bound over all parameters and frames."""
        r = np.concatenate([np.array(v) for v in self.ratios.values() if v])
        return float(math.sqrt(np.mean(r * r))) if r.size else math.inf


def observable(key: str, truth: Truth) -> bool:
    t, b = truth.values.get(key), truth.crb.get(key)
    if t is None or b is None:
        return False
    if key in ("r1_mm", "r2_mm"):
        return b / t < OBSERVABLE_RELATIVE
    if key == "angle_deg":
        return b < OBSERVABLE_ANGLE
    return True


def run_estimators(
    estimators: list[Estimator], frames: list[BenchFrame], truths: list[Truth], progress: bool | None = None
) -> list[Row]:
    """Run every estimator on every frame.  Estimators take turns frame by frame, so a busy
    spell on the (shared) machine slows all of them alike and their time ratios stay fair; and
    the time compared is the thread's CPU time (``time.thread_time``), which other processes
    on a shared machine disturb far less than wall time.  Wall time is reported beside it."""
    rows = [Row(est.name, est.description) for est in estimators]
    for est in estimators:
        est.estimate(frames[0].strain)  # warm caches outside the timing
    bar = Progress(len(frames), "configurations", progress)
    scene = None
    pairs = list(zip(estimators, rows))
    order_rng = np.random.default_rng(0)
    for bf, truth in zip(frames, truths):
        if bf.scene != scene:
            for est in estimators:
                est.reset()
            scene = bf.scene
        # a fresh random order each frame: no estimator always goes first (paying the new
        # frame's cache misses) or always follows the same neighbour (inheriting its cache)
        for idx in order_rng.permutation(len(pairs)):
            est, row = pairs[idx]
            w0, t0 = time.perf_counter(), time.thread_time()
            vals = est.estimate(bf.strain)
            row.times_ms.append((time.thread_time() - t0) * 1e3)
            row.wall_ms.append((time.perf_counter() - w0) * 1e3)
            for k in PARAMS:
                if not observable(k, truth):
                    continue
                e = error(k, vals.get(k), truth.values[k])
                if e is None:
                    row.missing[k] += 1
                    continue
                row.errors[k].append(e)
                b = crb_in_units(k, truth.crb[k], truth.values[k])
                if b:
                    row.ratios[k].append(e / b)
        bar.step()
    return rows


def noise_free_bias(estimators: list[Estimator], rows: list[Row], frames: list[np.ndarray], radii: list[float]) -> None:
    """Fill each row's ``noise_free_radius``: the worst radius error (%) on noise-free frames
    (each judged alone)."""
    for est, row in zip(estimators, rows):
        worst = 0.0
        for frame, r in zip(frames, radii):
            est.reset()
            v = est.estimate(frame).get("r1_mm")
            worst = max(worst, math.inf if v is None else abs(v / r - 1.0) * 100.0)
        row.noise_free_radius = worst


def pareto_front(rows: list[Row]) -> list[bool]:
    """True where no other row is at least as good on every objective and strictly better on
    one.  Objectives: median CPU time, RMS error / CRB on noisy frames, and the worst radius
    error on noise-free frames (the model's own bias, invisible under noise: without it any
    coarser forward model would look free)."""
    def objectives(r: Row) -> tuple[float, ...]:
        bias = r.noise_free_radius if r.noise_free_radius is not None else math.inf
        return (r.time_stats()[0], r.rms_over_crb(), bias)

    pts = [objectives(r) for r in rows]
    out = []
    for i, p in enumerate(pts):
        dominated = any(
            all(q[k] <= p[k] for k in range(3)) and any(q[k] < p[k] for k in range(3))
            for j, q in enumerate(pts) if j != i
        )
        out.append(not dominated)
    return out


def markdown_table(rows: list[Row]) -> str:
    front = pareto_front(rows)
    head = ("| configuration | CPU ms median | CPU ms p99 | wall ms median | radius % med / p90 | angle deg med / p90 | "
            "force % med / p90 | x um med / p90 | y um med / p90 | RMS err / CRB | noise-free radius % worst | Pareto |")
    lines = [head, "|" + "---|" * 12]

    def cell(row: Row, k: str) -> str:
        st = row.err_stats(k)
        miss = f" ({row.missing[k]} n/a)" if row.missing[k] else ""
        if st is None:
            return "n/a" + miss
        fmt = "{:.2f} / {:.2f}" if k in ("angle_deg", "force_n") else "{:.1f} / {:.1f}"
        return fmt.format(*st) + miss

    for row, on in zip(rows, front):
        t50, t99 = row.time_stats()
        lines.append(
            f"| {row.name} | {t50:.3f} | {t99:.3f} | {row.wall_median():.3f} | {cell(row, 'r1_mm')} | {cell(row, 'angle_deg')} | "
            f"{cell(row, 'force_n')} | {cell(row, 'x_mm')} | {cell(row, 'y_mm')} | "
            f"{row.rms_over_crb():.3f} | "
            f"{'-' if row.noise_free_radius is None else f'{row.noise_free_radius:.3f}'} | {'yes' if on else 'no'} |"
        )
    return "\n".join(lines)


def pareto_plot(rows: list[Row], path: str) -> None:
    """Median CPU time against RMS error / CRB, one numbered point per row (red: on the
    three-objective Pareto front), with a zoom on the full fits (needs matplotlib:
    ``pip install 'tactiled[plot]'``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    front = pareto_front(rows)
    pts = [(r.time_stats()[0], r.rms_over_crb()) for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.5), gridspec_kw={"width_ratios": [1, 1.3]})
    fits = [i for i, (_, a) in enumerate(pts) if a < 2.0]
    for ax, idx, title in ((axes[0], range(len(rows)), "all configurations"),
                           (axes[1], fits, "the full fits (zoom)")):
        for i in idx:
            t, a = pts[i]
            ax.scatter([t], [a], color="tab:red" if front[i] else "tab:gray", zorder=3)
            ax.annotate(str(i + 1), (t, a), fontsize=9, xytext=(3, 3), textcoords="offset points")
        ax.set_xlabel("median CPU time per frame (ms)")
        ax.set_ylabel("RMS error / Cramer-Rao bound")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_xscale("log")
    axes[0].set_yscale("log")
    legend = "\n".join(f"{i + 1}. {r.name}{'' if front[i] else '  (dominated)'}" for i, r in enumerate(rows))
    fig.text(0.01, 0.01, legend, fontsize=7, va="bottom", family="monospace")
    fig.suptitle("tactiled bench: run time against error (red: Pareto front over time, "
                 "RMS/CRB and noise-free bias)", fontsize=10)
    fig.tight_layout(rect=(0, 0.22, 1, 0.95))
    fig.savefig(path, dpi=120)
    plt.close(fig)

"""The fit time of the contacts bench's grasp frames, per grasp, and an A/B against a revision.

``python -m tactiled_bench.grasp_time [--sensor NAME] [--seed 1] [--frames 60] [--rounds 4]
[--baseline REV]`` fits the frames of ``tactiled bench --suite contacts``'s grasps (the same
frames: the suite's draws for that seed, :func:`tactiled_bench.contacts.frames_of` then
:func:`tactiled_bench.grasps.frames_of`) as that suite does (``fit_contacts(fitter, frame,
"auto")`` on a frozen fitter of the description's window), ``rounds`` times, each round in a
fresh process, and reports per grasp the p50 / p99 / max over frames of each frame's median
CPU time (``time.thread_time``) over the rounds: one round slowed by the machine's other jobs
does not rule a frame's figure.  With ``--baseline REV`` the rounds alternate this tree and
the code of git revision REV (this, REV, REV, this, ...: a drift of the machine's load falls on
both alike), every frame's published contacts are compared between the two (models, labels,
reasons, and every number within ``REL_TOL`` relative), and the table gives both and their
ratio.  The load average is printed with each round.
"""
# The worker (fit_times) is a self-contained function run in a subprocess on the code of either
# tree (tactiled_bench.checkout.run_at); it uses only Fitter, FitOptions, fit_contacts and
# load_description, so a revision from before this module measures the same way.  The frames are
# drawn once, by this tree, and handed to both in a .npz.

from __future__ import annotations

import argparse
import math
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactiled_bench import contacts, grasps
from tactiled_bench.checkout import ROOT, checkout, run_at
from tactiled.fit.params import VALUE_KEYS
from tactiled.physics.strain import StrainModel
from tactiled.sensors import load_description

#: Two results are the same when every number agrees within this relative difference.
REL_TOL = 1e-6
#: Keys that are not the result (times).
TIMING_KEYS = ("fit_ms",)


def grasp_frames(name: str, seed: int = 1, frames: int = 60) -> tuple[list[str], np.ndarray]:
    """The grasp frames (singles included) of ``tactiled bench --suite contacts --seed SEED``
    on description ``name`` (``frames`` of each: 60, or 12 with ``--quick``): each frame's
    grasp, and the frames, in the suite's order."""
    desc = load_description(name)
    model = StrainModel(desc.sensor_model())
    rng = contacts.rng_of(desc, seed)
    for _ in contacts.frames_of(desc, model, frames, rng):
        pass  # the suite's draws before its grasps'
    labels, out = [], []
    for grasp, _, truths, frame in grasps.frames_of(model, frames, rng):
        if truths is not None:
            labels.append(grasp)
            out.append(frame)
    return labels, np.array(out)


def fit_times(path: str, warmup: int = 5) -> dict[str, Any]:
    """Every frame of the .npz at ``path`` (``sensors``: description names; ``frames_NAME``:
    that description's frames) fitted as the contacts bench fits them, in order, after
    ``warmup`` untimed fits of its first frames: ``{name: {"ms": [...], "results": [[contact's
    JSON, ...], ...]}}``, CPU ms per frame (the thread's).  The heap is settled after the
    warm-up as a serving process settles it (``gc.freeze``, :func:`tactiled.heap.settle`), and
    the results kept as JSON text: a full collection of everything the imports left (25-40
    ms, at a moment the bench's own allocations decide) is no part of a fit's cost."""
    import gc
    import json
    import time

    import numpy as np

    from tactiled.fit.fitter import FitOptions, Fitter
    from tactiled.fit.multi import fit_contacts
    from tactiled.sensors import load_description

    data = np.load(path)
    out: dict[str, Any] = {}
    for name in [str(n) for n in data["sensors"]]:
        desc = load_description(name)
        fitter = Fitter(desc.sensor_model(), FitOptions(window=desc.window))
        fitter.frozen = True
        frames = data[f"frames_{name}"]
        for frame in frames[:warmup]:
            fit_contacts(fitter, frame, "auto")
        gc.collect()
        gc.freeze()
        gc.collect()
        ms, results = [], []
        for frame in frames:
            t0 = time.thread_time()
            fits = [r for r in fit_contacts(fitter, frame, "auto") if r.contact]
            ms.append((time.thread_time() - t0) * 1e3)
            results.append(json.dumps([r.to_json_dict() for r in fits]))
        out[name] = {"ms": ms, "results": [json.loads(r) for r in results]}
    return out


def differences(a: Any, b: Any, where: str = "") -> list[str]:
    """Where two published results differ: a number by more than ``REL_TOL`` relative, any
    other value at all (timing keys left out)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            if key in TIMING_KEYS:
                continue
            if key not in a or key not in b:
                out.append(f"{where}/{key}: only in {'one' if key in a else 'the other'}")
            else:
                out += differences(a[key], b[key], f"{where}/{key}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{where}: {len(a)} against {len(b)} items"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in differences(x, y, f"{where}[{i}]")]
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        if a == b or (math.isnan(a) and math.isnan(b)):
            return []
        if abs(a - b) <= REL_TOL * max(abs(a), abs(b)):
            return []
    elif a == b:
        return []
    return [f"{where}: {a!r} against {b!r}"]


#: What a result says of how it was found, not what it found: differences only here are
#: "bookkeeping".
BOOKKEEPING_KEYS = ("iterations", "evaluations", "message", "criterion")


def kind_of_difference(a: list[dict], b: list[dict]) -> tuple[str, float]:
    """How two frames' published contacts differ: ``("same", 0)``; ``("contacts", inf)`` (a
    different number of contacts, or a model or label); ``("values", z)``, ``z`` the largest
    difference of a published value in units of the larger of its two sigmas (inf where one
    publishes a value the other withholds; 0 where only sigmas or derived numbers moved);
    ``("bookkeeping", 0)`` (iterations, evaluations, messages only)."""
    if not differences(a, b):
        return "same", 0.0
    if len(a) != len(b) or any(x.get(k) != y.get(k) for x, y in zip(a, b) for k in ("model", "label")):
        return "contacts", math.inf
    z = 0.0
    for x, y in zip(a, b):
        pairs = [(x.get(k), y.get(k), x.get("std", {}).get(k), y.get("std", {}).get(k), k == "angle_deg")
                 for k in VALUE_KEYS]
        xl, yl = x.get("line") or {}, y.get("line") or {}
        pairs += [(xl.get(k), yl.get(k), xl.get(k + "_std"), yl.get(k + "_std"), False)
                  for k in ("load_n_per_mm", "offset_mm")]
        for u, v, su, sv, angle in pairs:
            if (u is None) != (v is None):
                return "values", math.inf
            if u is None or u == v:
                continue
            gap = abs((u - v + 90.0) % 180.0 - 90.0) if angle else abs(u - v)
            if gap > REL_TOL * max(abs(u), abs(v)):
                sd = max(su or 0.0, sv or 0.0)
                z = max(z, gap / sd if sd > 0.0 else math.inf)
    rest = [d for d in differences(a, b) if not any(f"/{k}" in d for k in BOOKKEEPING_KEYS)]
    return ("values", z) if rest else ("bookkeeping", 0.0)


def _stats(ms: np.ndarray) -> str:
    return f"{np.median(ms):.2f} / {np.percentile(ms, 99):.2f} / {ms.max():.2f}"


def run(names: Sequence[str], seed: int = 1, frames: int = 60, rounds: int = 4,
        baseline: str | None = None, workdir: str | None = None, show: int = 10,
        baseline_tree: str | None = None) -> str:
    """The per-grasp fit time table (Markdown), and with ``baseline`` the A/B and the results'
    comparison; ``workdir``: where the baseline's checkout is made and kept (built once);
    ``baseline_tree``: the baseline's code already checked out there (this tree's own path:
    this tree against itself)."""
    drawn = {n: grasp_frames(n, seed, frames) for n in names}
    lines: list[str] = []
    with tempfile.TemporaryDirectory(prefix="tactiled-grasp-time-") as tmp:
        path = os.path.join(tmp, "frames.npz")
        np.savez(path, sensors=np.array(list(names)), **{f"frames_{n}": f for n, (_, f) in drawn.items()})
        trees = {"this": str(ROOT)}
        if baseline is not None:
            where = workdir or tmp
            kept = Path(where) / f"tactiled-{baseline}"
            trees[baseline] = (baseline_tree or str(kept) if baseline_tree or kept.exists()
                               else checkout(baseline, where))
        order = list(trees) if baseline is None else ["this", baseline, baseline, "this"]
        runs: dict[str, list[dict[str, Any]]] = {k: [] for k in trees}
        for i in range(rounds if baseline is None else 2 * rounds):
            code = order[i % len(order)] if baseline is not None else "this"
            load = os.getloadavg()[0]
            runs[code].append(run_at(trees[code], fit_times, f"fit_times({path!r})"))
            lines.append(f"round {i + 1}: {code}, load average {load:.2f} -> {os.getloadavg()[0]:.2f}")
    codes = list(trees)
    head = " | ".join(f"{c} ms p50 / p99 / max" for c in codes)
    lines += ["", f"| description | grasp | frames | {head} |"
              + (" p50 ratio | p99 ratio |" if baseline else ""),
              "|---|---|---|" + "---|" * len(codes) + ("---|---|" if baseline else "")]
    diffs: list[str] = []
    kinds: dict[tuple[str, str, str], list[float]] = {}
    for n, (labels, _) in drawn.items():
        med = {c: np.median([r[n]["ms"] for r in runs[c]], axis=0) for c in codes}
        for grasp in dict.fromkeys(labels):
            sel = np.array([g == grasp for g in labels])
            cells = [_stats(med[c][sel]) for c in codes]
            row = f"| {n} | {grasp} | {int(sel.sum())} | " + " | ".join(cells) + " |"
            if baseline:
                a, b = med["this"][sel], med[baseline][sel]
                row += (f" {np.median(a) / np.median(b):.2f} |"
                        f" {np.percentile(a, 99) / np.percentile(b, 99):.2f} |")
            lines.append(row)
        for c in codes:  # one code's rounds must agree with each other
            for r in runs[c][1:]:
                if differences(r[n]["results"], runs[c][0][n]["results"]):
                    diffs.append(f"{n}: {c}'s rounds disagree")
        if baseline:
            mine, base = runs["this"][0][n]["results"], runs[baseline][0][n]["results"]
            for k, (a, b) in enumerate(zip(mine, base)):
                kind, z = kind_of_difference(a, b)
                if kind != "same":
                    kinds.setdefault((n, labels[k], kind), []).append(z)
                if kind in ("contacts", "values"):
                    d = differences(a, b)
                    diffs.append(f"{n} frame {k} ({labels[k]}), {kind}"
                                 + (f" (at most {z:.2g} sigma)" if kind == "values" else "") + ": "
                                 + "; ".join(d[:4]) + (f" (and {len(d) - 4} more)" if len(d) > 4 else ""))
    if baseline:
        total = sum(len(lab) for lab, _ in drawn.values())
        same = total - sum(len(v) for v in kinds.values())
        lines += ["", f"published results: {same} of {total} frames the same (numbers within "
                  f"{REL_TOL:g} relative); the others by description, grasp and how they differ "
                  "(bookkeeping: iterations and messages only; values: the largest difference "
                  "in sigmas; contacts: their number, a model or a label):"]
        for (n, grasp, kind), zs in kinds.items():
            worst = max(zs)
            lines.append(f"- {n} {grasp}: {len(zs)} {kind}"
                         + (f", at most {worst:.2g} sigma" if kind == "values" else ""))
        lines.append("")
    lines += [f"- {d}" for d in diffs[:show]] + ([f"- ... {len(diffs) - show} more"] if len(diffs) > show else [])
    return "\n".join(lines)


def _cli() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sensor", action="append", default=None,
                   help="a description (repeatable; default the contacts suite's: "
                        + ", ".join(contacts.DEFAULT_SENSORS) + ")")
    p.add_argument("--seed", type=int, default=1, help="the contacts suite's seed (default 1)")
    p.add_argument("--frames", type=int, default=60, help="frames of each grasp (the suite's 60; 12 --quick)")
    p.add_argument("--rounds", type=int, default=4, help="rounds of each code (default 4)")
    p.add_argument("--baseline", metavar="REV", default=None,
                   help="also the code of git revision REV, alternating with this tree's")
    p.add_argument("--workdir", default=None,
                   help="where the baseline's checkout is made and kept (its core built once)")
    a = p.parse_args()
    print(run(a.sensor or list(contacts.DEFAULT_SENSORS), a.seed, a.frames, a.rounds, a.baseline, a.workdir))


if __name__ == "__main__":
    _cli()

"""``tactiled simulate`` and ``tactiled fit`` on 3-axis arrays (docs/concepts/shear.md).

A 3-axis frame file is an .npz holding ``taxels``, a float array ``(N, rows, cols, 3)`` of
zeroed readings (x, y, z; z positive into the cover), and ``sensor``, the description's name
or path; ``tactiled simulate --sensor NAME`` on a 3-axis description writes one, with the truth
(``true_*``, tactiled/sim/shear.py), and ``tactiled fit`` reads it.  Frames of a ``sequence``
index (written with ``--load push|twist|pull``) are consecutive frames at ``rate_hz``, and the
slip detector (tactiled/fit/slip.py) runs along each sequence as in the daemon: each frame is
fitted, estimated by the step from that fit (``SlipDetector.track``), and fed to the detector.

Each output line of ``tactiled fit``: ``{"frame", "contact", "model": "sphere", "x_mm",
"y_mm", "force_n", "r1_mm", "std": {...}, "shear": {"fx_n", "fy_n", "torque_nmm",
"q_over_p", "mu", "slip_margin", "std": {...}}, "slip": {"state", "lam", "lam_std",
"event"}, "rms_over_noise", "converged", "reasons"}`` (``rms_over_noise``: the RMS residual
in units of the noise); ``mu`` and ``slip_margin`` are null where the bound does not resolve
them, and ``reasons`` says why.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from tactiled.errors import FrameError, TactiledError
from tactiled.io.files import read_npz, write_npz
from tactiled.sensors import load_description
from tactiled.sensors.description import SensorDescription

LOADS = ("random", "push", "twist", "pull", "limit")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The 3-axis flags of ``tactiled simulate`` (file mode, a 3-axis --sensor)."""
    g = p.add_argument_group("3-axis arrays (a --sensor with axes = 3): tangential loads")
    g.add_argument("--load", choices=LOADS, default="random",
                   help="random: independent frames (--frames); push, twist, pull, limit: --sequences "
                   "scenes at 1 kHz (pull slides; limit stays put at the friction's limit; "
                   "docs/concepts/shear.md) (default random)")
    g.add_argument("--sequences", type=int, default=1, help="scenes of --load push|twist|pull|limit (default 1)")
    g.add_argument("--mu", default="0.3:1.0", help="friction coefficient, value or LO:HI (default 0.3:1.0)")
    g.add_argument("--lam", default="0:0.95",
                   help="random: the friction mobilised Q/(mu P), value or LO:HI (default 0:0.95)")
    g.add_argument("--torque", default="-0.3:0.3", help="random: torsion, N mm, value or LO:HI (default -0.3:0.3)")


def is_three_axis_file(path: str | Path) -> bool:
    """True when the .npz at ``path`` holds 3-axis ``taxels`` (no error here: the reader says)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return "taxels" in data.files
    except Exception:  # noqa: BLE001 - the ordinary reader reports a bad file
        return False


def _pair(text: str, name: str) -> tuple[float, float]:
    parts = str(text).split(":")
    try:
        lo, hi = (float(parts[0]), float(parts[-1])) if len(parts) <= 2 else (math.nan, math.nan)
    except ValueError:
        lo = hi = math.nan
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise ValueError(f"--{name} must be a number or LO:HI, got {text!r}")
    return lo, hi


def simulate(args: argparse.Namespace, desc: SensorDescription) -> int:
    """``tactiled simulate OUT.npz --sensor NAME`` on a 3-axis description."""
    from tactiled.sim.shear import random_frames, sequence

    try:
        rng = np.random.default_rng(args.seed)
        if args.load == "random":
            if args.frames < 1:
                raise ValueError("--frames must be at least 1")
            ranges = {"r1": args.r1, "force": args.force, "mu": _pair(args.mu, "mu"),
                      "lam": _pair(args.lam, "lam"), "torque": _pair(args.torque, "torque")}
            if not (ranges["r1"][0] > 0 and ranges["force"][0] > 0 and 0 <= ranges["lam"][0]
                    and ranges["lam"][1] <= 1 and ranges["mu"][0] > 0):
                raise ValueError("need --r1 > 0, --force > 0, --mu > 0 and --lam within 0..1")
            centre = None if args.x is None or args.y is None else (args.x, args.y)
            frames, truth = random_frames(desc, args.frames, rng, ranges, centre)
            extras = {}
        else:
            if args.sequences < 1:
                raise ValueError("--sequences must be at least 1")
            runs = [sequence(desc, args.load, rng) for _ in range(args.sequences)]
            frames = np.concatenate([f for f, _ in runs])
            truth = {k: np.concatenate([t[k] for _, t in runs]) for k in runs[0][1] if k != "true_onset"}
            starts = np.cumsum([0] + [len(f) for f, _ in runs[:-1]])
            truth["true_onset"] = np.array([t["true_onset"] + (s if t["true_onset"] >= 0 else 0)
                                            for (_, t), s in zip(runs, starts)], dtype=np.int64)
            extras = {"sequence": np.concatenate([np.full(len(f), k) for k, (f, _) in enumerate(runs)]),
                      "rate_hz": np.float64(1000.0)}
    except ValueError as err:
        print(f"tactiled simulate: error: {err}", file=sys.stderr)
        return 2
    sensor = args.sensor if args.sensor is not None else desc.name
    write_npz(args.output, dict(taxels=frames, sensor=np.str_(sensor), **truth, **extras), error=FrameError)
    print(f"wrote {len(frames)} frame(s) of {desc.rows}x{desc.cols}x3 to {args.output}", file=sys.stderr)
    return 0


def load_taxels(path: str | Path, desc: SensorDescription) -> tuple[np.ndarray, np.ndarray | None]:
    """The ``taxels`` of a 3-axis frame file, checked against ``desc``, and its ``sequence``
    index (None: independent frames); :class:`FrameError` naming the problem."""
    data = read_npz(Path(path), "frame file", FrameError)
    taxels = data["taxels"]
    want = (desc.rows, desc.cols, 3)
    if (taxels.ndim != 4 or taxels.shape[1:] != want or taxels.shape[0] < 1
            or not np.issubdtype(taxels.dtype, np.number) or np.iscomplexobj(taxels)):
        raise FrameError(f"{path}: 'taxels' must be real readings of shape (N, {want[0]}, {want[1]}, 3) "
                         f"for sensor {desc.name!r}, got {taxels.dtype.name} {taxels.shape}")
    taxels = taxels.astype(float)
    bad = ~np.isfinite(taxels)
    if bad.any():
        f, m, n, k = (int(i) for i in np.argwhere(bad)[0])
        raise FrameError(f"{path}: 'taxels' has {int(bad.sum())} non-finite value(s), first at frame {f} "
                         f"taxel [{m}, {n}] axis {'xyz'[k]}")
    seq = data.get("sequence")
    if seq is not None and (seq.shape != (len(taxels),) or seq.dtype.kind not in "iu"):
        raise FrameError(f"{path}: 'sequence' must hold one whole number per frame")
    return taxels, seq


#: A frame is a contact when its readings' chi-square over the noise exceeds the count of
#: readings by this many of its standard deviations (about 1e-9 false contacts per frame).
CONTACT_SIGMAS = 6.0


def fit_lines(desc: SensorDescription, taxels: np.ndarray, sequence: np.ndarray | None):
    """One JSON-ready dict per frame (see the module docstring)."""
    from tactiled.fit.shear import ShearFitter
    from tactiled.fit.slip import SlipDetector

    fitter = ShearFitter(desc)
    noise = np.asarray(desc.axis_noise)
    detector, prev, last_seq = SlipDetector(), None, None
    for i, frame in enumerate(taxels):
        seq = None if sequence is None else int(sequence[i])
        if sequence is None or seq != last_seq:
            detector, prev, last_seq = SlipDetector(), None, seq
        chi2 = float(np.sum((frame / noise) ** 2))
        n = frame.size
        if chi2 - n < CONTACT_SIGMAS * math.sqrt(2.0 * n):
            if prev is not None:  # the contact ended: the next one starts afresh, as in the daemon
                detector, prev = SlipDetector(), None
            yield {"frame": i, "contact": False, "message": "no contact: below the noise threshold"}
            continue
        est = fitter.fit(frame, start=prev if sequence is not None else None)
        prev = est.params
        out = est.to_json()
        event = None
        if sequence is not None:
            # the daemon's path (tactiled.pipeline.shear_track): the frame estimated by the step
            # from the newest fit (here its own: lam before the clip), then the detector
            _, out["slip"]["state"], ev = detector.track(i, fitter.step(est), frame)
            event = None if ev is None else ev.kind
        out["slip"]["event"] = event
        contact = out.pop("contact")
        yield {"frame": i, "contact": True, "model": "sphere", **contact, **out}


def fit(args: argparse.Namespace) -> int:
    """``tactiled fit FRAMES.npz`` on a 3-axis frame file."""
    try:
        data = read_npz(Path(args.frames), "frame file", FrameError)
        spec = args.sensor if args.sensor is not None else (str(data["sensor"]) if "sensor" in data else None)
        if spec is None:
            raise FrameError(f"{args.frames}: a 3-axis file needs --sensor (its description)")
        desc = load_description(spec)
        if desc.axes != 3:
            raise FrameError(f"{args.frames}: holds 3-axis 'taxels', but sensor {desc.name!r} is 1-axis")
        taxels, seq = load_taxels(args.frames, desc)
    except (TactiledError, ValueError) as err:
        print(f"tactiled fit: error: {err}", file=sys.stderr)
        return 2
    try:
        for line in fit_lines(desc, taxels, seq):
            sys.stdout.write(json.dumps(line, allow_nan=False) + "\n")
        sys.stdout.flush()
    except BrokenPipeError:
        return 0
    return 0

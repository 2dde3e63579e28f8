"""The identification benchmark (``tactiled bench --suite identify``): a finger that is not the
paper's, identified from presses, then fitted.

Simulates a truth finger and ~400 presses of known contacts, identifies its constants (each
against the truth in units of its 1-sigma bound), fits cylinder frames with the identified
model, the nominal one and the paper's ideal finger, and shows how accuracy falls with fewer
presses.
"""
# 1. Truth finger: rubber d_x 5.0, nu_x 0.40, d_y 6.6, nu_y 0.60, E 0.32; 5 % tactel gains,
#    0.05 mm tactel displacements, +/-300-count offsets.  Presses: spheres and cylinders of a few
#    mm at all orientations, 0.25-2 N, centres over the array, 10 % unloaded, each the mean of 32
#    frames, as docs/howto/calibration.md's procedure records them.
# 2. Identification: each constant against the truth, in units of its own 1-sigma bound.
# 3. Cylinder frames (R 2-40 mm, psi 30-150 deg, 0.5-2 N, noise 0.0005 per frame) fitted three
#    ways: the identified model through the identified tables; docs/concepts/model.md's constants
#    with ideal zeroing and nominal gain (what a user gets without identifying); and, for
#    reference, the paper's ideal finger.  RMS error over the true finger's Cramer-Rao bound,
#    2-sigma coverage and the median reported sigma.
# 4. Each constant's accuracy against the number of presses (50, 100, 200, 400).

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tactiled_bench.runner import Progress
from tactiled.calibration.identify import RUBBER, Identification, identify
from tactiled.calibration.presses import synthesize_contact_presses
from tactiled.sensors.model import NoiseModel, SensorModel
from tactiled.sensors.finger import COUNTS_PER_STRAIN, FingerSpec
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.floor import MIN_FITS
from tactiled.fit.models import get_model
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel

PARAMS = ("r1_mm", "angle_deg", "force_n", "x_mm", "y_mm")
#: The issue's truth finger.
TRUTH = FingerSpec(depth_x=5.0, nu_x=0.40, depth_y=6.6, nu_y=0.60, modulus=0.32,
                   gain_error=0.05, position_error=0.05, offset_counts=300.0, seed=13)
#: A mismatched finger nobody identified: the paper's rubber, 5 % gains, 0.1 mm displacements.
MISMATCHED = FingerSpec(gain_error=0.05, position_error=0.1, seed=5)
FRAME_SIGMA = 0.0005


def test_cylinder(rng: np.random.Generator) -> Contact:
    """A cylinder of the issue's test range: R 2-40 mm (log-uniform), psi 30-150 deg,
    0.5-2 N, centre a pitch or more inside the array."""
    r = float(math.exp(rng.uniform(math.log(2.0), math.log(40.0))))
    return Contact(r, math.inf, float(rng.uniform(30.0, 150.0)), float(rng.uniform(0.5, 2.0)),
                   float(rng.uniform(5.0, 18.0)), float(rng.uniform(6.0, 21.0)))


@dataclass
class Scores:
    """Per parameter: RMS error / true CRB (pooled over frames), 2-sigma coverage, median sigma."""

    ratio: dict[str, float]
    coverage: dict[str, float]
    sigma: dict[str, float]
    frames: int
    #: coverage over the frames after the first ``floor.MIN_FITS`` (the floor learner's warm-up:
    #: before it, only a frame's own chi^2 can widen its sigmas)
    settled: dict[str, float] = None  # type: ignore[assignment]


def _error(k: str, est: float, true: float) -> float:
    e = est - true
    return (e + 90.0) % 180.0 - 90.0 if k == "angle_deg" else e


def score_frames(spec: FingerSpec, fitter: Fitter, linearise, n: int, seed: int,
                 progress: Progress | None = None) -> Scores:
    """Fit ``n`` test cylinders on the finger ``spec`` (counts through its true tactels,
    ``linearise(counts) -> strain``) with ``fitter``; scores against the true finger's bound."""
    truth_sensor = spec.sensor(noise=NoiseModel(FRAME_SIGMA))
    truth_model = StrainModel(truth_sensor)
    crb_fitter = Fitter(truth_sensor, warm=False)
    rng = np.random.default_rng(seed)
    sq = {k: [] for k in PARAMS}
    inside = {k: [] for k in PARAMS}
    sig = {k: [] for k in PARAMS}
    cyl = get_model("cylinder")
    for _ in range(n):
        c = test_cylinder(rng)
        clean = truth_model.predict(c)
        crb = crb_fitter.cramer_rao(clean, "cylinder", cyl.from_values(c.r1, c.r2, c.psi_deg, c.force, c.x0, c.y0))
        counts = spec.to_counts(clean + rng.normal(0.0, FRAME_SIGMA, clean.shape))
        res = fitter.fit(linearise(counts), "cylinder")
        truth = {"r1_mm": c.r1, "angle_deg": c.psi_deg, "force_n": c.force, "x_mm": c.x0, "y_mm": c.y0}
        for k in PARAMS:
            v, s, b = res.values[k], res.std[k], crb[k]
            if v is None or s is None or not b:
                inside[k].append(0.0)
                continue
            e = _error(k, v, truth[k])
            sq[k].append((e / b) ** 2)
            inside[k].append(float(abs(e) < 2.0 * s))
            sig[k].append(s / truth[k] if k in ("r1_mm", "force_n") else s)
        if progress:
            progress.step()
    return Scores({k: math.sqrt(float(np.mean(sq[k]))) if sq[k] else math.inf for k in PARAMS},
                  {k: 100.0 * float(np.mean(inside[k])) for k in PARAMS},
                  {k: float(np.median(sig[k])) if sig[k] else math.nan for k in PARAMS}, n,
                  {k: 100.0 * float(np.mean(inside[k][MIN_FITS:])) if n > MIN_FITS else math.nan
                   for k in PARAMS})


def identified_fitter(ident: Identification) -> tuple[Fitter, object]:
    """The daemon's fitter for an identified finger and its linearisation."""
    sensor = SensorModel(impulse=ident.sensor.impulse, material=ident.sensor.material,
                         positions=ident.sensor.positions, model_error=ident.model_error,
                         noise=NoiseModel(FRAME_SIGMA))
    return Fitter(sensor, FitOptions(learn_floor=True)), ident.table.to_strain


def nominal_fitter(spec: FingerSpec) -> tuple[Fitter, object]:
    """docs/concepts/model.md's constants with ideal zeroing (the true zero counts) and nominal gain."""
    zero = spec.zero_counts()
    fitter = Fitter(SensorModel(noise=NoiseModel(FRAME_SIGMA)), FitOptions(learn_floor=True))
    return fitter, lambda counts: (counts.astype(float) - zero) / COUNTS_PER_STRAIN


def _scores_table(rows: list[tuple[str, Scores]]) -> list[str]:
    unit = {"r1_mm": "rel", "angle_deg": "deg", "force_n": "rel", "x_mm": "mm", "y_mm": "mm"}
    out = ["| fitted as | frames | " + " | ".join(f"{k} RMS/CRB" for k in PARAMS) + " | "
           + " | ".join(f"{k} cov. %" for k in PARAMS) + " | "
           + " | ".join(f"{k} median sigma ({unit[k]})" for k in PARAMS) + " |",
           "|---|---|" + "---|" * (3 * len(PARAMS))]
    for name, s in rows:
        out.append(f"| {name} | {s.frames} | " + " | ".join(f"{s.ratio[k]:.2f}" for k in PARAMS) + " | "
                   + " | ".join(f"{s.coverage[k]:.1f}" for k in PARAMS) + " | "
                   + " | ".join(f"{s.sigma[k]:.3g}" for k in PARAMS) + " |")
    return out


def constants_table(ident: Identification, truth: FingerSpec) -> list[str]:
    t = truth.describe()
    out = ["| constant | truth | identified | 1-sigma | (est - truth) / sigma | paper |",
           "|---|---|---|---|---|---|"]
    paper = FingerSpec().describe()
    for k in RUBBER:
        sd = ident.sigma.get(k)
        z = "held" if sd is None else f"{(ident.constants[k] - t[k]) / sd:+.2f}"
        out.append(f"| {k} | {t[k]:g} | {ident.constants[k]:.5g} | "
                   f"{'held' if sd is None else f'{sd:.2g}'} | {z} | {paper[k]:g} |")
    return out


def run(quick: bool, progress: bool | None) -> str:
    """The whole suite as markdown."""
    n_presses = 200 if quick else 400
    n_frames = 100 if quick else 400
    presses = synthesize_contact_presses(TRUTH, n_presses, seed=21)
    ident = identify(presses)
    g = ident.sensor.positions
    ex, ey = g.arrays(8, 8)
    tex, tey = TRUTH.positions().arrays(8, 8)
    lines = [f"Truth finger: {TRUTH.describe()}.", "",
             f"### Identification from {n_presses} presses ({ident.presses_loaded} loaded), "
             f"{ident.iterations} iterations", ""]
    lines += constants_table(ident, TRUTH)
    gain_err = ident.gains / (COUNTS_PER_STRAIN * TRUTH.gains()) - 1.0
    lines += ["",
              f"Tactel gains: RMS error {100 * float(np.sqrt(np.mean(gain_err ** 2))):.2g} % "
              f"(true spread 5 %); positions: RMS error {1000 * float(np.sqrt(np.mean((ex - tex) ** 2 + (ey - tey) ** 2) / 2)):.2g} um "
              f"per axis (true spread 50 um, {int((~ident.positions_held).sum())} of 64 used); offsets: RMS error "
              f"{float(np.sqrt(np.mean((ident.offsets - TRUTH.zero_counts()) ** 2))):.2g} counts (true spread "
              f"+/-300); model-error floor {ident.model_error.strain:.2g} strain + "
              f"{100 * ident.model_error.relative:.2g} %.", ""]
    bar = Progress(3 * n_frames, "identify: fitting test frames", progress)
    fit_id, lin_id = identified_fitter(ident)
    fit_nom, lin_nom = nominal_fitter(TRUTH)
    ideal = FingerSpec()
    fit_ideal, lin_ideal = nominal_fitter(ideal)
    rows = [("identified model, identified tables", score_frames(TRUTH, fit_id, lin_id, n_frames, 31, bar)),
            ("docs/concepts/model.md constants, ideal zeroing, nominal gain", score_frames(TRUTH, fit_nom, lin_nom, n_frames, 31, bar)),
            ("(the paper's ideal finger, its own model)", score_frames(ideal, fit_ideal, lin_ideal, n_frames, 31, bar))]
    lines += [f"### Cylinder fits on the truth finger ({n_frames} frames: R 2-40 mm, psi 30-150 deg, "
              "0.5-2 N, noise 0.0005), against the true finger's Cramer-Rao bound", ""]
    lines += _scores_table(rows)
    lines += ["", "### A mismatched finger nobody identified (paper's rubber, 5 % gains, 0.1 mm "
              "displacements), fitted with docs/concepts/model.md's constants", ""]
    mm_rows, flats = [], []
    for seed in ((5,) if quick else (5, 6, 7)):
        spec = FingerSpec(gain_error=0.05, position_error=0.1, seed=seed)
        f, lin = nominal_fitter(spec)
        mm_rows.append((f"finger seed {seed}", score_frames(spec, f, lin, n_frames, 41, None)))
        flats.append(f.flat)
    lines += _scores_table(mm_rows)
    lines += ["", f"The same fingers after the floor learner's warm-up, where their gains lie, and what "
              f"the flat field learned of the central 4x4 tactels in {n_frames} fits (RMS error "
              "against the truth, gains relative to the array's mean):", "",
              f"| finger | 2-sigma coverage after the first {MIN_FITS} fits ("
              + " / ".join(PARAMS) + ") | mean gain, central 4x4 | mean gain, all 64 | "
              "flat field: gains' error, before -> after | displacements' error (um), before -> after |",
              "|---|---|---|---|---|---|"]
    c = (slice(2, 6), slice(2, 6))
    for (name, sc), seed, flat in zip(mm_rows, (5, 6, 7), flats):
        spec = FingerSpec(gain_error=0.05, position_error=0.1, seed=seed)
        gains = spec.gains()
        rel = gains / gains.mean()
        ex, ey = spec.positions().arrays(8, 8)
        ex, ey = ex - ex.mean(), ey - ey.mean()

        def rms(a: np.ndarray) -> float:
            return float(np.sqrt(np.mean(a[c] ** 2)))

        lines.append(f"| {name} | " + " / ".join(f"{sc.settled[k]:.1f}" for k in PARAMS)
                     + f" % | {float(gains[c].mean()):.4f} | {float(gains.mean()):.4f} | "
                     f"{100 * rms(rel - 1):.2f} % -> {100 * rms(rel - flat.gain):.2f} % | "
                     f"{1000 * rms(np.hypot(ex, ey)):.0f} -> {1000 * rms(np.hypot(ex - flat.dx, ey - flat.dy)):.0f} |")
    if not quick:
        lines += ["", "### More fingers nobody identified: the spread over fingers", "",
                  "Each the mean of 400 test frames (another draw of them than above); coverage "
                  "and RMS/CRB for r1_mm / angle_deg / force_n / x_mm / y_mm.", "",
                  "| gains, displacements | finger seed | 2-sigma coverage % | RMS/CRB | flat field |",
                  "|---|---|---|---|---|"]
        for gain_error, position_error, seeds in ((0.05, 0.1, range(8, 13)), (0.08, 0.15, range(20, 26))):
            for seed in seeds:
                spec = FingerSpec(gain_error=gain_error, position_error=position_error, seed=seed)
                f, lin = nominal_fitter(spec)
                sc = score_frames(spec, f, lin, n_frames, 7, None)
                lines.append(f"| {100 * gain_error:g} %, {1000 * position_error:g} um | {seed} | "
                             + " / ".join(f"{sc.coverage[k]:.1f}" for k in PARAMS) + " | "
                             + " / ".join(f"{sc.ratio[k]:.2f}" for k in PARAMS)
                             + f" | {f.flat.note if f.flat.active else 'off: ' + (f.flat.note or 'nothing significant')} |")
    lines += ["", "### Accuracy of the constants against the number of presses", "",
              "| presses | " + " | ".join(f"{k} error (sigma)" for k in RUBBER) + " |",
              "|---|" + "---|" * len(RUBBER)]
    t = TRUTH.describe()
    for n in ((50, 100, 200) if quick else (50, 100, 200, 400)):
        try:
            res = identify(synthesize_contact_presses(TRUTH, n, seed=100 + n))
        except Exception as err:  # noqa: BLE001 - a figure of the bench, not a crash
            lines.append(f"| {n} | " + " | ".join(["failed"] * len(RUBBER)) + f" ({err}) |")
            continue
        cells = []
        for k in RUBBER:
            sd = res.sigma.get(k)
            e = res.constants[k] - t[k]
            cells.append("held" if sd is None else f"{e:+.3g} ({sd:.2g})")
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    return "\n".join(lines)

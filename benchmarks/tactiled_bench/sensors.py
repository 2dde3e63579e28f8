"""Accuracy on every built-in sensor description (``tactiled bench --suite sensors``).

Simulated cylinders, spheres and edges are fitted with their own model under each description's
noise: per parameter the RMS error over the Cramer-Rao bound at the truth (1.0 is efficient),
2-sigma coverage (95 % for honest sigmas) and the share withheld; and the fit time per frame of
the contact's own model and of ``auto``.
"""
# Contacts the array can feel: cylinders (on a flat array: line contacts), spheres and edges
# (0.5 mm cylinders), at random orientations (on a curved finger 30-150 deg from its axis:
# nearer, a cylinder is a line longer than the finger) and positions in the array's middle half,
# pressed to a peak strain of 40-120 noise sigmas, many noise draws each.  Withheld values have
# their reasons counted.  Fit time is the fitting thread's CPU time; auto (the daemon's choice
# among the models) is timed on the same frame, with the share of its fits the budget stopped.

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from tactiled_bench import live_sensors
from tactiled_bench.live_sensors import FAR_SIGMAS
from tactiled.fit.budget import budget_spent
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.models import get_model
from tactiled.physics.contact import Contact, LineContact
from tactiled.physics.strain import StrainModel, scaled_to_peak
from tactiled.progress import Progress
from tactiled.sensors import SensorDescription, builtin_names, load_description

#: Peak strain of the simulated contacts, in noise sigmas.
PEAK_SNR = (40.0, 120.0)
#: Radii (mm) of the cylinders and spheres, drawn log-uniformly; an edge's radius.
RADII = (3.0, 25.0)
EDGE_RADIUS = 0.5
KINDS = ("cylinder", "sphere", "edge")
#: Parameters scored per kind: a line contact (a cylinder on a flat array), an ellipse
#: contact's cylinder, a sphere.
LINE_KEYS = ("r1_mm", "angle_deg", "load_n_per_mm", "offset_mm")
CYLINDER_KEYS = ("x_mm", "y_mm", "force_n", "r1_mm", "angle_deg")
SPHERE_KEYS = ("x_mm", "y_mm", "force_n", "r1_mm")


@dataclass
class Scores:
    """What one description's fits scored, per parameter (``kind/key``)."""

    z: dict[str, list[float]] = field(default_factory=dict)  # error / CRB at the truth
    covered: dict[str, list[bool]] = field(default_factory=dict)  # |error| <= 2 reported sigma
    far: dict[str, list[bool]] = field(default_factory=dict)  # |error| > 4 reported sigma
    withheld: Counter = field(default_factory=Counter)
    seen: Counter = field(default_factory=Counter)
    reasons: Counter = field(default_factory=Counter)
    fit_ms: list[float] = field(default_factory=list)
    auto_ms: list[float] = field(default_factory=list)
    auto_spent: int = 0

    def add(self, name: str, err: float | None, crb: float | None, sd: float | None,
            reason: str | None) -> None:
        self.seen[name] += 1
        if err is None:
            self.withheld[name] += 1
            if reason:
                self.reasons[reason.split(":")[0]] += 1
            return
        if crb is not None and crb > 0:
            self.z.setdefault(name, []).append(err / crb)
        self.covered.setdefault(name, []).append(sd is not None and abs(err) <= 2.0 * sd)
        self.far.setdefault(name, []).append(sd is None or abs(err) > FAR_SIGMAS * sd)

    def rms_over_crb(self, name: str) -> float | None:
        z = self.z.get(name)
        return float(np.sqrt(np.mean(np.square(z)))) if z else None

    def beyond(self, name: str) -> float | None:
        """The share of published values further than ``FAR_SIGMAS`` of their sigma."""
        c = self.far.get(name)
        return float(np.mean(c)) if c else None

    def coverage(self, name: str) -> float | None:
        c = self.covered.get(name)
        return float(np.mean(c)) if c else None


def _offset_err(est: float, est_angle: float | None, truth: float, truth_angle: float) -> float:
    """A line's offset error: the offset is signed along the normal of its own reported angle
    (modulo 180 deg), so an estimate whose angle wrapped past 0/180 from the truth's has the
    truth's offset with the other sign."""
    if est_angle is not None and math.cos(math.radians(est_angle - truth_angle)) < 0.0:
        truth = -truth
    return est - truth


def _angle_err(est: float, true: float) -> float:
    return (est - true + 90.0) % 180.0 - 90.0


def _truths(desc: SensorDescription, kind: str, n: int, rng: np.random.Generator,
            model: StrainModel) -> list[Contact | LineContact]:
    g = model.sensor.geometry
    sigma = model.sensor.noise.sigma
    out: list[Contact | LineContact] = []
    while len(out) < n:
        r = EDGE_RADIUS if kind == "edge" else math.exp(rng.uniform(*np.log(RADII)))
        # on a curved finger a cylinder within 30 deg of its axis is a line contact longer
        # than the finger, outside the planar model (docs/concepts/fitting.md): not drawn
        psi = float(rng.uniform(0.0, 180.0) if g.flat else rng.uniform(30.0, 150.0))
        x0 = g.span_x * rng.uniform(0.25, 0.75)
        y0 = g.span_y * rng.uniform(0.25, 0.75)
        snr = float(rng.uniform(*PEAK_SNR))
        if kind == "sphere":
            make = lambda s, r=r, x0=x0, y0=y0: Contact(r, r, 0.0, s, x0, y0)  # noqa: E731
        elif g.flat:
            make = lambda s, r=r, psi=psi, x0=x0, y0=y0: LineContact(r, psi, 0.1 * s, x0, y0)  # noqa: E731
        else:
            make = lambda s, r=r, psi=psi, x0=x0, y0=y0: Contact(r, math.inf, psi, s, x0, y0)  # noqa: E731
        try:
            out.append(scaled_to_peak(model, make, snr * sigma))
        except ValueError:  # a contact too long for the planar model at that load: draw again
            continue
    return out


def _truth_values(c: Contact | LineContact, centre: tuple[float, float]) -> dict[str, float]:
    if isinstance(c, LineContact):
        return {"r1_mm": c.r1, "angle_deg": c.psi_deg % 180.0, "load_n_per_mm": c.load,
                "offset_mm": c.offset_from(*centre)}
    return {"x_mm": c.x0, "y_mm": c.y0, "force_n": c.force, "r1_mm": c.r1,
            "angle_deg": c.psi_deg % 180.0}


def score_description(desc: SensorDescription, contacts: int, draws: int, seed: int,
                      bar: Progress | None = None) -> Scores:
    """Fit ``contacts`` simulated contacts of each kind, ``draws`` noise draws each."""
    sensor = desc.sensor_model()
    g = sensor.geometry
    model = StrainModel(sensor)
    fitter = Fitter(sensor, FitOptions(window=desc.window))
    sigma = sensor.noise.sigma
    centre = (0.5 * g.span_x, 0.5 * g.span_y)
    rng = np.random.default_rng([seed, sum(desc.name.encode())])
    scores = Scores()
    for kind in KINDS:
        for c in _truths(desc, kind, contacts, rng, model):
            clean = model.predict(c)
            truth = _truth_values(c, centre)
            fit_model = "sphere" if kind == "sphere" else "cylinder"
            if isinstance(c, LineContact):
                crb = fitter.line_cramer_rao(clean, c)
                keys = LINE_KEYS
            else:
                p = get_model(fit_model).from_values(c.r1, c.r2, c.psi_deg, c.force, c.x0, c.y0)
                crb = fitter.cramer_rao(clean, fit_model, p)
                keys = SPHERE_KEYS if kind == "sphere" else CYLINDER_KEYS
            for _ in range(draws):
                frame = clean + rng.normal(0.0, sigma, clean.shape)
                t0 = time.thread_time()
                res = fitter.fit(frame, fit_model)
                scores.fit_ms.append((time.thread_time() - t0) * 1e3)
                t0 = time.thread_time()
                auto = fitter.fit(frame, "auto")
                scores.auto_ms.append((time.thread_time() - t0) * 1e3)
                scores.auto_spent += budget_spent(auto.reasons)
                line = res.line or {}
                for k in keys:
                    est = line.get(k) if k in ("load_n_per_mm", "offset_mm") else res.values.get(k)
                    sd = line.get(f"{k}_std") if k in ("load_n_per_mm", "offset_mm") else res.std.get(k)
                    err = None
                    if est is not None and k == "offset_mm":
                        err = _offset_err(est, res.values.get("angle_deg"), truth[k], truth["angle_deg"])
                    elif est is not None:
                        err = _angle_err(est, truth[k]) if k == "angle_deg" else est - truth[k]
                    scores.add(f"{kind}/{k}", err, crb.get(k), sd, res.reasons.get(k))
                if bar is not None:
                    bar.step()
    return scores


def _times(ms: list[float]) -> str:
    t = np.array(ms)
    return f"{np.median(t):.2f} / {np.percentile(t, 99):.2f} / {t.max():.2f}"


def run(quick: bool, progress: bool | None, names: Sequence[str] | None = None, seed: int = 1,
        live: bool = True) -> str:
    """The suite's Markdown report: per description, its fits (one table each, then a summary
    line each) and, ``live``, the daemon's own estimates of the demo scene against the truth
    (:mod:`tactiled_bench.live_sensors`)."""
    names = list(names) if names else builtin_names()
    contacts, draws = (4, 10) if quick else (12, 25)
    rate = 100.0 if quick else 200.0
    descs = [load_description(n) for n in names]
    bar = Progress(len(descs) * len(KINDS) * contacts * draws, "sensors", progress)
    out = [f"Each description: {contacts} contacts of each kind x {draws} noise draws, peak strain "
           f"{PEAK_SNR[0]:g}-{PEAK_SNR[1]:g} noise sigmas, fitted with the contact's own model "
           "(cylinder; sphere; edge = a 0.5 mm cylinder). RMS/CRB: RMS error over the Cramer-Rao "
           "bound at the truth; 2-sigma: errors within twice the fit's own sigma; beyond 4 sigma: "
           "published values further than four of their sigmas; withheld: values the fit "
           "withheld with a reason. Fit times: CPU ms of the contact's own model "
           "and of auto on the same frame (auto stopped: its fits the budget stopped).", ""]
    summary = ["| description | array | surface | worst RMS/CRB | coverage range | beyond 4 sigma | withheld "
               "| fit ms p50 / p99 / max | auto ms p50 / p99 / max | auto stopped |",
               "|---|---|---|---|---|---|---|---|---|---|"]
    live_rows = list(live_sensors.SUMMARY_HEAD)
    for desc in descs:
        s = score_description(desc, contacts, draws, seed, bar)
        out += [f"### {desc.name}: {desc.rows}x{desc.cols}, {desc.pitch_x_mm:g} x {desc.pitch_y_mm:g} mm, "
                f"{'flat' if desc.flat else f'radius {desc.surface_radius_mm:g} mm'}", "",
                "| parameter | RMS/CRB | 2-sigma | beyond 4 sigma | withheld | n |",
                "|---|---|---|---|---|---|"]
        worst, covs, fars = 0.0, [], []
        for name in s.seen:
            r, c, b = s.rms_over_crb(name), s.coverage(name), s.beyond(name)
            kind = name.split("/")[0]
            if r is not None and kind != "edge":  # an edge's radius is below what any array resolves
                worst = max(worst, r)
            if c is not None and kind != "edge":
                covs.append(c)
            fars += s.far.get(name, [])
            out.append(f"| {name} | {'-' if r is None else f'{r:.2f}'} | "
                       f"{'-' if c is None else f'{100 * c:.0f} %'} | "
                       f"{'-' if b is None else f'{100 * b:.1f} %'} | "
                       f"{100 * s.withheld[name] / s.seen[name]:.0f} % | {s.seen[name]} |")
        if s.reasons:
            out += ["", "withheld because: " + "; ".join(f"{k} ({v})" for k, v in s.reasons.most_common())]
        out.append("")
        if live:
            ls = live_sensors.score(desc, rate, seed)
            out += live_sensors.report(desc, ls, rate)
            live_rows.append(live_sensors.summary_row(desc, ls))
        total = sum(s.seen.values())
        summary.append(
            f"| {desc.name} | {desc.rows}x{desc.cols} | {'flat' if desc.flat else 'curved'} | {worst:.2f} | "
            f"{100 * min(covs):.0f}-{100 * max(covs):.0f} % | {100 * float(np.mean(fars)):.1f} % | "
            f"{100 * sum(s.withheld.values()) / total:.0f} % | "
            f"{_times(s.fit_ms)} | {_times(s.auto_ms)} | {100 * s.auto_spent / len(s.auto_ms):.1f} % |"
            if covs else f"| {desc.name} | - |")
    bar.finish(f"{len(descs)} descriptions scored")
    head = ["Summary (cylinders and spheres; edges in each table):", "", *summary, ""]
    if live:
        head += [f"The daemon's own estimates (`{live_sensors.SCENE}` scene at {rate:g} Hz through the "
                 "daemon with the description's simulated finger, lossless; every published value "
                 "against the truth):", "", *live_rows, ""]
    return "\n".join([*head, *out])

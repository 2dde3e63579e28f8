"""Accuracy on every built-in sensor description (``tactiled bench --suite sensors``).

Simulated cylinders, spheres, ellipsoids and edges are fitted by ``tactiled fit --sensor`` with
their own model under each description's noise: per parameter the RMS error over the
Cramer-Rao bound at the truth (1.0 is efficient), 2-sigma coverage (95 % for honest sigmas),
the share beyond 4 sigma and the share withheld; and the fit time per frame of the contact's
own model and of ``auto``.
"""
# Contacts the array can feel: cylinders (on a flat array: line contacts), spheres, ellipsoids
# (principal radii 1.5-4 times apart) and edges (0.5 mm cylinders), at random orientations (on
# a curved finger 30-150 deg from its axis: nearer, a cylinder is a line longer than the
# finger) and positions in the array's middle half, pressed to a peak strain of 40-120 noise
# sigmas, many noise draws each.  Each kind's frames are one frame file fitted by the command
# (tactiled_bench.fit_command: its learning pass included); a frame's contact is the reported
# one nearest the truth, and frames reporting other than one contact are counted.
# Two bounds: the window the fit itself uses (RMS/CRB: how efficient it is there), and the
# reference, a REFERENCE_WINDOW-square window (clipped to the array: a 4x6 pad's whole pad;
# a line's on its ridge), what the array offers near the contact.  A value the reference
# bound resolves (runner.OBSERVABLE_*: a radius, force or load at least two bounds from
# zero, an orientation within 20 deg, any place) and the fit withholds is counted apart.
# An ellipse's orientation is resolved only where the reference window also tells the
# ellipse from a circle (CIRCLE_CHI2): its bound is the curvature of the likelihood at the
# truth, and where a circle lies within two sigmas the likelihood turns flat a few degrees
# away (on the noise-free frame of a 8.8 x 13.8 mm ellipsoid at 1.4 N on the XELA 4x4 pad,
# a bound of 6.9 deg, and no orientation raises chi^2 by more than 2.3).
# Fit time is the fitting thread's CPU time of a direct fit of the same frame (the command's
# own clock is wall time); auto (the daemon's choice among the models) is timed on the same
# frame, with the share of its fits the budget stopped.

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from tactiled_bench import live_sensors
from tactiled_bench.fit_command import contacts_of, fit_lines
from tactiled_bench.live_sensors import FAR_SIGMAS, REFERENCE_WINDOW  # (clipped to the array)
from tactiled_bench.runner import OBSERVABLE_ANGLE, OBSERVABLE_RELATIVE
from tactiled.fit.budget import budget_spent
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.models import get_model
from tactiled.physics.contact import Contact, LineContact
from tactiled.physics.strain import StrainModel, scaled_to_peak
from tactiled.progress import Progress
from tactiled.sensors import SensorDescription, builtin_names, load_description

#: Peak strain of the simulated contacts, in noise sigmas.
PEAK_SNR = (40.0, 120.0)
#: Radii (mm) of the cylinders, spheres and ellipsoids (the smaller), drawn log-uniformly; an
#: ellipsoid's larger radius over its smaller (log-uniform); an edge's radius.
RADII = (3.0, 25.0)
ELLIPSOID_RATIO = (1.5, 4.0)
EDGE_RADIUS = 0.5
KINDS = ("cylinder", "sphere", "ellipsoid", "edge")
#: An ellipsoid's orientation is resolved only where its best circle (a sphere fitted to the
#: noise-free frame on the reference window) raises chi^2 by at least this: two sigmas away.
CIRCLE_CHI2 = 4.0
#: The model each kind is fitted with (``tactiled fit --model``).
FIT_MODEL = {"cylinder": "cylinder", "sphere": "sphere", "ellipsoid": "general", "edge": "cylinder"}
#: Parameters scored per kind: a line contact (a cylinder on a flat array), an ellipse
#: contact's cylinder, a sphere, an ellipsoid.
LINE_KEYS = ("r1_mm", "angle_deg", "load_n_per_mm", "offset_mm")
CYLINDER_KEYS = ("x_mm", "y_mm", "force_n", "r1_mm", "angle_deg")
SPHERE_KEYS = ("x_mm", "y_mm", "force_n", "r1_mm")
ELLIPSOID_KEYS = ("x_mm", "y_mm", "force_n", "r1_mm", "r2_mm", "angle_deg")


@dataclass
class Scores:
    """What one description's fits scored, per parameter (``kind/key``)."""

    z: dict[str, list[float]] = field(default_factory=dict)  # error / CRB at the truth
    zref: dict[str, list[float]] = field(default_factory=dict)  # error / reference CRB
    covered: dict[str, list[bool]] = field(default_factory=dict)  # |error| <= 2 reported sigma
    far: dict[str, list[bool]] = field(default_factory=dict)  # |error| > 4 reported sigma
    withheld: Counter = field(default_factory=Counter)
    seen: Counter = field(default_factory=Counter)
    resolved: Counter = field(default_factory=Counter)  # the reference bound resolves it
    resolved_withheld: Counter = field(default_factory=Counter)
    reasons: Counter = field(default_factory=Counter)
    contacts: Counter = field(default_factory=Counter)  # frames by the contacts reported
    learned: list[str] = field(default_factory=list)  # what the command's learning pass said
    fit_ms: list[float] = field(default_factory=list)
    auto_ms: list[float] = field(default_factory=list)
    auto_spent: int = 0

    def add(self, name: str, err: float | None, crb: float | None, sd: float | None,
            reason: str | None, ref: float | None = None, resolved: bool = False) -> None:
        self.seen[name] += 1
        self.resolved[name] += resolved
        if err is None:
            self.withheld[name] += 1
            self.resolved_withheld[name] += resolved
            if reason:
                self.reasons[reason.split(":")[0]] += 1
            return
        if crb is not None and crb > 0:
            self.z.setdefault(name, []).append(err / crb)
        if ref is not None and ref > 0:
            self.zref.setdefault(name, []).append(err / ref)
        self.covered.setdefault(name, []).append(sd is not None and abs(err) <= 2.0 * sd)
        self.far.setdefault(name, []).append(sd is None or abs(err) > FAR_SIGMAS * sd)

    def rms_over_crb(self, name: str, reference: bool = False) -> float | None:
        z = (self.zref if reference else self.z).get(name)
        return float(np.sqrt(np.mean(np.square(z)))) if z else None

    def beyond(self, name: str) -> float | None:
        """The share of published values further than ``FAR_SIGMAS`` of their sigma."""
        c = self.far.get(name)
        return float(np.mean(c)) if c else None

    def coverage(self, name: str) -> float | None:
        c = self.covered.get(name)
        return float(np.mean(c)) if c else None

    def withheld_resolved(self, name: str | None = None) -> float | None:
        """The share of values the reference bound resolves that the fit withheld."""
        names = [name] if name else list(self.seen)
        n = sum(self.resolved[k] for k in names)
        return sum(self.resolved_withheld[k] for k in names) / n if n else None


def resolved_by(key: str, truth: float, bound: float | None,
                circle_chi2: float | None = None) -> bool:
    """Does the bound ``bound`` at the truth ``truth`` resolve ``key`` (the rule the configs
    suite leaves frames out by, :data:`tactiled_bench.runner.OBSERVABLE_RELATIVE`): a radius,
    force or load at least two bounds from zero, an orientation within ``OBSERVABLE_ANGLE``
    degrees (an ellipse's only where ``circle_chi2``, its best circle's chi^2 on the
    noise-free frame, is at least ``CIRCLE_CHI2``: a circle has no orientation), a place
    always."""
    if bound is None or not math.isfinite(bound):
        return False
    if key in ("r1_mm", "r2_mm", "force_n", "load_n_per_mm"):
        return bound < OBSERVABLE_RELATIVE * abs(truth)
    if key == "angle_deg":
        return bound < OBSERVABLE_ANGLE and (circle_chi2 is None or circle_chi2 >= CIRCLE_CHI2)
    return True


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
        elif kind == "ellipsoid":
            r2 = r * math.exp(rng.uniform(*np.log(ELLIPSOID_RATIO)))
            make = lambda s, r=r, r2=r2, psi=psi, x0=x0, y0=y0: Contact(r, r2, psi, s, x0, y0)  # noqa: E731
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
    return {"x_mm": c.x0, "y_mm": c.y0, "force_n": c.force, "r1_mm": c.r1, "r2_mm": c.r2,
            "angle_deg": c.psi_deg % 180.0}


def _keys(kind: str, c: Contact | LineContact) -> tuple[str, ...]:
    if isinstance(c, LineContact):
        return LINE_KEYS
    return {"sphere": SPHERE_KEYS, "ellipsoid": ELLIPSOID_KEYS}.get(kind, CYLINDER_KEYS)


def _bounds(fitter: Fitter, reference: Fitter, clean: np.ndarray, kind: str,
            c: Contact | LineContact) -> tuple[dict, dict]:
    """The Cramer-Rao bounds at the truth ``c``: on the window the fit uses, and on the
    reference window (:data:`REFERENCE_WINDOW`)."""
    if isinstance(c, LineContact):
        return (fitter.line_cramer_rao(clean, c),
                fitter.line_cramer_rao(clean, c, window=REFERENCE_WINDOW))
    name = FIT_MODEL[kind]
    p = get_model(name).from_values(c.r1, c.r2, c.psi_deg, c.force, c.x0, c.y0)
    return fitter.cramer_rao(clean, name, p), reference.cramer_rao(clean, name, p)


def _nearest(found: list[dict], c: Contact | LineContact) -> dict | None:
    """The reported contact nearest the truth ``c`` (a line's: measured across it)."""
    def distance(r: dict) -> float:
        x, y = r.get("x_mm"), r.get("y_mm")
        if x is None or y is None:
            return math.inf
        if isinstance(c, LineContact):
            return abs(-math.sin(c.psi) * (x - c.x0) + math.cos(c.psi) * (y - c.y0))
        return math.dist((x, y), (c.x0, c.y0))
    return min(found, key=distance) if found else None


def _value(r: dict | None, key: str) -> tuple[float | None, float | None, str | None]:
    """A reported contact's ``(value, sigma, reason)`` of ``key`` (a line's load and offset
    from its ``line``)."""
    if r is None:
        return None, None, "no contact reported"
    reason = (r.get("reasons") or {}).get(key)
    if key in ("load_n_per_mm", "offset_mm"):
        line = r.get("line") or {}
        return line.get(key), line.get(f"{key}_std"), reason
    return r.get(key), (r.get("std") or {}).get(key), reason


def score_description(desc: SensorDescription, contacts: int, draws: int, seed: int,
                      bar: Progress | None = None, spec: str | None = None) -> Scores:
    """Fit ``contacts`` simulated contacts of each kind, ``draws`` noise draws each, through
    ``tactiled fit --sensor spec`` (default ``desc.name``)."""
    sensor = desc.sensor_model()
    g = sensor.geometry
    model = StrainModel(sensor)
    fitter = Fitter(sensor, FitOptions(window=desc.window))
    reference = Fitter(sensor, FitOptions(window=max(REFERENCE_WINDOW, desc.window)), warm=False)
    sigma = sensor.noise.sigma
    centre = (0.5 * g.span_x, 0.5 * g.span_y)
    rng = np.random.default_rng([seed, sum(desc.name.encode())])
    scores = Scores()
    for kind in KINDS:
        truths = _truths(desc, kind, contacts, rng, model)
        cleans = [model.predict(c) for c in truths]
        frames = np.array([clean + rng.normal(0.0, sigma, clean.shape)
                           for clean in cleans for _ in range(draws)])
        fit_model = FIT_MODEL[kind]
        lines, said = fit_lines(frames, desc, fit_model, spec)
        if said:
            scores.learned.append(f"{kind}: {said}")
        for i, (c, clean) in enumerate(zip(truths, cleans)):
            truth = _truth_values(c, centre)
            crb, ref = _bounds(fitter, reference, clean, kind, c)
            # an ellipse's orientation needs it told from a circle (the reference window's)
            circle = reference.fit(clean, "sphere").chi2 if kind == "ellipsoid" else None
            for d in range(draws):
                frame = frames[i * draws + d]
                t0 = time.thread_time()
                fitter.fit(frame, fit_model)
                scores.fit_ms.append((time.thread_time() - t0) * 1e3)
                t0 = time.thread_time()
                auto = fitter.fit(frame, "auto")
                scores.auto_ms.append((time.thread_time() - t0) * 1e3)
                scores.auto_spent += budget_spent(auto.reasons)
                found = contacts_of(lines[i * draws + d])
                scores.contacts[min(len(found), 2)] += 1
                r = _nearest(found, c)
                for k in _keys(kind, c):
                    est, sd, reason = _value(r, k)
                    err = None
                    if est is not None and k == "offset_mm":
                        err = _offset_err(est, None if r is None else r.get("angle_deg"),
                                          truth[k], truth["angle_deg"])
                    elif est is not None:
                        err = _angle_err(est, truth[k]) if k == "angle_deg" else est - truth[k]
                    scores.add(f"{kind}/{k}", err, crb.get(k), sd, reason, ref.get(k),
                               resolved_by(k, truth[k], ref.get(k), circle))
                if bar is not None:
                    bar.step()
    return scores


def _times(ms: list[float]) -> str:
    t = np.array(ms)
    return f"{np.median(t):.2f} / {np.percentile(t, 99):.2f} / {t.max():.2f}"


def _pct(v: float | None, digits: int = 0) -> str:
    return "-" if v is None else f"{100 * v:.{digits}f} %"


def _ratio(v: float | None) -> str:
    return "-" if v is None else f"{v:.2f}"


def description_table(desc: SensorDescription, s: Scores) -> list[str]:
    """One description's table: each parameter's figures, then why values were withheld."""
    ref = f"{REFERENCE_WINDOW}x{REFERENCE_WINDOW}" if max(desc.rows, desc.cols) > REFERENCE_WINDOW else "whole pad"
    out = [f"### {desc.name}: {desc.rows}x{desc.cols}, {desc.pitch_x_mm:g} x {desc.pitch_y_mm:g} mm, "
           f"{'flat' if desc.flat else f'radius {desc.surface_radius_mm:g} mm'}", "",
           f"| parameter | RMS/CRB | RMS/CRB {ref} | 2-sigma | beyond 4 sigma | withheld | "
           "withheld where resolved | n |",
           "|---|---|---|---|---|---|---|---|"]
    for name in s.seen:
        out.append(f"| {name} | {_ratio(s.rms_over_crb(name))} | {_ratio(s.rms_over_crb(name, True))} | "
                   f"{_pct(s.coverage(name))} | {_pct(s.beyond(name), 1)} | "
                   f"{100 * s.withheld[name] / s.seen[name]:.0f} % | "
                   f"{_pct(s.withheld_resolved(name))} ({s.resolved[name]}) | {s.seen[name]} |")
    if s.reasons:
        out += ["", "withheld because: " + "; ".join(f"{k} ({v})" for k, v in s.reasons.most_common())]
    n = sum(s.contacts.values())
    out += ["", f"frames reporting one contact: {s.contacts[1]} of {n} (none {s.contacts[0]}, "
            f"several {s.contacts[2]})"]
    out += [f"learning pass ({k})" for k in s.learned]
    out.append("")
    return out


def summary_row(desc: SensorDescription, s: Scores) -> str:
    """The summary's row: cylinders, spheres and ellipsoids (an edge's radius is below what
    any array resolves; its own table has it)."""
    names = [n for n in s.seen if not n.startswith("edge/")]
    own = [r for r in (s.rms_over_crb(n) for n in names) if r is not None]
    ref = [r for r in (s.rms_over_crb(n, True) for n in names) if r is not None]
    covs = [c for c in (s.coverage(n) for n in names) if c is not None]
    if not covs:
        return f"| {desc.name} | - |"
    fars = [v for n in names for v in s.far.get(n, [])]
    seen = sum(s.seen[n] for n in names)
    resolved = sum(s.resolved[n] for n in names)
    return (f"| {desc.name} | {desc.rows}x{desc.cols} | {'flat' if desc.flat else 'curved'} | "
            f"{max(own):.2f} | {max(ref):.2f} | {100 * min(covs):.0f}-{100 * max(covs):.0f} % | "
            f"{100 * float(np.mean(fars)):.1f} % | "
            f"{100 * sum(s.withheld[n] for n in names) / seen:.0f} % | "
            f"{_pct(sum(s.resolved_withheld[n] for n in names) / resolved if resolved else None, 1)} | "
            f"{100 * s.contacts[1] / max(sum(s.contacts.values()), 1):.0f} % | "
            f"{_times(s.fit_ms)} | {_times(s.auto_ms)} | {100 * s.auto_spent / len(s.auto_ms):.1f} % |")


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
           f"{PEAK_SNR[0]:g}-{PEAK_SNR[1]:g} noise sigmas, fitted by `tactiled fit --sensor NAME` "
           "with the contact's own model (cylinder; sphere; ellipsoid = general, radii "
           f"{ELLIPSOID_RATIO[0]:g}-{ELLIPSOID_RATIO[1]:g} times apart; edge = a 0.5 mm cylinder); "
           "the reported contact nearest the truth is scored. RMS/CRB: RMS error over the "
           "Cramer-Rao bound at the truth on the fit's own window; RMS/CRB NxN: over the bound of "
           f"a {REFERENCE_WINDOW}x{REFERENCE_WINDOW} window (clipped to the array: the whole pad "
           "of a small one; a line's on its ridge); 2-sigma: errors within twice the fit's own "
           "sigma; beyond 4 sigma: published values further than four of their sigmas; "
           "withheld: values the fit withheld with a reason; withheld where resolved: of the "
           "values the reference bound resolves (a radius, force or load at least two bounds "
           f"from zero, an orientation within {OBSERVABLE_ANGLE:g} deg, an ellipse's where its "
           f"best circle also lies at least {CIRCLE_CHI2:g} in chi^2 away, a place), those withheld "
           "(how many such values in brackets). Fit times: CPU ms of the contact's own model "
           "and of auto on the same frame (auto stopped: its fits the budget stopped).", ""]
    summary = ["| description | array | surface | worst RMS/CRB | worst RMS/CRB reference | coverage range "
               "| beyond 4 sigma | withheld | withheld where resolved | one contact "
               "| fit ms p50 / p99 / max | auto ms p50 / p99 / max | auto stopped |",
               "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    live_rows = list(live_sensors.SUMMARY_HEAD)
    for spec, desc in zip(names, descs):
        s = score_description(desc, contacts, draws, seed, bar, spec=spec)
        out += description_table(desc, s)
        if live:
            ls = live_sensors.score(desc, rate, seed)
            out += live_sensors.report(desc, ls, rate)
            live_rows.append(live_sensors.summary_row(desc, ls))
        summary.append(summary_row(desc, s))
    bar.finish(f"{len(descs)} descriptions scored")
    head = ["Summary (cylinders, spheres and ellipsoids; edges in each table):", "", *summary, ""]
    if live:
        head += [f"The daemon's own estimates (`{live_sensors.SCENE}` scene at {rate:g} Hz through the "
                 "daemon with the description's simulated finger, lossless; every published value "
                 "against the truth):", "", *live_rows, ""]
    return "\n".join([*head, *out])

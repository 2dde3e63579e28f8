"""Grasps of lines, edges and balls together (``tactiled bench --suite contacts``'s grasp tables).

Each frame presses an array with a grasp's contacts at random places, angles, radii and loads,
adds the description's noise and is fitted by :func:`tactiled.fit.multi.fit_contacts` with
``auto``.  Fits are matched to truths (missed, phantoms) and matched contacts fitted with their
own model are scored against their single-contact Cramer-Rao bound and by 2-sigma coverage.
"""
# Draws: radii 3-25 mm log-uniform (an edge is a 0.5 mm cylinder), each contact's own peak 40-120
# noise sigmas.  On a flat array a cylinder is a line contact, longer than the array; on a
# curved finger a cylinder is a Hertz ellipse 30-150 deg from the finger's axis.
# * flat: two parallel lines (a handle, two bars: within 5 deg), a line and a ball, an edge and
#   a ball, a line and two balls; every two contacts at least FLAT_APART_DEPTHS cover depths
#   apart (12 mm on the 16x16 pad's 2 mm cover);
# * curved: two crossing cylinders (60-90 deg apart, each 30-150 deg from the finger's axis), a
#   cylinder and a ball, an edge and a ball, a cylinder and two balls; every two centres at
#   least RESOLVED_DEPTHS depths apart and their noise-free strain dipping between them
#   (tactiled.fit.regions.find_regions finds each);
# * single: one line (cylinder), edge or ball, which must give exactly one contact.
# A fit is a truth's when its place is within MATCH_PITCHES pitches of it (a line's: measured
# across the line).  The bound is that contact's alone on the window its fit would choose at
# the truth (its neighbours known: their strain dips to nothing between contacts this far
# apart); coverage uses its own reported sigma.

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Iterator

import numpy as np
from scipy.optimize import linear_sum_assignment

from tactiled.fit.fitter import Fitter
from tactiled.fit.models import get_model
from tactiled.fit.multi import fit_contacts
from tactiled.fit.regions import find_regions
from tactiled.physics.contact import Contact, LineContact
from tactiled.physics.strain import StrainModel
from tactiled.sensors import SensorDescription

PEAK_SNR = (40.0, 120.0)
RADII = (3.0, 25.0)
EDGE_RADIUS = 0.5
#: On a flat array every two contacts at least this many cover depths apart.
FLAT_APART_DEPTHS = 6.0
RESOLVED_DEPTHS = 2.5
#: On a curved finger every cylinder lies this many degrees from the finger's axis (nearer, it
#: is a line longer than the finger, outside the planar model: docs/concepts/fitting.md).
CURVED_ANGLES = (30.0, 150.0)
MATCH_PITCHES = 1.5
#: A line's errors are also compared with the bound of a square window of this side on its ridge.
SQUARE_WINDOW = 6
FLAT_GRASPS = {"line+line": ("line", "line"), "line+ball": ("line", "ball"),
               "edge+ball": ("edge", "ball"), "line+ball+ball": ("line", "ball", "ball")}
CURVED_GRASPS = {"crossing": ("cylinder", "cylinder"), "cylinder+ball": ("cylinder", "ball"),
                 "edge+ball": ("edge", "ball"), "cylinder+ball+ball": ("cylinder", "ball", "ball")}
SINGLES = ("line", "edge", "ball")
LINE_KEYS = ("r1_mm", "angle_deg", "load_n_per_mm", "offset_mm")
SPHERE_KEYS = ("x_mm", "y_mm", "force_n", "r1_mm")
CYLINDER_KEYS = ("x_mm", "y_mm", "force_n", "r1_mm", "angle_deg")


def _scaled(model: StrainModel, make, snr: float):
    sigma = model.sensor.noise.sigma
    scale = 1.0
    for _ in range(2):
        scale *= snr * sigma / float(model.predict(make(scale)).max())
    return make(scale)


def _one(kind: str, rng: np.random.Generator, model: StrainModel, xy: tuple[float, float],
         psi: float | None = None) -> Contact | LineContact:
    g = model.sensor.geometry
    r = EDGE_RADIUS if kind == "edge" else math.exp(rng.uniform(*np.log(RADII)))
    snr = float(rng.uniform(*PEAK_SNR))
    if kind == "ball":
        return _scaled(model, lambda s: Contact(r, r, 0.0, s, *xy), snr)
    if psi is None:
        psi = float(rng.uniform(0.0, 180.0) if g.flat else rng.uniform(*CURVED_ANGLES))
    psi %= 180.0  # the reported angle's range, which the offset's sign follows
    if g.flat:
        return _scaled(model, lambda s: LineContact(r, psi, 0.1 * s, *xy), snr)
    return _scaled(model, lambda s: Contact(r, math.inf, psi, s, *xy), snr)


def _apart(a: Contact | LineContact, b: Contact | LineContact) -> float:
    """A line's distance from the other's place (lines: parallel ones' distance), else the
    centres'."""
    if isinstance(a, LineContact):
        return abs(-math.sin(a.psi) * (b.x0 - a.x0) + math.cos(a.psi) * (b.y0 - a.y0))
    if isinstance(b, LineContact):
        return _apart(b, a)
    return math.dist((a.x0, a.y0), (b.x0, b.y0))


def draw(kinds: tuple[str, ...], rng: np.random.Generator, model: StrainModel,
         depth: float) -> list[Contact | LineContact] | None:
    """A grasp of ``kinds`` as the module's doc says, or None when none was found."""
    g = model.sensor.geometry
    sigma = model.sensor.noise.sigma
    lo = (FLAT_APART_DEPTHS if g.flat else RESOLVED_DEPTHS) * depth
    lines = [k for k in kinds if k in ("line", "cylinder")]
    for _ in range(400):
        base = float(rng.uniform(0.0, 180.0) if g.flat else rng.uniform(30.0, 90.0))
        angles: list[float | None] = []
        for i, k in enumerate(kinds):
            if k == "line" and len(lines) > 1:
                angles.append(base + (float(rng.uniform(-5.0, 5.0)) if i else 0.0))
            elif k == "cylinder" and len(lines) > 1:
                angles.append(base + (float(rng.uniform(60.0, 90.0)) if i else 0.0))
            else:
                angles.append(None)
        if not g.flat and any(a is not None and not CURVED_ANGLES[0] <= a <= CURVED_ANGLES[1] for a in angles):
            continue  # nearer its axis a cylinder is a line longer than the finger: not drawn
        places = [(g.span_x * rng.uniform(0.15, 0.85), g.span_y * rng.uniform(0.15, 0.85)) for _ in kinds]
        try:
            truths = [_one(k, rng, model, xy, psi) for k, xy, psi in zip(kinds, places, angles)]
            if any(_apart(a, b) < lo for i, a in enumerate(truths) for b in truths[i + 1:]):
                continue
            clean = sum(model.predict(c) for c in truths)
        except ValueError:  # a contact too long for the planar model at that load
            continue
        if not g.flat and len(find_regions(clean, sigma)) != len(truths):
            continue
        return truths
    return None


def _err(key: str, est: float, true: float) -> float:
    return (est - true + 90.0) % 180.0 - 90.0 if key == "angle_deg" else est - true


def _truth_values(c: Contact | LineContact, centre: tuple[float, float]) -> dict[str, float]:
    if isinstance(c, LineContact):
        return {"r1_mm": c.r1, "angle_deg": c.psi_deg % 180.0, "load_n_per_mm": c.load,
                "offset_mm": c.offset_from(*centre)}
    return {"x_mm": c.x0, "y_mm": c.y0, "force_n": c.force, "r1_mm": c.r1, "angle_deg": c.psi_deg % 180.0}


class Tally:
    """What one grasp's frames scored."""

    def __init__(self) -> None:
        self.count: Counter = Counter()
        self.z: dict[str, list[float]] = {}
        self.cov: dict[str, list[bool]] = {}
        self.fit_ms: list[float] = []
        #: a line's errors over a square 6x6 window's bound (what a window cut from the ridge
        #: could do at best: ``Fitter.line_cramer_rao(window=6)``)
        self.z6: dict[str, list[float]] = {}

    def add(self, key: str, err: float | None, crb: float | None, sd: float | None) -> None:
        self.count[f"seen {key}"] += 1
        if err is None:
            self.count[f"withheld {key}"] += 1
            return
        if crb:
            self.z.setdefault(key, []).append(err / crb)
        self.cov.setdefault(key, []).append(sd is not None and abs(err) <= 2.0 * sd)

    def rms(self, keys: list[str] | None = None) -> float | None:
        z = [v for k, zs in self.z.items() if keys is None or k in keys for v in zs]
        return float(np.sqrt(np.mean(np.square(z)))) if z else None


def _line_values(res, key: str) -> tuple[float | None, float | None]:
    line = res.line or {}
    if key in ("load_n_per_mm", "offset_mm"):
        return line.get(key), line.get(f"{key}_std")
    return res.values.get(key), res.std.get(key)


def match(truths: list, fits: list, gate: float, count: Counter) -> list[tuple[int, int]]:
    """The ``(truth, fit)`` index pairs of ``truths`` and fits ``fits`` matched by place (a
    line truth: the fit's distance across the line) within ``gate`` mm, nearest overall;
    ``count`` gains the truths, misses, fits and phantoms."""
    cost = np.full((len(truths), len(fits)), 1e6)
    for i, c in enumerate(truths):
        for j, r in enumerate(fits):
            x, y = r.values.get("x_mm"), r.values.get("y_mm")
            if x is not None and y is not None:
                place = Contact(1.0, 1.0, 0.0, 1.0, x, y)
                cost[i, j] = _apart(c, place) if isinstance(c, LineContact) else math.dist((c.x0, c.y0), (x, y))
    rows, cols = linear_sum_assignment(cost) if fits else ((), ())
    pairs = [(i, j) for i, j in zip(rows, cols) if cost[i, j] <= gate]
    count["truths"] += len(truths)
    count["missed"] += len(truths) - len(pairs)
    count["fits"] += len(fits)
    count["phantom"] += len(fits) - len(pairs)
    return pairs


def score_frame(fitter: Fitter, model: StrainModel, truths: list[Contact | LineContact],
                frame: np.ndarray, tally: Tally, kind_of: list[str]) -> None:
    """Fit one frame and add its matches, misses, phantoms and errors to ``tally``."""
    t0 = time.thread_time()
    fits = [r for r in fit_contacts(fitter, frame, "auto") if r.contact]
    tally.fit_ms.append((time.thread_time() - t0) * 1e3)
    g = model.sensor.geometry
    pairs = match(truths, fits, MATCH_PITCHES * max(g.dx, g.dy), tally.count)
    centre = (0.5 * g.span_x, 0.5 * g.span_y)
    for i, j in pairs:
        c, r, kind = truths[i], fits[j], kind_of[i]
        own = "sphere" if kind == "ball" else "cylinder"
        tally.count["matched"] += 1
        if r.model != own:
            continue
        tally.count["own model"] += 1
        alone = model.predict(c)
        truth = _truth_values(c, centre)
        if isinstance(c, LineContact):
            crb = fitter.line_cramer_rao(alone, c)
            six = fitter.line_cramer_rao(alone, c, window=SQUARE_WINDOW)
            for key in LINE_KEYS:
                est, sd = _line_values(r, key)
                err = None
                if est is not None:
                    err = _err(key, est, truth[key])
                    ang = r.values.get("angle_deg")
                    if key == "offset_mm" and ang is not None and math.cos(math.radians(ang - truth["angle_deg"])) < 0:
                        err = est + truth[key]  # the offset's sign follows the reported angle
                tally.add(f"{kind}/{key}", err, crb.get(key), sd)
                if err is not None and six.get(key):
                    tally.z6.setdefault(f"{kind}/{key}", []).append(err / six[key])
            continue
        p = get_model(own).from_values(c.r1, c.r2, c.psi_deg, c.force, c.x0, c.y0)
        crb = fitter.cramer_rao(alone, own, p)
        for key in (SPHERE_KEYS if own == "sphere" else CYLINDER_KEYS):
            est = r.values.get(key)
            tally.add(f"{kind}/{key}", None if est is None else _err(key, est, truth[key]),
                      crb.get(key), r.std.get(key))


def frames_of(model: StrainModel, frames: int, rng: np.random.Generator
              ) -> Iterator[tuple[str, tuple[str, ...], list[Contact | LineContact] | None, np.ndarray | None]]:
    """Each grasp's ``frames`` frames, then as many single contacts (grasp ``single``), in the
    order :func:`score` fits them: ``(grasp, kinds, truths, frame)``, truths and frame None
    where no grasp could be drawn."""
    sensor = model.sensor
    depth = max(sensor.impulse.depth_x, sensor.impulse.depth_y)
    sigma = sensor.noise.sigma
    g = sensor.geometry
    for name, kinds in (FLAT_GRASPS if g.flat else CURVED_GRASPS).items():
        for _ in range(frames):
            truths = draw(kinds, rng, model, depth)
            if truths is None:
                yield name, kinds, None, None
                continue
            clean = sum(model.predict(c) for c in truths)
            yield name, kinds, truths, clean + rng.normal(0.0, sigma, clean.shape)
    for f in range(frames):
        kind = SINGLES[f % len(SINGLES)]
        kind = "cylinder" if kind == "line" and not g.flat else kind
        place = (g.span_x * rng.uniform(0.25, 0.75), g.span_y * rng.uniform(0.25, 0.75))
        c = _one(kind, rng, model, place)
        yield "single", (kind,), [c], model.predict(c) + rng.normal(0.0, sigma, (g.rows, g.cols))


def score(desc: SensorDescription, fitter: Fitter, model: StrainModel, frames: int,
          rng: np.random.Generator, bar=None) -> tuple[dict[str, Tally], Counter]:
    """Each grasp's tally over ``frames`` frames, and the single contacts' counts of fits."""
    out: dict[str, Tally] = {}
    singles: Counter = Counter()
    for name, kinds, truths, frame in frames_of(model, frames, rng):
        tally = out.setdefault(name, Tally())
        if bar is not None:
            bar.step()
        if truths is None:
            tally.count["undrawn"] += 1
            continue
        before = tally.count["fits"]
        score_frame(fitter, model, truths, frame, tally, list(kinds))
        if name == "single":
            singles["one" if tally.count["fits"] - before == 1 else "other"] += 1
    return out, singles


def report(tallies: dict[str, Tally], singles: Counter) -> list[str]:
    """The grasp table's Markdown lines."""
    out = ["| grasp | contacts | found | phantom | own model | RMS/CRB | 2-sigma | withheld | fit ms p50 / p99 / max |",
           "|---|---|---|---|---|---|---|---|---|"]
    for name, t in tallies.items():
        c = t.count
        if not c["truths"]:
            continue
        cov = [v for vs in t.cov.values() for v in vs]
        seen = sum(v for k, v in c.items() if k.startswith("seen "))
        withheld = sum(v for k, v in c.items() if k.startswith("withheld "))
        rms = t.rms()
        ms = np.array(t.fit_ms)
        out.append(f"| {name} | {c['truths']} | {100 * (c['truths'] - c['missed']) / c['truths']:.1f} % | "
                   f"{100 * c['phantom'] / max(c['fits'], 1):.1f} % | {c['own model']} of {c['matched']} | "
                   f"{'-' if rms is None else f'{rms:.2f}'} | "
                   f"{'-' if not cov else f'{100 * np.mean(cov):.0f} %'} | "
                   f"{100 * withheld / max(seen, 1):.0f} % | "
                   f"{np.median(ms):.2f} / {np.percentile(ms, 99):.2f} / {ms.max():.2f} |")
    worst = []
    for name, t in tallies.items():
        for key, z in t.z.items():
            worst.append((float(np.sqrt(np.mean(np.square(z)))), f"{name} {key}",
                          100 * float(np.mean(t.cov[key]))))
    worst.sort(reverse=True)
    single = tallies.get("single")
    six = ("; ".join(f"{k} {float(np.sqrt(np.mean(np.square(z)))):.2f}" for k, z in single.z6.items())
           if single is not None and single.z6 else None)
    out += ["", "single contacts giving exactly one contact: "
            f"{singles['one']} of {singles['one'] + singles['other']}",
            "worst parameters (RMS/CRB, 2-sigma): "
            + "; ".join(f"{n} {r:.2f}, {cv:.0f} %" for r, n, cv in worst[:4])]
    if six:
        out.append(f"single lines, RMS error over a {SQUARE_WINDOW}x{SQUARE_WINDOW} window's bound: {six}")
    out.append("")
    return out

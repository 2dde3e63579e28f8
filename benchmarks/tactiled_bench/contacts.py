"""Several contacts on one array (``tactiled bench --suite contacts``).

Frames of two and three simultaneous contacts on the paper's finger and a flat 16x16 array (or
``--sensor``'s), fitted by :func:`tactiled.fit.multi.fit_contacts`: resolved, close, tracked
(:mod:`tactiled_bench.tracked_contacts`), grasps (:mod:`tactiled_bench.grasps`) and single
frames.  Scores: missed, phantoms, RMS error over the joint model's Cramer-Rao bound, 2-sigma
coverage.
"""
# Contacts: spheres, and on a curved finger cylinders too, each pressed to a peak of 40-120 noise
# sigmas at random places in the array's middle; all contacts of a frame of one kind, fitted with
# that model.
# * Resolved: contacts at least RESOLVED_DEPTHS cover depths apart whose noise-free strain dips
#   between every two (what tells contacts apart: a large contact spreads wider than the cover
#   alone); each must be found.  Fits match truths by position (within MATCH_PITCHES pitches);
#   the bound is at the truth with every contact's parameters unknown, on the union of the fitted
#   windows (tactiled.fit.multi.joint_bounds); coverage is within twice the reported sigma.
# * Close: two contacts 1-2 depths apart with no dip between them: how often reported as two, as
#   one (merged or not), or otherwise.
# * Tracked: the hand-palm grasp (up to three contacts) through the whole daemon, each contact's
#   filter against the scene's truth.
# * Grasps: lines, edges and balls together, and single contacts of each, fitted with auto.
# * Single: one contact (on a flat array, spheres and line contacts, whose ridge the grid samples
#   as several bumps), fitted by fit_contacts and by the single-contact fitter; the two results
#   must be the same, key for key.

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Iterator, Sequence

import numpy as np

from tactiled_bench import grasps, tracked_contacts
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.models import get_model
from tactiled.fit.multi import fit_contacts, joint_bounds
from tactiled.fit.regions import find_regions
from tactiled.physics.contact import Contact, LineContact
from tactiled.physics.strain import StrainModel
from tactiled.progress import Progress
from tactiled.sensors import SensorDescription, load_description

#: Peak strain of each simulated contact alone, in noise sigmas.
PEAK_SNR = (40.0, 120.0)
RADII = (3.0, 25.0)
#: Resolved frames: contacts at least this many cover depths apart.
RESOLVED_DEPTHS = 2.5
#: Close frames: two contacts this many depths apart.
CLOSE_DEPTHS = (1.0, 2.0)
#: A fit within this many pitches of a truth is that truth's.
MATCH_PITCHES = 1.5
DEFAULT_SENSORS = ("fearing1988", "flat16")
KEYS = {"sphere": ("x_mm", "y_mm", "force_n", "r1_mm"),
        "cylinder": ("x_mm", "y_mm", "force_n", "r1_mm", "angle_deg")}


def _scaled(model: StrainModel, make, snr: float, sigma: float) -> Contact:
    scale = 1.0
    for _ in range(2):
        scale *= snr * sigma / float(model.predict(make(scale)).max())
    return make(scale)


def _contact(kind: str, rng: np.random.Generator, model: StrainModel, xy: tuple[float, float]) -> Contact:
    r = math.exp(rng.uniform(*np.log(RADII)))
    snr = float(rng.uniform(*PEAK_SNR))
    x0, y0 = xy
    if kind == "sphere":
        make = lambda s: Contact(r, r, 0.0, s, x0, y0)  # noqa: E731
    else:
        psi = float(rng.uniform(30.0, 150.0))
        make = lambda s: Contact(r, math.inf, psi, s, x0, y0)  # noqa: E731
    return _scaled(model, make, snr, model.sensor.noise.sigma)


def _line(rng: np.random.Generator, model: StrainModel, xy: tuple[float, float]) -> LineContact:
    """A cylinder on a flat array (a line contact) through ``xy``, at any angle."""
    r = math.exp(rng.uniform(*np.log(RADII)))
    psi = float(rng.uniform(0.0, 180.0))
    snr = float(rng.uniform(*PEAK_SNR))
    make = lambda s: LineContact(r, psi, 0.1 * s, *xy)  # noqa: E731
    return _scaled(model, make, snr, model.sensor.noise.sigma)


def _places(n: int, rng: np.random.Generator, desc: SensorDescription, lo: float,
            hi: float = math.inf) -> list[tuple[float, float]] | None:
    """``n`` places in the array's middle 80 %, every pair between ``lo`` and ``hi`` mm apart."""
    g = desc.sensor_model().geometry
    for _ in range(2000):
        pts = [(g.span_x * rng.uniform(0.1, 0.9), g.span_y * rng.uniform(0.1, 0.9)) for _ in range(n)]
        d = [math.dist(a, b) for i, a in enumerate(pts) for b in pts[i + 1:]]
        if not d or (min(d) >= lo and max(d) <= hi):
            return pts
    return None


def _draw(n: int, kind: str, rng: np.random.Generator, desc: SensorDescription, model: StrainModel,
          regions: int, lo: float, hi: float = math.inf) -> tuple[list[Contact], np.ndarray] | None:
    """``n`` contacts ``lo``-``hi`` mm apart whose noise-free strain shows ``regions`` separate
    regions (:func:`find_regions`: a dip between them, or none), and that strain."""
    sigma = model.sensor.noise.sigma
    for _ in range(200):
        places = _places(n, rng, desc, lo, hi)
        if places is None:
            return None
        truths = [_contact(kind, rng, model, p) for p in places]
        clean = sum(model.predict(c) for c in truths)
        if len(find_regions(clean, sigma)) == regions:
            return truths, clean
    return None


def _err(key: str, est: float, true: float) -> float:
    return (est - true + 90.0) % 180.0 - 90.0 if key == "angle_deg" else est - true


def _truth(c: Contact) -> dict[str, float]:
    return {"x_mm": c.x0, "y_mm": c.y0, "force_n": c.force, "r1_mm": c.r1, "angle_deg": c.psi_deg % 180.0}


class _Tally:
    def __init__(self) -> None:
        self.z: dict[str, list[float]] = {}
        self.cov: dict[str, list[bool]] = {}
        self.count: Counter = Counter()
        self.fit_ms: list[float] = []

    def merge(self, other: "_Tally") -> None:
        self.count.update(other.count)
        self.fit_ms += other.fit_ms
        for key, z in other.z.items():
            self.z.setdefault(key, []).extend(z)
        for key, c in other.cov.items():
            self.cov.setdefault(key, []).extend(c)

    def add(self, key: str, err: float, crb: float | None, sd: float | None) -> None:
        if crb:
            self.z.setdefault(key, []).append(err / crb)
        self.cov.setdefault(key, []).append(sd is not None and abs(err) <= 2.0 * sd)


def _score_frame(fitter: Fitter, desc: SensorDescription, kind: str, truths: list[Contact],
                 frame: np.ndarray, tally: _Tally) -> list:
    t0 = time.thread_time()  # the fitting thread's CPU, as the grasps' (wall time counts the load)
    fits = [r for r in fit_contacts(fitter, frame, kind) if r.contact]
    tally.fit_ms.append((time.thread_time() - t0) * 1e3)
    g = fitter.sensor.geometry
    pairs = grasps.match(truths, fits, MATCH_PITCHES * max(g.dx, g.dy), tally.count)
    if not pairs:
        return fits
    union = np.zeros((g.rows, g.cols), bool)
    for r in fits:
        if r.window is not None:
            r0, c0, nr, nc = r.window
            union[r0:r0 + nr, c0:c0 + nc] = True
    model = get_model(kind)
    truth_params = [(kind, tuple(model.from_values(c.r1, c.r2, c.psi_deg, c.force, c.x0, c.y0)))
                    for c in truths]
    bounds = joint_bounds(fitter, truth_params, union)
    for i, j in pairs:
        r, true = fits[j], _truth(truths[i])
        for key in KEYS[kind]:
            est = r.values.get(key)
            if est is None:
                tally.count[f"withheld {key}"] += 1
                continue
            crb = None if bounds is None else bounds[0][i].get(key)
            tally.add(f"{kind}/{key}", _err(key, est, true[key]), crb, r.std.get(key))
    return fits


def frames_of(desc: SensorDescription, model: StrainModel, frames: int,
              rng: np.random.Generator) -> Iterator[tuple[str, str, list[Contact | LineContact], np.ndarray]]:
    """The resolved, close and single frames of one description, in the order :func:`score`
    fits them: ``(part, kind, truths, frame)``, part ``resolved``, ``close`` or ``single``
    (a frame that could not be drawn is left out).  The grasps' frames follow from the same
    ``rng`` (:func:`tactiled_bench.grasps.frames_of`)."""
    sigma = model.sensor.noise.sigma
    depth = max(model.sensor.impulse.depth_x, model.sensor.impulse.depth_y)
    kinds = ("sphere",) if desc.flat else ("sphere", "cylinder")
    for n in (2, 3):
        for f in range(frames):
            kind = kinds[f % len(kinds)]
            drawn = _draw(n, kind, rng, desc, model, n, RESOLVED_DEPTHS * depth)
            if drawn is not None:
                yield "resolved", kind, drawn[0], drawn[1] + rng.normal(0.0, sigma, drawn[1].shape)
    for f in range(frames):
        kind = kinds[f % len(kinds)]
        drawn = _draw(2, kind, rng, desc, model, 1, CLOSE_DEPTHS[0] * depth, CLOSE_DEPTHS[1] * depth)
        if drawn is not None:
            yield "close", kind, drawn[0], drawn[1] + rng.normal(0.0, sigma, drawn[1].shape)
    singles = ("sphere", "line") if desc.flat else kinds
    for f in range(frames):
        kind = singles[f % len(singles)]
        place = _places(1, rng, desc, 0.0)[0]  # type: ignore[index]
        c = _line(rng, model, place) if kind == "line" else _contact(kind, rng, model, place)
        yield "single", kind, [c], model.predict(c) + rng.normal(0.0, sigma, (desc.rows, desc.cols))


def rng_of(desc: SensorDescription, seed: int) -> np.random.Generator:
    """The suite's random draws for ``desc`` (every frame of :func:`frames_of`, then the grasps')."""
    return np.random.default_rng([seed, sum(desc.name.encode())])


def score(desc: SensorDescription, frames: int, seed: int, bar: Progress | None = None) -> dict:
    """The resolved, close and single tallies of one description."""
    sensor = desc.sensor_model()
    model = StrainModel(sensor)
    fitter = Fitter(sensor, FitOptions(window=desc.window))
    fitter.frozen = True  # every frame alike, whatever came before it
    rng = rng_of(desc, seed)
    resolved, close, single, close_tally = _Tally(), Counter(), Counter(), _Tally()
    for part, kind, truths, frame in frames_of(desc, model, frames, rng):
        if part == "resolved":
            _score_frame(fitter, desc, kind, truths, frame, resolved)
        elif part == "close":
            pair = _Tally()
            fits = _score_frame(fitter, desc, kind, truths, frame, pair)
            if len(fits) == 2:  # told apart: scored as the resolved are (one, merged, is no measurement of either)
                close_tally.merge(pair)
            close["two" if len(fits) == 2 else "one, merged" if len(fits) == 1 and fits[0].label == "merged"
                  else "one" if len(fits) == 1 else f"{len(fits)}"] += 1
        else:
            fit_model = "cylinder" if kind == "line" else kind
            a = fit_contacts(fitter, frame, fit_model)
            b = fitter.fit(frame, fit_model)
            same = len(a) == 1 and _same(a[0].to_json_dict(), b.to_json_dict())
            single["same" if same else "different"] += 1
        if bar is not None:
            bar.step()
    grasped, grasp_singles = grasps.score(desc, fitter, model, frames, rng, bar)
    return {"resolved": resolved, "close": close, "close_tally": close_tally, "single": single, "grasps": grasped,
            "grasp_singles": grasp_singles}


def _close_line(t: _Tally) -> str:
    """The close pairs reported as two: their contacts found, and their errors over the joint
    bound and their sigmas (every parameter together)."""
    c = t.count
    z = [v for zs in t.z.values() for v in zs]
    cov = [v for vs in t.cov.values() for v in vs]
    rms = f"{float(np.sqrt(np.mean(np.square(z)))):.2f}" if z else "-"
    inside = f"{100 * np.mean(cov):.0f} %" if cov else "-"
    return (f"of those reported as two, contacts found {100 * (c['truths'] - c['missed']) / max(c['truths'], 1):.0f} %, "
            f"phantom {c['phantom']}, RMS/CRB {rms}, 2-sigma {inside}")


def _same(a: dict, b: dict) -> bool:
    a, b = dict(a), dict(b)
    a.pop("fit_ms", None)
    b.pop("fit_ms", None)
    return a == b


def run(quick: bool, progress: bool | None, names: Sequence[str] | None = None, seed: int = 1) -> str:
    """The suite's Markdown report."""
    names = list(names) if names else list(DEFAULT_SENSORS)
    frames = 12 if quick else 60
    descs = [load_description(n) for n in names]
    bar = Progress(len(descs) * frames * (4 + len(grasps.FLAT_GRASPS) + 1), "contacts", progress)
    out = [f"Each description: {frames} frames of two and {frames} of three contacts at least "
           f"{RESOLVED_DEPTHS:g} cover depths apart (resolved), {frames} of two contacts "
           f"{CLOSE_DEPTHS[0]:g}-{CLOSE_DEPTHS[1]:g} depths apart (close), {frames} of one; "
           f"each contact's peak {PEAK_SNR[0]:g}-{PEAK_SNR[1]:g} noise sigmas. RMS/CRB against the "
           "joint model's bound at the truth; 2-sigma: errors within twice the reported sigma. "
           f"Grasps: {frames} frames of each grasp of lines, edges and balls and {frames} single "
           "contacts, fitted with auto (tactiled_bench.grasps: found, phantoms, RMS/CRB against "
           "each contact's own bound, fit CPU ms per frame).", ""]
    for desc in descs:
        s = score(desc, frames, seed, bar)
        r: _Tally = s["resolved"]
        c = r.count
        ms = np.array(r.fit_ms) if r.fit_ms else np.zeros(1)
        out += [f"### {desc.name}: {desc.rows}x{desc.cols}, {desc.pitch_x_mm:g} x {desc.pitch_y_mm:g} mm, "
                f"{'flat' if desc.flat else f'radius {desc.surface_radius_mm:g} mm'}", "",
                f"resolved: {c['truths']} contacts, missed {100 * c['missed'] / max(c['truths'], 1):.1f} %, "
                f"phantom {100 * c['phantom'] / max(c['fits'], 1):.1f} % of {c['fits']} fits; "
                f"fit CPU ms per frame p50 {np.median(ms):.2f}, p99 {np.percentile(ms, 99):.2f}", "",
                "| parameter | RMS/CRB | 2-sigma | n |", "|---|---|---|---|"]
        for key in r.cov:
            z = r.z.get(key)
            rms = float(np.sqrt(np.mean(np.square(z)))) if z else None
            out.append(f"| {key} | {'-' if rms is None else f'{rms:.2f}'} | "
                       f"{100 * np.mean(r.cov[key]):.0f} % | {len(r.cov[key])} |")
        withheld = {k: v for k, v in c.items() if k.startswith("withheld")}
        out += ["", "withheld: " + (", ".join(f"{k[9:]} {v}" for k, v in withheld.items()) or "none"),
                "close pairs reported as: " + ", ".join(f"{k} {v}" for k, v in s["close"].most_common())
                + "; " + _close_line(s["close_tally"]),
                f"single contacts, same result as the single-contact fitter: "
                f"{s['single']['same']} of {sum(s['single'].values())}", "",
                "grasps (auto):", ""]
        out += grasps.report(s["grasps"], s["grasp_singles"])
        out += tracked_contacts.report(desc, tracked_contacts.score(desc, seed))
    bar.finish(f"{len(descs)} descriptions")
    return "\n".join(out)

"""The daemon's own estimates on every built-in description, against the truth (part of
``tactiled bench --suite sensors``).

The ``demo`` scene is played once by each description's simulated finger (no drift or
hysteresis) through the whole daemon in lossless mode, model ``auto``; every published contact
value is compared with the scene's truth at its frame.  Deterministic (seeded scene noise,
lossless): the same figures on every machine.
"""
# The scene: a 10 mm cylinder pressed, rolled, turned, held and released; an 8 mm sphere; a
# 0.5 mm knife edge.  The path: wire bytes -> decoder -> zeroing -> detector -> gate -> fits in a
# real worker process -> the tracker, reuse and the several-contacts association -> the one rule
# of tactiled.fit.verdict.  Scores:
# * 2-sigma: the share of published values within twice their reported sigma (95 % for honest
#   sigmas);
# * beyond 4 sigma: the share further than four sigmas from the truth (6e-5 for honest Gaussian
#   sigmas), and the share of contact estimates with any;
# * withheld: the share of values published as null with a reason; and of a point contact's
#   force and radius that the Cramer-Rao bound at the truth on a 6x6 window (the whole pad of
#   a smaller array) resolves (at least two bounds from zero), the share withheld;
# * stale: the longest run of estimates in which a value stayed bit-identical while its contact
#   moved (its true centre or orientation changed);
# * phantoms: contact estimates listing more than one contact (the scene touches once).
# A line on a flat array (the cylinder there) has no centre along it: its place is scored across
# the line only (offset), and its total force is not a value it reports.

from __future__ import annotations

import math
from typing import Any

from tactiled_bench.lossless import play_lossless
from tactiled_bench.runner import OBSERVABLE_RELATIVE
from tactiled.sensors import SensorDescription

SCENE = "demo"
KEYS = ("offset", "x_mm", "y_mm", "force_n", "r1_mm", "angle_deg")
#: a value this many reported sigmas from the truth is a confident wrong value
FAR_SIGMAS = 4.0
#: Side of the square window of the reference bound a withheld value is scored against
#: (clipped to the array; ``tactiled bench --suite sensors``'s fits are scored against it too).
REFERENCE_WINDOW = 6


#: How long (s) the bench waits for its fit worker to be ready: the most ``fit.startup_timeout``
#: allows.  A worker builds its description's Fitter before it is ready (flat32's took 50 s on
#: a loaded machine); the daemon starts streaming only once it is, so the bench waits for
#: readiness, not for a time a quiet machine happens to need.
WORKER_READY_S = 3600.0


def play(desc: SensorDescription, rate: float, seed: int,
         scene: str = SCENE) -> list[tuple[int, dict[str, Any]]]:
    """The daemon's estimates of one pass of the scene (a name in ``tactiled.sim.SCENES``):
    ``(tick, fit dict)``."""
    url = (f"sim://?scene={scene}&sensor={desc.name}&seed={seed}&rate={rate:g}&speed=0&loop=0"
           "&drift=0&hysteresis=0")
    overrides = {"sensor[0].url": url, "sensor[0].description": desc.name, "fit.workers": 1,
                 "fit.startup_timeout": WORKER_READY_S}
    return [(round(it.device_time_us * 1e-6 * rate), it.fit) for it in play_lossless(overrides)]


def truth(desc: SensorDescription, rate: float, ticks: int,
          scene: str = SCENE) -> list[list[Any]]:
    """The scene's true contacts at each tick."""
    from tactiled.sim import FingerSimulator

    sim = FingerSimulator(desc.sensor_model(), scene, rate_hz=rate, noise=0.0, drift=None,
                          hysteresis=None, loop=False)
    return [list(sim.step().contacts) for _ in range(ticks)]


def _errors(fit: dict[str, Any], c: Any, flat: bool) -> dict[str, tuple[float | None, float | None]]:
    """Per key: (error, reported sigma), or (None, None) for a withheld value; keys a contact
    does not have are left out."""
    std = fit.get("std") or {}
    out: dict[str, tuple[float | None, float | None]] = {}
    line = flat and math.isinf(c.r2)
    if line:
        x, y, sx, sy = fit.get("x_mm"), fit.get("y_mm"), std.get("x_mm"), std.get("y_mm")
        if None in (x, y, sx, sy):
            out["offset"] = (None, None)
        else:
            psi = math.radians(c.psi_deg)
            nx, ny = -math.sin(psi), math.cos(psi)
            out["offset"] = ((x - c.x0) * nx + (y - c.y0) * ny, math.hypot(sx * nx, sy * ny))
    else:
        for key, t in (("x_mm", c.x0), ("y_mm", c.y0), ("force_n", c.force)):
            v = fit.get(key)
            out[key] = (None, None) if v is None else (v - t, std.get(key))
    v = fit.get("r1_mm")
    out["r1_mm"] = (None, None) if v is None else (v - c.r1, std.get("r1_mm"))
    if math.isinf(c.r2):
        v = fit.get("angle_deg")
        out["angle_deg"] = ((None, None) if v is None else
                            ((v - c.psi_deg + 90.0) % 180.0 - 90.0, std.get("angle_deg")))
    return out


def score(desc: SensorDescription, rate: float = 200.0, seed: int = 1,
          estimates: list[tuple[int, dict[str, Any]]] | None = None) -> dict[str, Any]:
    """The live figures of one description (see the module's doc); ``estimates``: those
    :func:`play` gave already for ``desc``, ``rate`` and ``seed``."""
    estimates = play(desc, rate, seed) if estimates is None else estimates
    ticks = max((t for t, _ in estimates), default=0) + 1
    true = truth(desc, rate, ticks)
    flat = math.isinf(desc.sensor_model().geometry.finger_radius)
    n = {k: 0 for k in KEYS}
    withheld = dict(n)
    resolved = dict(n)  # the whole pad's (a 6x6 window's) bound at the truth resolves it
    resolved_withheld = dict(n)
    bound = _reference_bound(desc)
    covered = dict(n)
    far = dict(n)
    stale = dict(n)
    counts = {"contact_estimates": 0, "with_far": 0, "phantom": 0, "missed": 0}
    run: dict[str, tuple[Any, int, Any]] = {}
    for tick, fit in estimates:
        if not 0 <= tick < len(true) or not true[tick]:
            continue
        c = true[tick][0]
        if not fit.get("contact"):
            counts["missed"] += 1
            run.clear()
            continue
        counts["contact_estimates"] += 1
        counts["phantom"] += len(fit.get("contacts") or ()) > 1
        any_far = False
        bounds = None
        for key, (err, sd) in _errors(fit, c, flat).items():
            n[key] += 1
            if key in RESOLVED_KEYS:
                bounds = bound(c) if bounds is None else bounds
                ok = _resolves(bounds.get(key), getattr(c, "force" if key == "force_n" else "r1"))
                resolved[key] += ok
                resolved_withheld[key] += ok and err is None
            if err is None:
                withheld[key] += 1
                continue
            z = abs(err) / sd if sd else math.inf
            covered[key] += z <= 2.0
            if z > FAR_SIGMAS:
                far[key] += 1
                any_far = True
        counts["with_far"] += any_far
        pose = (c.x0, c.y0, c.psi_deg)
        for key in ("x_mm", "y_mm", "force_n", "r1_mm", "angle_deg"):
            v = fit.get(key)
            last = run.get(key)
            if v is None or last is None or last[0] != v:
                run[key] = (v, 1, pose)
                continue
            moved = last[2] != pose
            run[key] = (v, last[1] + 1, last[2])
            if moved:
                stale[key] = max(stale[key], last[1] + 1)
    return {"n": n, "withheld": withheld, "covered": covered, "far": far, "stale": stale,
            "counts": counts, "resolved": resolved, "resolved_withheld": resolved_withheld}


#: The values whose withholding is scored against the bound at the truth (a ball's or an
#: ellipse's force and radius; a line's are not: its total force is no value it reports).
RESOLVED_KEYS = ("force_n", "r1_mm")


def _reference_bound(desc: SensorDescription):
    """``bound(contact)``: the Cramer-Rao bounds at the true point contact ``contact`` on a
    ``REFERENCE_WINDOW``-square window (the whole pad of a smaller array), as
    ``tactiled bench --suite sensors`` scores its fits; ``{}`` for a line on a flat array."""
    from tactiled.fit.fitter import FitOptions, Fitter
    from tactiled.fit.models import get_model
    from tactiled.physics.strain import StrainModel

    sensor = desc.sensor_model()
    model = StrainModel(sensor)
    ref = Fitter(sensor, FitOptions(window=max(REFERENCE_WINDOW, desc.window)), warm=False)
    flat = math.isinf(sensor.geometry.finger_radius)

    def bound(c: Any) -> dict[str, float]:
        if math.isinf(c.r2) and flat:
            return {}
        name = "cylinder" if math.isinf(c.r2) else "sphere" if c.r1 == c.r2 else "general"
        p = get_model(name).from_values(c.r1, c.r2, c.psi_deg, c.force, c.x0, c.y0)
        return ref.cramer_rao(model.predict(c), name, p)
    return bound


def _resolves(b: float | None, truth: float) -> bool:
    """The bound ``b`` leaves the true ``truth`` at least two bounds from zero."""
    return b is not None and math.isfinite(b) and b < OBSERVABLE_RELATIVE * abs(truth)


def report(desc: SensorDescription, s: dict[str, Any], rate: float) -> list[str]:
    """Markdown lines of one description's :func:`score`."""
    c = s["counts"]
    ce = max(c["contact_estimates"], 1)
    out = [f"live (`{SCENE}` at {rate:g} Hz through the daemon, lossless): "
           f"{c['contact_estimates']} contact estimates, {100 * c['with_far'] / ce:.2f} % with a "
           f"value beyond {FAR_SIGMAS:g} sigma, {c['phantom']} listing more than one contact", "",
           "| value | n | 2-sigma | beyond 4 sigma | withheld | withheld where resolved "
           "| longest stale run |",
           "|---|---|---|---|---|---|---|"]
    for key in KEYS:
        n = s["n"][key]
        if not n:
            continue
        pub = n - s["withheld"][key]
        cov = f"{100 * s['covered'][key] / pub:.0f} %" if pub else "-"
        far = f"{100 * s['far'][key] / pub:.1f} %" if pub else "-"
        st = s["stale"].get(key, 0) if key != "offset" else "-"
        res = s.get("resolved", {}).get(key, 0)
        rw = (f"{100 * s['resolved_withheld'][key] / res:.0f} % ({res})" if res else "-")
        out.append(f"| {key} | {n} | {cov} | {far} | {100 * s['withheld'][key] / n:.0f} % | {rw} "
                   f"| {st} |")
    return out + [""]


def summary_row(desc: SensorDescription, s: dict[str, Any]) -> str:
    """One line of the live summary table."""
    c = s["counts"]
    ce = max(c["contact_estimates"], 1)
    pub = sum(s["n"].values()) - sum(s["withheld"].values())
    cov = sum(s["covered"].values()) / pub if pub else float("nan")
    far = sum(s["far"].values()) / pub if pub else float("nan")
    return (f"| {desc.name} | {c['contact_estimates']} | {100 * cov:.0f} % | {100 * far:.2f} % | "
            f"{100 * c['with_far'] / ce:.2f} % | {100 * sum(s['withheld'].values()) / max(sum(s['n'].values()), 1):.0f} % | "
            f"{max(s['stale'].values())} | {c['phantom']} |")


SUMMARY_HEAD = ["| description | contact estimates | 2-sigma | values beyond 4 sigma | estimates with one "
                "| withheld | longest stale run | phantom estimates |",
                "|---|---|---|---|---|---|---|---|"]

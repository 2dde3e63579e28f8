"""``tactiled bench --suite temporal``: the tracker against its bars, through the whole
daemon, the estimates taken from the daemon's stream and compared with the scene's truth.

Hold (radius error against the single-frame Cramer-Rao bound at 100 ms and 1 s), roll and
rotation (lag, rates), steps (frames until shown), and the CPU per frame with tracking on and
off; on the ideal finger (what the noise allows) and the default one (what model error leaves).
"""
# Path: simulated finger -> wire bytes -> decoder -> table -> zeroing -> tracker and real fit
# workers.
# * hold: a 10 mm cylinder at 60 deg pressed to 1.2 N and held; radius RMS error over seeds at
#   100 ms and 1 s into the hold against the bound at the truth (bars: 1/3 and 1/10), and
#   2-sigma coverage of every value through the hold;
# * roll at 1, 3, 10 mm/s and rotation at 10, 45, 90 deg/s: the median signed error of x (of the
#   angle) in single-frame sigmas (the lag; bar 0.2) and the median reported rate against the
#   truth (bar 10 %);
# * steps: the temporal scene's 20 % force step and 0.5 mm jump, frames until the estimate
#   shows them;
# * cost: the daemon's CPU per frame on the moving scene in real time, tracking on against off.
# The ideal finger has no drift and no hysteresis; the default simulated finger has both.
# Scenes are played lossless (each frame waits for any fit it needs: deterministic), except the
# cost run, in real time.

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from tactiled_bench.lossless import play_lossless
from tactiled.sensors.model import NoiseModel, SensorModel
from tactiled.physics.contact import Contact
from tactiled.sim import SCENES, Pose, SceneBuilder, named_scene

RATE = 1000.0
IDEAL = "&drift=0&hysteresis=0"
HOLD_START = 0.8  # s: the press ends here


def _hold_scene(g):
    xc, yc = g.span_x / 2.0, g.span_y / 2.0
    return (SceneBuilder(Pose(r1=10.0, psi_deg=60.0, x0=xc, y0=yc))
            .idle(0.5).press(0.3, force=1.2).hold(1.5).release(0.3).idle(0.2).build("t-hold"))


def _roll_scene(v: float):
    def build(g):
        xc, yc = g.span_x / 2.0, g.span_y / 2.0
        return (SceneBuilder(Pose(r1=10.0, psi_deg=60.0, x0=xc - 0.4 * v, y0=yc))
                .idle(0.5).press(0.3, force=1.2).hold(0.2).roll(0.8, x0=xc + 0.4 * v)
                .hold(0.1).release(0.3).idle(0.2).build(f"t-roll-{v:g}"))
    return build


def _turn_scene(w: float):
    def build(g):
        xc, yc = g.span_x / 2.0, g.span_y / 2.0
        return (SceneBuilder(Pose(r1=10.0, psi_deg=90.0 - 0.4 * w, x0=xc, y0=yc))
                .idle(0.5).press(0.3, force=1.2).hold(0.2).rotate(0.8, psi_deg=90.0 + 0.4 * w)
                .hold(0.1).release(0.3).idle(0.2).build(f"t-turn-{w:g}"))
    return build


MOTION_SEEDS = 8
ROLLS = (1.0, 3.0, 10.0)  # mm/s
TURNS = (10.0, 45.0, 90.0)  # deg/s


def _register() -> None:
    SCENES.setdefault("t-hold", _hold_scene)
    for v in ROLLS:
        SCENES.setdefault(f"t-roll-{v:g}", _roll_scene(v))
    for w in TURNS:
        SCENES.setdefault(f"t-turn-{w:g}", _turn_scene(w))


def _play(scene: str, seed: int, extra: str = "") -> list[tuple[float, dict]]:
    """The daemon on one simulated finger playing ``scene`` once, lossless: its estimates,
    ``(device time s, fit dict)``."""
    url = f"sim://?scene={scene}&seed={seed}&rate={RATE:g}&speed=0&loop=0{extra}"
    overrides = {"sensor[0].url": url, "sensor[0].model": "cylinder", "fit.workers": 2}
    return [(it.device_time_us * 1e-6, it.fit) for it in play_lossless(overrides)]


def _crb(c: Contact) -> dict:
    from tactiled.fit.fitter import FitOptions, Fitter
    from tactiled.physics.strain import StrainModel

    sensor = SensorModel(noise=NoiseModel(sigma=0.0005))
    fitter = Fitter(sensor, FitOptions())
    s = StrainModel(sensor).predict(c)
    return fitter.cramer_rao(s, "cylinder", np.array(fitter.fit(s, "cylinder").params))


def _err(key: str, fit: dict, c: Contact) -> float | None:
    v = fit.get(key)
    if v is None:
        return None
    truth = {"r1_mm": c.r1, "x_mm": c.x0, "y_mm": c.y0, "force_n": c.force,
             "angle_deg": c.psi_deg}[key]
    d = v - truth
    if key == "angle_deg":
        d = (d + 90.0) % 180.0 - 90.0
    return d


def _covered(rows: list[tuple[float, dict, Contact]], key: str) -> tuple[float, int]:
    hits = n = 0
    for _, f, c in rows:
        d, sd = _err(key, f, c), (f.get("std") or {}).get(key)
        if d is None or sd is None:
            continue
        n += 1
        hits += abs(d) <= 2.0 * sd
    return (100.0 * hits / n if n else math.nan), n


def hold(quick: bool, progress, plot: str | None = None) -> str:
    _register()
    g = SensorModel().geometry
    scene = named_scene("t-hold", g)
    seeds = range(1, 4 if quick else 11)
    c = scene.contact_at(1.0)
    bound = _crb(c)["r1_mm"]
    lines = ["| finger | radius RMS err / CRB at 100 ms | at 1 s | reported sigma / CRB at 1 s "
             "| frames used at 1 s | inside 2 sigma (r1 / x / force / angle) over the hold |",
             "|---|---|---|---|---|---|"]
    curves = {}
    for finger, extra in (("ideal", IDEAL), ("default (drift, hysteresis)", "")):
        at = {0.1: [], 1.0: []}
        sd1, used1, rows = [], [], []
        times = np.arange(0.002, 1.5, 0.002)
        track_err = np.zeros((len(seeds), times.size))
        for i, seed in enumerate(seeds):
            if progress:
                progress(f"hold {finger} seed {seed}")
            out = _play("t-hold", seed, extra)
            by_t = {round(t, 3): f for t, f in out}
            for t_in in at:
                f = by_t[round(HOLD_START + t_in, 3)]
                at[t_in].append(f["r1_mm"] - c.r1 if f.get("r1_mm") is not None else math.nan)
                if t_in == 1.0:
                    sd1.append(f["std"]["r1_mm"] or math.nan)
                    used1.append(f["frames_used"])
            for j, t_in in enumerate(times):
                f = by_t.get(round(HOLD_START + t_in, 3))
                track_err[i, j] = (f["r1_mm"] - c.r1) if f and f.get("r1_mm") else math.nan
            rows += [(t, f, scene.contact_at(t)) for t, f in out
                     if HOLD_START <= t < HOLD_START + 1.5 and f.get("contact")]
        rms = {k: math.sqrt(np.nanmean(np.square(v))) / bound for k, v in at.items()}
        cover = " / ".join(f"{_covered(rows, k)[0]:.1f} %" for k in
                           ("r1_mm", "x_mm", "force_n", "angle_deg"))
        lines.append(f"| {finger} | {rms[0.1]:.3f} | {rms[1.0]:.3f} | "
                     f"{np.nanmedian(sd1) / bound:.3f} | {int(np.median(used1))} | {cover} |")
        curves[finger] = (times, np.sqrt(np.nanmean(track_err ** 2, axis=0)) / bound)
    lines += ["", f"{len(seeds)} seeds per finger; single-frame Cramer-Rao bound of the radius at "
              f"the truth {bound:.3f} mm (1.2 N, noise 0.0005).  Bars (issue 17, ideal finger): "
              "1/3 at 100 ms (0.333), 1/10 at 1 s (0.100)."]
    if plot:
        _plot(curves, plot)
        lines += ["", f"![radius error against time in the hold]({Path(plot).name})"]
    return "\n".join(lines)


def _plot(curves: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.6), dpi=100)
    for name, (t, y) in curves.items():
        ax.loglog(t * 1e3, y, label=f"{name} finger")
    t = curves[next(iter(curves))][0]
    ax.loglog(t * 1e3, 1.0 / np.sqrt(t * RATE), "k:", label="1/sqrt(frames held)")
    ax.axhline(1 / 3, color="grey", lw=0.8)
    ax.axhline(1 / 10, color="grey", lw=0.8)
    ax.set_xlabel("time in the hold, ms")
    ax.set_ylabel("radius RMS error / single-frame CRB")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def motion(quick: bool, progress) -> str:
    _register()
    g = SensorModel().geometry
    lines = ["| motion | median signed error (lag) / single-frame sigma | median reported rate "
             "| truth | rate error | inside 2 sigma (value / rate) |", "|---|---|---|---|---|---|"]
    seeds = range(1, 2 if quick else 1 + MOTION_SEEDS)
    for kind, speeds, key, rate_key, attr in (
            ("roll", ROLLS, "x_mm", "vx_mm_s", "x0"), ("turn", TURNS, "angle_deg",
                                                       "angle_rate_deg_s", "psi_deg")):
        for v in speeds:
            name = f"t-{kind}-{v:g}"
            scene = named_scene(name, g)
            bound = _crb(scene.contact_at(1.4))[key]
            lags, rates, rows, rate_hits, rate_n = [], [], [], 0, 0
            for seed in seeds:
                if progress:
                    progress(f"{name} seed {seed}")
                out = _play(name, seed, IDEAL)
                for t, f in out:
                    if 1.1 <= t < 1.8 and f.get("contact") and f.get(key) is not None:
                        c = scene.contact_at(t)
                        lags.append(_err(key, f, c))
                        rows.append((t, f, c))
                        if f.get(rate_key) is not None:
                            rates.append(f[rate_key])
                            rate_n += 1
                            rate_hits += abs(f[rate_key] - v) <= 2 * f["std"][rate_key]
            med_rate = float(np.median(rates))
            unit = "mm/s" if kind == "roll" else "deg/s"
            lines.append(f"| {kind} {v:g} {unit} | {np.median(lags) / bound:+.3f} | "
                         f"{med_rate:.3f} | {v:g} | {100 * (med_rate - v) / v:+.1f} % | "
                         f"{_covered(rows, key)[0]:.1f} % / {100 * rate_hits / max(rate_n, 1):.1f} % |")
    lines += ["", f"Ideal finger, {len(seeds)} seed(s) per motion, the middle 0.7 s of each "
              "constant-speed segment.  Bars (issue 17): lag within 0.2 single-frame sigmas, "
              "rates within 10 % at the median."]
    return "\n".join(lines)


def steps(quick: bool, progress) -> str:
    lines = ["| change | frames until the estimate shows 90 % of it | frames_used right after |",
             "|---|---|---|"]
    out = _play("temporal", 5, IDEAL)
    by_t = {round(t, 3): f for t, f in out}
    for name, t0, key, size in (("force step 1.2 -> 1.44 N", 7.0, "force_n", 0.24),
                                ("jump 0.5 mm along y", 7.501, "y_mm", 0.5)):
        before = by_t[round(t0 - 0.002, 3)][key]
        k, shown = 0, None
        while k < 50:
            f = by_t.get(round(t0 + k / RATE, 3))
            if f is not None and f.get(key) is not None and abs(f[key] - before) >= 0.9 * size:
                shown = k + 1
                break
            k += 1
        used = by_t[round(t0 + (shown or 1) / RATE - 1 / RATE, 3)]["frames_used"]
        lines.append(f"| {name} | {shown if shown else 'not within 50'} | {used} |")
    lines += ["", "The ``temporal`` scene (ideal finger); each step happens within one frame at "
              "1 kHz.  Bar (issue 17): visible within 2 frames."]
    return "\n".join(lines)


def cost(quick: bool, progress) -> str:
    from tactiled_bench import acquisition

    seconds = 6.0 if quick else 20.0
    lines = ["| tracking | frames | daemon CPU per frame, us | workers' CPU per frame, us "
             "| total, us | ratio to off (total) | fits/s | contact frames answered "
             "| superseded | latency p50 / p99 ms (contact) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    res: dict[bool, dict[str, float]] = {}
    lat: dict[bool, list[float]] = {False: [], True: []}
    for track in (False, True, False, True):  # twice each, alternating: the machine drifts
        if progress:
            progress(f"cost track={track}")
        r = acquisition.measure(seconds, 5.0, RATE, "moving", 2, track=track)
        acc = res.setdefault(track, dict.fromkeys(
            ("frames", "daemon", "workers", "fits", "superseded", "answered", "elapsed"), 0.0))
        for s in r.after["sensors"]:
            a, b = r.after["sensors"][s], r.before["sensors"][s]
            acc["frames"] += a["frames"] - b["frames"]
            acc["fits"] += a["fitted"] - b["fitted"]
            acc["superseded"] += a["superseded"] - b["superseded"]
        contact = [x for x in r.seen if x.fit.get("contact")]
        acc["answered"] += len(contact)
        lat[track] += [x.latency_ms for x in contact]
        acc["daemon"] += r.cpu_s["daemon"] or 0.0
        acc["workers"] += r.cpu_s["workers"] or 0.0
        acc["elapsed"] += r.elapsed
    per = {t: (1e6 * v["daemon"] / max(v["frames"], 1), 1e6 * v["workers"] / max(v["frames"], 1))
           for t, v in res.items()}
    base = sum(per[False])
    for track in (False, True):
        v, (d, w) = res[track], per[track]
        shown = v["answered"] / max(v["answered"] + v["superseded"], 1)
        p50, p99 = (np.percentile(lat[track], q) for q in (50, 99)) if lat[track] else (math.nan,) * 2
        lines.append(f"| {'on' if track else 'off'} | {int(v['frames'])} | {d:.0f} | {w:.0f} | "
                     f"{d + w:.0f} | {(d + w) / base:.2f} | {v['fits'] / v['elapsed']:.0f} | "
                     f"{100 * shown:.1f} % | {int(v['superseded'])} | {p50:.2f} / {p99:.2f} |")
    lines += ["", f"The ``moving`` scene: three simulated fingers at 1 kHz over real ptys (the "
              f"acquisition bench's set-up), 2 fit workers, {seconds:g} s measured twice per "
              "setting, alternating.  The daemon's CPU counts its loop and serial read thread, not "
              "the simulators.  'contact frames answered': estimates in contact over those plus "
              "the frames superseded (given up unanswered).  Bar (issue 17): no more than 1.5x "
              "the untracked daemon's CPU per frame."]
    return "\n".join(lines)


def run(quick: bool, progress, plot: str | None = None) -> str:
    return "\n".join([
        "### hold: a held contact sharpens", "", hold(quick, progress, plot), "",
        "### roll and rotation: tracked without lag", "", motion(quick, progress), "",
        "### steps", "", steps(quick, progress), "",
        "### cost", "", cost(quick, progress)])

"""What skipping buys and costs: the daemon's per-frame decisions, each measured.

No contact, unchanged frame, persisting contact (warm against cold), too light for curvature,
and a scripted 1 kHz scene with all skipping on and off.  The daemon's per-frame work is done
in-line (detector, gate, fitter, no worker process or sockets), so the numbers are the
algorithm's and not the transport's.
"""
# - no contact: false contacts on noise-only frames, missed contacts at 0.05 N, cost of an empty
#   frame;
# - unchanged frame: share of a static hold reused, and the error of what is reused;
# - persisting contact: warm against cold fits;
# - too light for curvature: where the radius is withheld, by force;
# - the scripted scene (approach, press, roll, rotate, hold, release): frames per second and
#   errors.

from __future__ import annotations

import math
import time

import numpy as np

from tactiled_bench.runner import Progress
from tactiled_bench.suite import issue_cylinder
from tactiled.calibration.detection import ContactDetector
from tactiled.sensors.model import NoiseModel, SensorModel
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
from tactiled.pipeline.gate import Gate
from tactiled.sim import FingerSimulator, Pose, Scene, SceneBuilder

#: docs/concepts/model.md's sensor noise (the paper's +/-0.05 % quantisation bound as a sigma).
NOISE = NoiseModel(sigma=0.0005)
DAEMON_AVERAGE = 2  # frames the daemon's contact detector averages (1 ms at 1 kHz)


def _contacts_005(rng: np.random.Generator, n: int, sensor: SensorModel, near_axis: bool) -> list[Contact]:
    """0.05 N cylinders, R 1-50 mm, centred anywhere on the array; psi 30-150 deg, or (the
    paper's line-contact failure case) within 30 deg of the finger axis (but not so close that
    the contact is too long to model at all: those are redrawn)."""
    g = sensor.geometry
    model = StrainModel(sensor)
    out: list[Contact] = []
    while len(out) < n:
        psi = float(rng.uniform(30, 150)) if not near_axis else float(rng.uniform(-29.5, 29.5)) % 180.0
        c = Contact(float(math.exp(rng.uniform(0, math.log(50)))), math.inf, psi or 1.0,
                    0.05, float(rng.uniform(0, g.span_x)), float(rng.uniform(0, g.span_y)))
        try:
            model.predict(c, [c.x0], [c.y0])
        except ValueError:
            continue
        out.append(c)
    return out


def no_contact(quick: bool, progress: bool | None) -> str:
    sensor = SensorModel(noise=NOISE)
    rng = np.random.default_rng(31)
    n_noise = 200_000 if quick else 2_000_000
    single = ContactDetector(sensor=sensor, exit_fraction=1.0)  # single frames, no hysteresis
    bar = Progress(3, "no-contact decision", progress)
    # false contacts, one frame at a time (the statistic of each frame against its threshold)
    false_single = 0
    for start in range(0, n_noise, 50_000):
        z = rng.normal(0.0, NOISE.sigma, (min(50_000, n_noise - start), 8, 8))
        false_single += int(np.sum(single.statistic_batch(z) > single.enter_threshold))
    # the daemon's detector: mean of 2 frames, with hysteresis, on a noise stream
    n_stream = 100_000 if quick else 400_000
    daemon = ContactDetector(sensor=sensor, average=DAEMON_AVERAGE)
    noise = rng.normal(0.0, NOISE.sigma, (n_stream, 8, 8))
    false_daemon = sum(daemon.update(f) for f in noise)
    bar.step()
    # missed contacts at 0.05 N, per frame: single frames judged alone, and the daemon's
    # detector on a 20-frame stream of the held contact (after its 2-frame window has filled)
    model = StrainModel(sensor)
    frames_per = 20
    missed = {}
    for near_axis in (False, True):
        ms = md = ts = td = 0
        for c in _contacts_005(rng, 200 if quick else 1000, sensor, near_axis):
            z = model.predict(c) + rng.normal(0.0, NOISE.sigma, (frames_per, 8, 8))
            ms += int(np.sum(single.statistic_batch(z) <= single.enter_threshold))
            ts += frames_per
            det = ContactDetector(sensor=sensor, average=DAEMON_AVERAGE)
            decisions = [det.update(f) for f in z]
            md += sum(not d for d in decisions[DAEMON_AVERAGE:])
            td += frames_per - DAEMON_AVERAGE
        missed[near_axis] = (100 * ms / ts, 100 * md / td)
    bar.step()
    # cost of an empty frame: the contact decision plus the gate, per frame
    det = ContactDetector(sensor=sensor, average=DAEMON_AVERAGE)
    gate = Gate(NOISE.sigma)
    empties = rng.normal(0.0, NOISE.sigma, (5000, 8, 8))
    t = []
    for f in empties:
        t0 = time.perf_counter()
        gate.decide(f, det.update(f))
        t.append((time.perf_counter() - t0) * 1e6)
    bar.step()
    lines = [
        f"Noise sigma {NOISE.sigma} (docs/concepts/model.md), matched-filter statistic, threshold for 1e-4 false contacts per frame:", "",
        "| measure | single frame | daemon (mean of 2 frames, hysteresis) | bar |", "|---|---|---|---|",
        f"| false contacts per noise-only frame | {false_single / n_noise:.2e} ({false_single} in {n_noise}) | "
        f"{false_daemon / n_stream:.2e} ({false_daemon} in {n_stream}) | <= 1e-4 |",
        f"| missed contacts at 0.05 N per frame (cylinders R 1-50 mm, psi 30-150, anywhere on the array) | "
        f"{missed[False][0]:.2f} % | {missed[False][1]:.3f} % | <= 1 % |",
        f"| ... the same within 30 deg of the finger axis (line contacts: the force spreads along the finger) | "
        f"{missed[True][0]:.2f} % | {missed[True][1]:.3f} % | (known limit) |",
        f"| cost of an empty frame (decision + gate), median / p99 us | | "
        f"{np.median(t):.1f} / {np.percentile(t, 99):.1f} | <= 20 us |",
    ]
    return "\n".join(lines)


def unchanged(quick: bool, progress: bool | None) -> str:
    sensor = SensorModel(noise=NOISE)
    fitter = Fitter(sensor)
    model = StrainModel(sensor)
    rng = np.random.default_rng(41)
    n = 500 if quick else 3000
    out = ["| motion | frames | reused | fits | radius err % (med) reused / fitted | x err um (med) reused / fitted |",
           "|---|---|---|---|---|---|"]
    bar = Progress(3, "unchanged-frame reuse", progress)
    for label, dx_per_frame in (("static hold", 0.0), ("rolling 5 mm/s", 0.005), ("rolling 50 mm/s", 0.05)):
        gate = Gate(NOISE.sigma)
        last = None
        err_reused, err_fit, ex_reused, ex_fit = [], [], [], []
        reused = fits = 0
        for i in range(n):
            c = Contact(10.0, math.inf, 80.0, 1.0, 8.0 + i * dx_per_frame % 8.0, 13.0)
            z = model.predict(c) + rng.normal(0.0, NOISE.sigma, (8, 8))
            d = gate.decide(z, True)
            if d.action == "unchanged" and last is not None:
                reused += 1
                res, errs, exs = last, err_reused, ex_reused
            else:
                res = fitter.fit(z, "cylinder", start=np.array(last.params) if last and last.params else None)
                gate.fitted(z)
                last = res
                fits += 1
                errs, exs = err_fit, ex_fit
            if res.values["r1_mm"] is not None:
                errs.append(abs(res.values["r1_mm"] / c.r1 - 1) * 100)
            exs.append(abs(res.values["x_mm"] - c.x0) * 1000)

        def med(v):
            return f"{np.median(v):.2f}" if v else "-"

        out.append(f"| {label} | {n} | {100 * reused / n:.1f} % | {fits} | {med(err_reused)} / {med(err_fit)} | "
                   f"{med(ex_reused)} / {med(ex_fit)} |")
        bar.step()
    return "\n".join(out)


def too_light(quick: bool, progress: bool | None) -> str:
    sensor = SensorModel(noise=NOISE)
    fitter = Fitter(sensor, FitOptions(withhold_relative_sigma=0.5))
    model = StrainModel(sensor)
    rng = np.random.default_rng(51)
    n = 40 if quick else 200
    out = ["| force N | radius withheld | radius err % (median, reported) | force err % (median) |", "|---|---|---|---|"]
    forces = (0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)
    bar = Progress(len(forces), "too light for curvature", progress)
    for f in forces:
        withheld = 0
        er, ef = [], []
        for _ in range(n):
            c = issue_cylinder(rng, force=f)
            res = fitter.fit(model.predict(c) + rng.normal(0, NOISE.sigma, (8, 8)), "cylinder")
            if res.values["r1_mm"] is None:
                withheld += 1
            else:
                er.append(abs(res.values["r1_mm"] / c.r1 - 1) * 100)
            if res.values["force_n"] is not None:
                ef.append(abs(res.values["force_n"] / f - 1) * 100)
        out.append(f"| {f:g} | {100 * withheld / n:.0f} % | {np.median(er) if er else float('nan'):.1f} | "
                   f"{np.median(ef) if ef else float('nan'):.1f} |")
        bar.step()
    return "\n".join(out)


def scripted_scene(geometry_sensor: SensorModel | None = None) -> Scene:
    """A few seconds of approach, press, roll, rotate, hold and release."""
    g = (geometry_sensor or SensorModel()).geometry
    yc = g.span_y / 2
    return (SceneBuilder(Pose(r1=10.0, psi_deg=90.0, x0=0.3 * g.span_x, y0=yc))
            .idle(0.3).approach(0.2).press(0.4, force=1.0)
            .roll(1.0, x0=0.7 * g.span_x).rotate(1.0, psi_deg=40.0)
            .hold(1.5).release(0.3).idle(0.3).build("bench"))


def scene_throughput(quick: bool, progress: bool | None) -> str:
    """The scripted scene at 1 kHz processed with every skip on, and with all of them off."""
    sensor = SensorModel(noise=NOISE)
    sim = FingerSimulator(sensor, scripted_scene(sensor), seed=3, rate_hz=1000.0, noise=NOISE.sigma,
                          drift=None, hysteresis=None, loop=False)
    n = int(sim.scene.duration * 1000)
    if quick:
        n = min(n, 2500)
    ticks = [sim.step() for _ in range(n)]
    rows = []
    bar = Progress(2, "scripted scene at 1 kHz", progress)
    for label, skipping in (("all skipping on", True), ("all skipping off", False)):
        fitter = Fitter(sensor, FitOptions(withhold_relative_sigma=0.5 if skipping else None))
        det = ContactDetector(sensor=sensor, average=DAEMON_AVERAGE)
        gate = Gate(NOISE.sigma, reuse_unchanged=skipping)
        last = None
        counts = {"fit": 0, "unchanged": 0, "no_contact": 0}
        errs = {"r1": [], "angle": [], "force": [], "x": []}
        missed = false = 0
        t0 = time.perf_counter()
        for tk in ticks:
            z = tk.strain
            if skipping:
                in_contact = det.update(z)
                d = gate.decide(z, in_contact)
                action = d.action
            else:
                action = "fit"
            if action == "no_contact":
                res = None
                last = None
                gate.reset()
            elif action == "unchanged" and last is not None:
                res = last
            else:
                action = "fit"
                start = np.array(last.params) if (skipping and last is not None and last.params) else None
                res = fitter.fit(z, "cylinder", start=start)
                gate.fitted(z)
                last = res
            counts[action] += 1
            c = tk.contact
            if c is None:
                false += res is not None and skipping
                continue
            if res is None:
                missed += 1
                continue
            v = res.values
            if v["r1_mm"] is not None:
                errs["r1"].append(abs(v["r1_mm"] / c.r1 - 1) * 100)
            if v["angle_deg"] is not None:
                errs["angle"].append(abs((v["angle_deg"] - c.psi_deg + 90) % 180 - 90))
            if v["force_n"] is not None:
                errs["force"].append(abs(v["force_n"] / c.force - 1) * 100)
            if v["x_mm"] is not None:
                errs["x"].append(abs(v["x_mm"] - c.x0) * 1000)
        dt = time.perf_counter() - t0
        rows.append((label, n / dt, counts, errs, missed, false))
        bar.step()
    out = [f"Scene of {sim.scene.duration:.1f} s at 1 kHz ({n} frames: idle, approach, press, roll, rotate, hold, "
           "release, idle), noise sigma 0.0005, processed in-line:", "",
           "| processing | frames/s | fits | reused | no contact | missed contact frames | radius err % med | "
           "angle err deg med | force err % med | x err um med |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for label, fps, counts, errs, missed, false in rows:
        def med(v):
            return f"{np.median(v):.2f}" if v else "-"
        out.append(f"| {label} | {fps:,.0f} | {counts['fit']} | {counts['unchanged']} | {counts['no_contact']} | "
                   f"{missed} | {med(errs['r1'])} | {med(errs['angle'])} | {med(errs['force'])} | {med(errs['x'])} |")
    out.append("")
    out.append("'Missed contact frames' are frames with a true contact but no estimate (the lightest moments of "
               "approach and release, below the detection threshold); with skipping off every frame is fitted, "
               "including those.  Radius errors are over frames where one is reported: with skipping on, a radius "
               "whose Cramer-Rao bound exceeds 50 % is withheld (too light for curvature).")
    return "\n".join(out)

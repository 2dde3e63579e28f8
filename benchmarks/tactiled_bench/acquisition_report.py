"""The acquisition bench's figures and report: frame integrity, answers, CPU per frame, the
collector's pauses, accuracy against the scene's truth, and the Markdown tables
``tactiled bench --suite acquisition`` prints.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from tactiled_bench.acquisition_runs import (HAND, INDENTORS, LATE_RELEASE_S, PARAMS, Answers,
                                             RunResult, counter_delta, devices, scene_detectable,
                                             scene_truth, summarise, timeline)


#: A finger counts as locked in contact when it published fewer "no contact" estimates than
#: this share of the frames its scene leaves untouched (the release residual or drift held
#: the detector on: docs/concepts/calibration.md, "The rubber's hysteresis is learnt and taken out"
#: and "Drift during a hold"): its run says little of fitting, and is marked so.
LOCKED_SHARE = 0.1


def untouched_share(scene: str, rate: float) -> float:
    """The share of a pass of ``scene`` at ``rate`` Hz in which nothing touches the finger."""
    truth = scene_truth(scene, rate)
    per_pass = max(1, round(timeline(scene).duration * rate))
    return sum(truth(k) is None for k in range(per_pass)) / per_pass


def locked_fingers(result: RunResult, untouched: float) -> list[str]:
    """The fingers of ``result`` locked in contact over the measured window: they published
    "no contact" for under ``LOCKED_SHARE`` of the frames their scene leaves untouched
    (``untouched``: :func:`untouched_share`)."""
    locked = []
    for name in result.parts:
        a, b = result.after["sensors"][name], result.before["sensors"][name]
        frames = counter_delta(a, b, "frames")
        free = counter_delta(a, b, "skipped", "no_contact")
        if frames and free < LOCKED_SHARE * untouched * frames:
            locked.append(name)
    return locked


def _pct(values: Sequence[float], q: float, digits: int = 2) -> str:
    return f"{np.percentile(values, q):.{digits}f}" if len(values) else "-"


def _q(values: Sequence[float], q: float) -> float | None:
    """The ``q``-th percentile of ``values`` (None for none), as JSON carries it."""
    return float(np.percentile(values, q)) if len(values) else None


def integrity(result: RunResult) -> dict[str, dict[str, Any]]:
    """Per sensor of one run: frames the device sent and the daemon received, lost, rejected
    and what became of every frame (counts over the measured window, rates per second; gaps
    and the device's own counts over the whole run)."""
    before, after, elapsed = result.before["sensors"], result.after["sensors"], result.elapsed
    out = {}
    for i, name in enumerate(result.parts):
        a, b = after[name], before[name]

        def delta(key: str, sub: str | None = None) -> int:
            return counter_delta(a, b, key, sub)

        frames = delta("frames")
        # whole-run totals: the device's own count of frames it never sent against the gaps
        # the decoder saw over the daemon's whole life
        gaps_total = int(a["decoder"]["lost"])
        dev = result.device[i] if i < len(result.device) else None
        unsent = (dev[1] + dev[2]) if dev else None
        accounted = (delta("published") + delta("superseded") + delta("stale_dropped") + delta("fit_failed")
                     + delta("fit_errors") + delta("wrong_sensor") + delta("bad_shape") + delta("errors"))
        in_hand = int(a["in_hand"]) - int(b["in_hand"])
        out[name] = {
            "frames": frames, "frames_per_s": frames / elapsed,
            "device_sent": dev[0] if dev else None,  # whole run
            "device_not_sent": unsent,  # whole run: pty full or behind schedule
            "gaps_seen": gaps_total,  # whole run
            "lost_in_acquisition": None if unsent is None else max(gaps_total - unsent, 0),
            "rejected": delta("decoder", "crc_errors") + delta("decoder", "cobs_errors") + delta("decoder", "truncated"),
            "duplicated": delta("decoder", "duplicated"),
            "fits_per_s": delta("fitted") / elapsed,
            "superseded_per_s": delta("superseded") / elapsed,
            "reused_per_s": delta("skipped", "unchanged") / elapsed,
            "no_contact_per_s": delta("skipped", "no_contact") / elapsed,
            "stale": delta("stale_dropped"),
            "unaccounted": frames - accounted - in_hand,
        }
    return out


def _answers_figures(a: Answers, elapsed: float, sensors: int) -> dict[str, Any]:
    """The answers of a run (or of one sensor of it) as plain figures (shares in %)."""
    def share(n: int) -> float | None:
        return 100.0 * n / a.contact if a.contact else None

    answered = a.own_fit + a.reused - a.predicted
    return {
        "frames": a.frames, "contact_frames": a.contact,
        "own_fit": a.own_fit, "reused": a.reused, "predicted": a.predicted,
        "superseded": a.superseded, "unanswered": a.unanswered, "answered": answered,
        "own_fit_pct": share(a.own_fit), "reused_pct": share(a.reused),
        "predicted_pct": share(a.predicted), "superseded_pct": share(a.superseded),
        "unanswered_pct": share(a.unanswered), "answered_pct": share(answered),
        "latency_ms": {"p50": _q(a.latency_contact, 50), "p99": _q(a.latency_contact, 99),
                       "max": max(a.latency_contact) if a.latency_contact else None},
        "own_fit_latency_ms": {"p50": _q(a.latency_fit, 50), "p99": _q(a.latency_fit, 99)},
        "fits_per_s_per_sensor": a.own_fit / elapsed / sensors,
        "fit_ms": {"p50": _q(a.fit_ms, 50), "p99": _q(a.fit_ms, 99)},
        "auto_kept_pct": 100.0 * a.kept / a.own_fit if a.own_fit else 0.0,
        "contacts_reported": a.contacts_reported, "estimates_with_several_contacts": a.several,
        "truth_touching": a.touching, "missed": a.missed, "phantom": a.phantom,
        "phantom_after_release": a.phantom_after_release,
        "touching_detectable": a.touching_detectable, "missed_detectable": a.missed_detectable,
    }


def cpu_per_frame(result: RunResult) -> dict[str, float | None]:
    """The daemon's main process's CPU per frame handled (us), over the run's windows of
    about a second: median, p99 and max of the windows, and over the whole window."""
    windows = getattr(result, "windows", [])  # (a baseline's result may not have them)
    per = [1e6 * cpu / frames for _, cpu, frames in windows if frames > 0]
    cpu = result.cpu_s.get("daemon")
    frames = sum(counter_delta(result.after["sensors"][n], result.before["sensors"][n], "frames")
                 for n in result.parts)
    return {"median_us": _q(per, 50), "p99_us": _q(per, 99), "max_us": max(per) if per else None,
            "windows": len(per),
            "whole_us": None if cpu is None or not frames else 1e6 * cpu / frames}


def garbage_collection(result: RunResult) -> dict[str, float | int | None]:
    """The daemon's process's garbage collections in the measured window: how many, their
    total and their longest (ms); None where the run did not record them (a baseline's)."""
    times = getattr(result, "gc_s", None)
    if times is None:
        return {"collections": None, "total_ms": None, "max_ms": None}
    return {"collections": len(times), "total_ms": 1e3 * sum(times),
            "max_ms": 1e3 * max(times) if times else 0.0}


def figures(result: RunResult, scene: str, rate: float) -> dict[str, Any]:
    """Every figure of one run's tables, machine-readable: totals, and per sensor."""
    truth = scene_truth(scene, rate)
    detectable = scene_detectable(scene, rate)
    accuracy = scene != HAND
    late = round(LATE_RELEASE_S * rate)
    a = summarise(result, truth, accuracy=accuracy, late_ticks=late, detectable=detectable)
    sensors = integrity(result)
    n = len(result.parts)
    for name in result.parts:
        sensors[name].update(_answers_figures(summarise(result, truth, name, accuracy, late,
                                                        detectable), result.elapsed, 1))
    total_keys = ("frames", "device_sent", "device_not_sent", "gaps_seen", "lost_in_acquisition",
                  "rejected", "duplicated", "stale", "unaccounted")
    total: dict[str, Any] = {
        k: (None if any(s[k] is None for s in sensors.values()) else sum(s[k] for s in sensors.values()))
        for k in total_keys}
    total["frames_per_s"] = total["frames"] / result.elapsed
    total.update(_answers_figures(a, result.elapsed, n))
    untouched = untouched_share(scene, rate)
    out: dict[str, Any] = {
        "run": result.who, "workers": result.workers, "elapsed_s": result.elapsed,
        "tares": result.tares,
        "cpu_pct_of_a_core": {k: None if v is None else 100.0 * v / result.elapsed
                              for k, v in result.cpu_s.items()},
        "main_process_cpu_per_frame": cpu_per_frame(result),
        "garbage_collection": garbage_collection(result),
        "locked_in_contact": locked_fingers(result, untouched),
        "total": total, "sensors": sensors,
    }
    if accuracy:
        out["accuracy"] = {k: {"estimates": acc.estimates,
                               "median_abs_error": {p: _q(acc.errors[p], 50) for p in PARAMS},
                               "withheld": dict(acc.withheld)}
                           for k, acc in a.accuracy.items() if acc.estimates}
    return out


def _cpu_cell(seconds: float | None, elapsed: float) -> str:
    return "?" if seconds is None else f"{100.0 * seconds / elapsed:.0f} %"


def _num(v: float | None, fmt: str = "{:.2f}") -> str:
    return "-" if v is None else fmt.format(v)


def _share(v: float | None) -> str:
    return "-" if v is None else f"{v:.1f} %"


def conditions(scene: str, rate: float, seconds: float, warmup: float, results: Sequence[RunResult],
               sim_nice: int) -> str:
    """The sentence that says how a sweep ran."""
    col = "workers" if not any(r.label for r in results) else "code, workers"
    sweep = ", ".join(dict.fromkeys(str(r.workers) for r in results))
    runs = ("one run each, everything restarted" if col == "workers" else
            "four runs each, alternating this tree and the baseline's code (this, baseline, "
            "baseline, this), everything restarted every run")
    devs = devices(scene)
    if scene == HAND:
        what = (f"{len(devs)} simulated devices, a hand (`tactiled simulate --pty --scene hand-palm --sensor "
                f"flat16` and `--scene hand-finger1` .. `hand-finger5` on the default finger, "
                f"`--rate {rate:g}`, one process each)")
    else:
        what = (f"{len(devs)} simulated fingers (`tactiled simulate --pty --scene {scene} --rate {rate:g}`, one "
                f"process each)")
    return (f"{what} read over real ptys with pyserial; {seconds:g} s measured after {warmup:g} s of "
            f"warm-up; each sensor tared early in an idle of the scene, as a hand starts with its fingers free "
            f"(the daemon opens the ports at an arbitrary moment of the scene), again at the next idle if the "
            f"baseline took in a contact frame (tares per run: {', '.join(str(r.tares) for r in results)}); fit "
            f"workers: {sweep} ({runs}); model `auto` (the daemon's default); "
            f"{os.cpu_count()} cores shared by everything"
            + (f" (the simulators at niceness {sim_nice}: a finger's device has a processor of its "
               f"own, so they take only the CPU the daemon leaves)" if sim_nice else
               " (the simulators at the daemon's own niceness, competing with it for the cores)") + ".")


def report(results: list[RunResult], scene: str, rate: float, seconds: float, warmup: float,
           sim_nice: int = 0, figs: list[dict[str, Any]] | None = None) -> str:
    """The Markdown tables of a sweep (from :func:`figures` of each run, ``figs`` if given)."""
    col = "code, workers" if any(r.label for r in results) else "workers"
    figs = figs if figs is not None else [figures(r, scene, rate) for r in results]
    lines = [conditions(scene, rate, seconds, warmup, results, sim_nice), ""]
    # -- answers and latency
    lines += ["### Every contact frame answered?", "",
              f"| {col} | contact frames | own fit | gate reuse (unchanged) | of which predicted | superseded | stale / lost | "
              "latency p50 / p99 ms (contact frames) | own fits p50 / p99 ms | fits/s per finger | "
              "fit_ms p50 / p99 | auto kept the model | CPU: daemon / workers / simulators | "
              "fingers locked in contact |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r, f in zip(results, figs):
        t = f["total"]
        lines.append(
            f"| {r.who} | {t['contact_frames']} | {_share(t['own_fit_pct'])} | {_share(t['reused_pct'])} | "
            f"{_share(t['predicted_pct'])} | {_share(t['superseded_pct'])} | {_share(t['unanswered_pct'])} | "
            f"{_num(t['latency_ms']['p50'])} / {_num(t['latency_ms']['p99'])} | "
            f"{_num(t['own_fit_latency_ms']['p50'])} / {_num(t['own_fit_latency_ms']['p99'])} | "
            f"{t['fits_per_s_per_sensor']:.0f} | {_num(t['fit_ms']['p50'], '{:.3f}')} / "
            f"{_num(t['fit_ms']['p99'], '{:.3f}')} | {t['auto_kept_pct']:.0f} % | "
            f"{_cpu_cell(r.cpu_s.get('daemon'), r.elapsed)} / {_cpu_cell(r.cpu_s.get('workers'), r.elapsed)} / "
            f"{_cpu_cell(r.cpu_s.get('simulators'), r.elapsed)} | "
            f"{', '.join(f['locked_in_contact']) or 'none'} |")
    lines += ["",
              "Shares are of the contact frames (frames the detector called contact): answered by a fit of their "
              "own, answered by the last fit because the chi-square test found them unchanged within noise (a "
              "justified reuse; with tracking, measured through the last fit's linearisation, which a test of "
              "its own admits: docs/concepts/tracking.md), of which predicted (the tracker had to publish the contact "
              "predicted to the frame's time because its fit came back late: not a justified reuse), superseded "
              "in the one-frame slot by a newer frame before a worker was free, or unanswered otherwise (a fit "
              "result dropped as stale, a fit lost).  Targets (issue 16): own fit + reuse - predicted >= 99 %, "
              "superseded <= 1 %, p99 latency <= 5 ms.  Latency: frame arrival (host receive) to "
              "published estimate.  fit_ms: the fitter's own time per fit in the worker (wall).  'auto kept the "
              "model': own fits where auto refitted only the previous frame's model, warm (one model, not three).  "
              "CPU over the measured window in % of one core: the daemon's main process (event loop and serial "
              "read thread), its fit workers, the simulators.  'Fingers locked in contact': fingers "
              f"that published 'no contact' for under {100 * LOCKED_SHARE:g} % of the frames the scene leaves "
              "untouched (a release residual or drift held the detector on, docs/concepts/calibration.md): their phantom contact frames "
              "count here, so such a run says little of the fitting."]
    # -- the main process's budget, per sensor
    lines += ["", "### The main process's CPU per frame, and each sensor's answers", "",
              f"| {col} | sensor | contact frames | answered (own fit + reuse - predicted) | contacts reported | "
              "estimates with several contacts | latency p50 / p99 / max ms |",
              "|---|---|---|---|---|---|---|"]
    for r, f in zip(results, figs):
        for name, s in [*f["sensors"].items(), ("all", f["total"])]:
            lat = s["latency_ms"]
            lines.append(f"| {r.who} | {name} | {s['contact_frames']} | {_share(s['answered_pct'])} | "
                         f"{s['contacts_reported']} | {s['estimates_with_several_contacts']} | "
                         f"{_num(lat['p50'])} / {_num(lat['p99'])} / {_num(lat['max'])} |")
    lines += ["", f"| {col} | main process CPU per frame, us: median / p99 of ~1 s windows | whole window | windows "
              "| garbage collections: count / total ms / longest ms |",
              "|---|---|---|---|---|"]
    for r, f in zip(results, figs):
        c, g = f["main_process_cpu_per_frame"], f["garbage_collection"]
        lines.append(f"| {r.who} | {_num(c['median_us'], '{:.1f}')} / {_num(c['p99_us'], '{:.1f}')} | "
                     f"{_num(c['whole_us'], '{:.1f}')} | {c['windows']} | {_num(g['collections'], '{}')} / "
                     f"{_num(g['total_ms'], '{:.1f}')} / {_num(g['max_ms'], '{:.1f}')} |")
    lines += ["",
              "Answered: the contact frames answered by their own fit or a justified reuse (the tracker's "
              "measurement included), less those only predicted; target >= 99 %.  Contacts reported: the "
              "estimates' `contacts` lists' lengths where they carry one, else their top-level contact (0 or "
              "1).  Main process CPU per frame: the CPU time of the daemon's main process (its event loop and "
              "serial read thread, not its fit workers) in each window of about a second, divided by the "
              "frames all its sensors handled in that window; target <= 40 us at the median.  Garbage "
              "collections: those the daemon's process ran in the measured window, of any generation "
              "(the start-up heap is frozen before the run: tactiled.heap)."]
    # -- accuracy
    if scene != HAND:
        lines += ["", "### Accuracy of the streamed estimates against the scene's truth", "",
                  f"| {col} | estimates of | count | radius % | angle deg | force % | x um | y um |",
                  "|---|---|---|---|---|---|---|---|"]
        truth = scene_truth(scene, rate)
        for r in results:
            a = summarise(r, truth)
            for key in ("all", "own fits", "reuses", *INDENTORS, "general"):
                acc = a.accuracy.get(key)
                if acc is None or not acc.estimates:
                    continue
                lines.append(f"| {r.who} | {key} | {acc.estimates} | {acc.cell('r1_mm')} | {acc.cell('angle_deg')} | "
                             f"{acc.cell('force_n')} | {acc.cell('x_mm')} | {acc.cell('y_mm')} |")
        lines += ["",
                  "Median absolute errors of every estimate in contact published in the window (own fits and reuses "
                  "alike) against the truth of *its own* frame (matched by seq), so a reuse that lags a moving contact "
                  "costs accuracy here (rows 'own fits' and 'reuses' split them; then by the true indentor); withheld: the estimate's value was null (e.g. radius 'force too low for "
                  "curvature'), its share of the estimates.  Angles are not compared on spheres."]
    lines += ["", f"| {col} | truth touching | missed (published as no contact) | ... above the detection limit: "
              f"touching / missed | contact published without truth | ... of which within {LATE_RELEASE_S:g} s of "
              "a lift-off |",
              "|---|---|---|---|---|---|"]
    for r, f in zip(results, figs):
        t = f["total"]
        above, missed_above = t.get("touching_detectable", 0), t.get("missed_detectable", 0)
        lines.append(f"| {r.who} | {t['truth_touching']} | {t['missed']} "
                     f"({100.0 * t['missed'] / max(t['truth_touching'], 1):.1f} %) | {above} / {missed_above} "
                     f"({100.0 * missed_above / max(above, 1):.1f} %) | {t['phantom']} "
                     f"| {t.get('phantom_after_release', '-')} |")
    lines += ["",
              "Truth touching: frames whose scene presses the finger, however lightly; above the detection limit: "
              "those whose noise-free strain reaches the detector's enter threshold (the daemon's defaults), "
              "which a press's first and a release's last few hundredths of a newton do not: "
              "docs/concepts/calibration.md, \"Contact detection\"."]
    # -- integrity
    lines += ["", "### Acquisition", "",
              f"| {col} | finger | frames/s | gaps seen | not sent by the device | lost in acquisition | "
              "CRC / COBS / truncated | duplicated | fits/s | superseded/s | reused (unchanged)/s | "
              "no contact/s | stale | unaccounted |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    total_lost = 0
    for r, f in zip(results, figs):
        for name, s in f["sensors"].items():
            lost = s["lost_in_acquisition"]
            total_lost += lost if lost is not None else s["gaps_seen"]
            lines.append(
                f"| {r.who} | {name} | {s['frames_per_s']:.0f} | {s['gaps_seen']} | "
                f"{'?' if s['device_not_sent'] is None else s['device_not_sent']} | "
                f"{'?' if lost is None else lost} | {s['rejected']} | {s['duplicated']} | "
                f"{s['fits_per_s']:.0f} | {s['superseded_per_s']:.0f} | {s['reused_per_s']:.0f} | "
                f"{s['no_contact_per_s']:.0f} | {s['stale']} | {s['unaccounted']} |")
    lines += ["",
              f"Frames lost in acquisition: {total_lost}.  'Gaps seen' are sequence gaps the decoder counted over "
              "the whole run; 'not sent by the device' is the simulators' own count of frames they generated but "
              "did not write (pty full, or behind schedule on a starved CPU); the difference is what acquisition "
              "lost.  Rates and 'unaccounted' are over the measured window: 'unaccounted' = frames - (published + "
              "superseded + stale + failed + rejected), corrected for a frame waiting or in flight at the two "
              "snapshots; 0 means every frame was either answered or counted as superseded."]
    return "\n".join(lines)

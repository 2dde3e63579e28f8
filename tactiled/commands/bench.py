"""Benchmark run time against error over a seeded suite of simulated scenes with ground truth.

Suites (default: all):
  configs     each way of estimating (window size, cold/warm start, exact vs finite-difference
              Jacobian, forward-model accuracy, the cheap estimators) on cylinders and edges:
              median/p99 time per frame, median/90th-percentile errors, RMS error over the
              Cramer-Rao bound, and whether the row is on the Pareto front
  models      model order: cylinder-only against auto on cylinders, spheres, ellipsoids, edges
  skip        the daemon's per-frame skips: no contact (false/missed rates, cost of an empty
              frame), unchanged frames, too light for curvature, and a scripted scene at 1 kHz
              with all skipping on and off (frames/s, errors)
  acquisition three simulated fingers at 1 kHz over real ptys through the whole daemon:
              frames lost, every frame accounted for, fit rate, latency p50/p99; the share of
              contact frames answered by their own fit or a justified gate reuse (not
              superseded), and the streamed estimates' accuracy against the scene's truth;
              --scene picks the scene (moving: contacts that never rest), --workers sweeps
              the fit worker count (one run each, side by side)
  foundation  the fitter against its bars: noise-free recovery from the reference integration,
              noisy efficiency (RMS/CRB, 2-sigma coverage), the paper's Table 1, speed
  sensors     accuracy on every built-in sensor description (or --sensor's): cylinders (line
              contacts on flat arrays), spheres and edges; RMS error over the Cramer-Rao
              bound, 2-sigma coverage and the share beyond 4 sigma per parameter, values
              withheld, fit time; and the daemon's own estimates of the demo scene (the
              description's simulated finger through the whole daemon) against the truth
  temporal    the tracker through the whole daemon: a held contact sharpening (radius error
              against the single-frame bound at 100 ms and 1 s, coverage; --plot draws the
              error against time), rolls and rotations (lag, rates), steps, and the CPU per
              frame with tracking on and off
  contacts    several contacts on one array (the paper's finger and a flat 16x16, or
              --sensor's): contacts found, missed and phantom; RMS error over the joint
              model's Cramer-Rao bound and 2-sigma coverage per parameter; close pairs the
              cover merges; single contacts unchanged
  unexplained the fit's cost on frames the model cannot explain (several contacts at once, a
              hand print on a 32x32 array, random and saturated patterns) and on the simulated
              contacts, with the fit budget and without: CPU ms median/p99/max, iterations,
              the share converged, stopped by the budget, withheld

Output is Markdown on stdout; progress goes to stderr.  --quick runs in about a minute.

examples:
  tactiled bench --quick
  tactiled bench --suite configs --plot pareto.png
  tactiled bench --suite acquisition --scene moving --workers 1,2,4
  tactiled bench --suite acquisition --scene moving --baseline REV   # this tree against REV
  tactiled bench --suite acquisition --scene moving --sim-nice 10   # devices off the host's CPU
  tactiled bench --suite acquisition --scene hand --json hand.json   # six devices: a hand
"""

from __future__ import annotations

import argparse
import platform
import sys
import time

SUITES = ("configs", "models", "skip", "foundation", "acquisition", "identify", "speed",
          "temporal", "sensors", "unexplained", "contacts", "shear")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--suite", choices=SUITES + ("all",), default="all", help="which benchmark (default all)")
    p.add_argument("--quick", action="store_true", help="a small suite that runs in about a minute")
    p.add_argument("--scenes", type=int, default=None, help="scenes in the configs suite (default 240, quick 40)")
    p.add_argument("--seed", type=int, default=1, help="suite seed (default 1)")
    p.add_argument("--baseline", metavar="REV", default=None,
                   help="speed suite: also time the fitter of git revision REV, interleaved "
                   "(ratios to it are the figure); acquisition suite: also run the daemon of REV, "
                   "two runs each, alternating (needs a git checkout)")
    p.add_argument("--plot", metavar="FILE.png", default=None,
                   help="write a Pareto chart of time against error (needs matplotlib: pip install 'tactiled[plot]')")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bar on stderr (default: when stderr is a terminal)")
    p.add_argument("--sensor", metavar="NAME|FILE.toml", action="append", default=None,
                   help="sensors and contacts suites: score this description (repeatable; default "
                   "every built-in for sensors, fearing1988 and flat16 for contacts)")
    acq = p.add_argument_group("acquisition suite")
    acq.add_argument("--scene", default="demo",
                     help="simulator scene the fingers play (default demo; moving: contacts that never rest; "
                          "hand: six devices, five fingertips and a 16x16 palm, grasping several contacts at once)")
    acq.add_argument("--json", metavar="FILE", default=None,
                     help="also write every figure of the tables to FILE as JSON")
    acq.add_argument("--workers", type=_worker_list, default=(2,), metavar="N[,N...]",
                     help="fit worker counts, one run each (default 2; e.g. 1,2,4)")
    acq.add_argument("--seconds", type=float, default=None, metavar="S",
                     help="measured seconds per run, after 4-5 s of warm-up (default 20, quick 6)")
    acq.add_argument("--sim-nice", type=int, default=0, metavar="N",
                     help="run the simulated fingers at this niceness (0-19; default 0): a real finger's "
                          "device has a processor of its own, so niced they take only the CPU the "
                          "daemon leaves")


def _worker_list(text: str) -> tuple[int, ...]:
    try:
        counts = tuple(int(t) for t in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected worker counts like 1,2,4, got {text!r}") from None
    if not counts or any(not 1 <= n <= 64 for n in counts):
        raise argparse.ArgumentTypeError(f"worker counts must lie in 1..64, got {text!r}")
    return counts


def _say(what: str) -> None:
    print(f"temporal: {what}", file=sys.stderr, flush=True)


def _header(args: argparse.Namespace) -> str:
    cmd = "tactiled bench " + " ".join(sys.argv[2:]) if len(sys.argv) > 2 else "tactiled bench"
    return (f"<!-- {cmd} | {time.strftime('%Y-%m-%d %H:%M')} | python {platform.python_version()} | "
            f"{platform.machine()} -->")


def run(args: argparse.Namespace) -> int:
    from tactiled_bench import foundation, runner
    from tactiled_bench.estimators import default_configurations
    from tactiled_bench.suite import BENCH_NOISE, build_suite
    from tactiled.sensors.model import SensorModel
    from tactiled.fit.fitter import FitOptions, Fitter

    if args.plot:
        try:
            import matplotlib  # noqa: F401  (only to fail early and clearly)
        except ImportError:
            print("tactiled bench: error: --plot needs matplotlib: pip install 'tactiled[plot]'", file=sys.stderr)
            return 2
        from tactiled.io.files import check_output

        check_output(args.plot)  # before the run, not after it
    suites = SUITES if args.suite == "all" else (args.suite,)
    if "acquisition" in suites:
        from tactiled_bench.acquisition_runs import HAND, known_scene
        from tactiled.sim import SCENES

        if not known_scene(args.scene.strip().lower()):
            print(f"tactiled bench: error: unknown scene {args.scene!r}; known scenes: {', '.join(SCENES)}, {HAND}",
                  file=sys.stderr)
            return 2
        if args.json:
            from tactiled.io.files import check_output

            check_output(args.json)  # before the run, not after it
        if args.seconds is not None and not args.seconds > 0:
            print("tactiled bench: error: --seconds must be positive", file=sys.stderr)
            return 2
        if not 0 <= args.sim_nice <= 19:
            print(f"tactiled bench: error: --sim-nice must be a niceness 0-19, got {args.sim_nice}",
                  file=sys.stderr)
            return 2
    sensor = SensorModel(noise=BENCH_NOISE)
    out = [_header(args)]
    if "configs" in suites:
        scenes = args.scenes or (40 if args.quick else 240)
        frames = build_suite(scenes, 4, kinds=("cylinder", "cylinder", "edge"), seed=args.seed, sensor=sensor)
        reference = Fitter(sensor)
        truths = [runner.truth_of(f, reference) for f in frames]
        estimators = default_configurations(sensor, args.quick)
        rows = runner.run_estimators(estimators, frames, truths, args.progress)
        nf_frames, nf_radii = foundation.reference_cylinders(args.quick)
        runner.noise_free_bias(estimators, rows, nf_frames, nf_radii)
        out += ["", f"## Configurations ({scenes} scenes x 4 frames: cylinders psi 30-150 and edges r1 < 1 mm, "
                "0.1-3 N, centres over the whole array)", "",
                runner.markdown_table(rows), "",
                f"Radius statistics over frames whose radius bound is under {100 * runner.OBSERVABLE_RELATIVE:.0f} % "
                f"of the radius, angle over bounds under {runner.OBSERVABLE_ANGLE:g} deg; 'n/a' counts frames "
                "where an observable quantity was not returned.  RMS err / CRB pools error / Cramer-Rao bound "
                "(at the truth) over all five parameters.  The noise-free column is the worst radius error on "
                "cylinders from the independent reference integration (R 1-50 mm, psi 30-150, 0.5-2 N): the "
                "estimator's own bias, which noise hides.  Pareto: no other row at least as good in median CPU time, "
                "RMS err / CRB and noise-free radius error, and better in one."]
        front = runner.pareto_front(rows)
        out.append("")
        out.append(f"Default configuration on the Pareto front: {'yes' if front[0] else 'NO'}")
        if args.plot:
            runner.pareto_plot(rows, args.plot)
            out.append(f"Pareto chart written to {args.plot}")
    if "models" in suites:
        scenes = (args.scenes or (40 if args.quick else 160))
        frames = build_suite(scenes, 2, seed=args.seed + 1, sensor=sensor)
        reference = Fitter(sensor)
        truths = [runner.truth_of(f, reference) for f in frames]
        out += ["", f"## Model order ({scenes} scenes x 2 frames over cylinders, edges, spheres, ellipsoids)", "",
                "| estimator | kind | frames | CPU ms median | radius % med | second radius % med | model picked (share) |",
                "|---|---|---|---|---|---|---|"]
        for name, model in (("fit cylinder", "cylinder"), ("fit auto (BIC)", "auto")):
            fitter = Fitter(sensor, FitOptions())
            by_kind: dict[str, list] = {}
            bar = runner.Progress(len(frames), name, args.progress)
            for bf, truth in zip(frames, truths):
                t0 = time.thread_time()
                res = fitter.fit(bf.strain, model)
                dt = (time.thread_time() - t0) * 1e3
                e = runner.error("r1_mm", res.values["r1_mm"], bf.contact.r1) if runner.observable("r1_mm", truth) else None
                # an ellipsoid's second radius, where its bound resolves it and the model picked has one
                e2 = (runner.error("r2_mm", res.values.get("r2_mm"), truth.values["r2_mm"])
                      if runner.observable("r2_mm", truth) else None)
                by_kind.setdefault(bf.kind, []).append((dt, e, res.model, e2))
                bar.step()
            for kind, items in by_kind.items():
                import numpy as np

                times = [i[0] for i in items]
                errs = [abs(i[1]) for i in items if i[1] is not None]
                errs2 = [abs(i[3]) for i in items if i[3] is not None]
                picks: dict[str, int] = {}
                for i in items:
                    picks[str(i[2])] = picks.get(str(i[2]), 0) + 1
                share = ", ".join(f"{m} {100 * c / len(items):.0f} %" for m, c in sorted(picks.items(), key=lambda t: -t[1]))
                out.append(f"| {name} | {kind} | {len(items)} | {np.median(times):.3f} | "
                           f"{np.median(errs) if errs else float('nan'):.1f} | "
                           f"{f'{np.median(errs2):.1f}' if errs2 else '-'} | {share} |")
    if "skip" in suites:
        from tactiled_bench import skipping

        out += ["", "## Skipping: no contact", "", skipping.no_contact(args.quick, args.progress)]
        out += ["", "## Skipping: unchanged frames (chi-square test against the last fitted frame)", "",
                skipping.unchanged(args.quick, args.progress)]
        out += ["", "## Skipping: too light for curvature (radius withheld when its bound exceeds 50 %)", "",
                skipping.too_light(args.quick, args.progress)]
        out += ["", "## Skipping: a scripted scene", "", skipping.scene_throughput(args.quick, args.progress)]
    if "foundation" in suites:
        out += ["", "## Foundation: noise-free recovery", "", foundation.noise_free_recovery(args.quick, args.progress)]
        text, _ = foundation.noisy_efficiency(args.quick, args.progress)
        out += ["", "## Foundation: noisy frames against the Cramer-Rao bound", "", text]
        out += ["", "## Foundation: the paper's Table 1 in simulation", "", foundation.paper_table1(args.quick, args.progress)]
        out += ["", "## Foundation: speed", "", foundation.speed(args.quick, args.progress)]
    if "acquisition" in suites:
        from tactiled_bench import acquisition

        scene = args.scene.strip().lower()
        what = "a hand: six devices" if scene == acquisition.HAND else "three fingers"
        out += ["", f"## Acquisition: {what} at 1 kHz over ptys, scene {scene}", "",
                acquisition.run(args.quick, scene=scene, workers=args.workers,
                                seconds=args.seconds, baseline=args.baseline, sim_nice=args.sim_nice,
                                json_path=args.json)]
    if "speed" in suites and (args.suite == "speed" or args.baseline):
        from tactiled_bench import speed

        out += ["", "## Fitter speed" + (f" against {args.baseline}" if args.baseline else ""), "",
                speed.run(args.quick, args.progress, args.baseline)]
    if "temporal" in suites:
        from tactiled_bench import temporal

        out += ["", "## Time: held contacts sharpen, moving ones are tracked", "",
                temporal.run(args.quick, _say if args.progress is not False else None,
                             args.plot if args.suite == "temporal" else None)]
    # the suites that take --sensor: a bad description is exit 2 with its one-line message
    for suite, title in (("sensors", "Sensors: accuracy on every description"),
                         ("contacts", "Several contacts on one array"),
                         ("shear", "Shear, torsion, friction and slip on 3-axis arrays")):
        if suite not in suites:
            continue
        import importlib

        from tactiled.errors import ConfigError

        module = importlib.import_module(f"tactiled_bench.{suite}")
        try:
            report = module.run(args.quick, args.progress, args.sensor, args.seed)
        except ConfigError as err:
            print(f"tactiled bench: error: {err}", file=sys.stderr)
            return 2
        out += ["", f"## {title}", "", report]
    if "identify" in suites:
        from tactiled_bench import identify

        out += ["", "## Identification: a finger that is not the paper's", "", identify.run(args.quick, args.progress)]
    if "unexplained" in suites:
        from tactiled_bench import unexplained

        out += ["", "## Frames the model cannot explain: the fit budget", "",
                unexplained.run(args.quick, args.progress)]
    print("\n".join(out))
    return 0

"""Build per-tactel lookup tables (raw counts -> strain) from recorded presses with known loads.

PRESSES.npz holds the lab's presses (docs/howto/calibration.md; `tactiled presses` makes one
from a recorded session):
  counts      (N, rows, cols) integer raw counts, 0..65535
  strain_ref  (N, rows, cols) float, the strain each tactel should read for that press
  sensor_id   integer scalar (optional here if --sensor-id is given)

Per tactel, a least-squares piecewise-linear response counts(strain) is fitted on up to --knots
knots, made monotone by pool-adjacent-violators and inverted into the table.  Printed: the RMS
residual per tactel as a rows x cols grid (units of 1e-4 strain) with flags D (dead: gain below
--dead-fraction of the median), N (non-monotone: more than --nonmonotone-fraction of the response
runs backwards) and U (unexercised: reference strain spans < --min-strain-span), then a summary.
The calibration file (JSON, format in docs/reference/file-formats.md) is written to -o even when tactels are
flagged; the flags are stored in it.  --strict makes flagged tactels exit 1.

Exit status: 0 success, 1 flagged tactels with --strict, 2 unusable input (one error line).

With --identify, the press file carries each press's known contact instead of strain_ref:
  contacts    (N, 6) float: r1_mm, r2_mm (inf = cylinder), angle_deg, force_n, x_mm, y_mm
              (force_n 0 = unloaded; its other columns are ignored)
and the rubber's constants (depth_x, nu_x, depth_y, nu_y, modulus), every tactel's response
and position, and the model-error floor are estimated together by maximum likelihood.  Each
constant is printed with its 1-sigma bound; one the presses cannot determine is held at the
nominal value (the --sensor description's cover; the paper's finger's without --sensor), and
the report says why.  The file written is a version 2 calibration file.

The file belongs to the sensor id in the presses (or --sensor-id): the id the sensor's frames
carry (a lines or FlexiTac device sends 0, a Robotiq finger its number, a XELA sensor its
number; docs/howto/calibration.md).  The daemon refuses at start a calibration of another id.

Example:
  tactiled calibrate presses.npz -o pad.json --knots 8
  tactiled calibrate contacts.npz -o pad.json --identify --sensor flat16
  tactiled calibrate --bench          # per-frame cost of linearisation, zeroing, detection
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Iterator

from tactiled.errors import CalibrationError

HELP = "build per-tactel lookup tables from recorded presses with known loads"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    # Defaults are repeated literally (not imported) so --help never imports numpy.
    parser.add_argument("presses", nargs="?", metavar="PRESSES.npz",
                        help="recorded presses: counts, strain_ref[, sensor_id]")
    parser.add_argument("-o", "--output", metavar="CAL.json",
                        help="calibration file to write (required unless --bench)")
    parser.add_argument("--sensor-id", type=int, metavar="ID",
                        help="the sensor's id (0..65535); must match the press file's, "
                        "if it has one")
    parser.add_argument("--knots", type=int, default=8, metavar="N",
                        help="maximum knots per tactel, >= 2 (default 8)")
    parser.add_argument("--dead-fraction", type=float, default=0.1, metavar="F",
                        help="dead if gain < F * median gain (default 0.1)")
    parser.add_argument("--nonmonotone-fraction", type=float, default=0.1, metavar="F",
                        help="non-monotone if more than F of the response runs backwards "
                        "(default 0.1)")
    parser.add_argument("--min-strain-span", type=float, default=0.005, metavar="S",
                        help="unexercised if the reference strain spans less than S "
                        "(default 0.005)")
    parser.add_argument("--identify", action="store_true",
                        help="presses carry known contacts: identify the finger's rubber "
                        "constants, tactel responses and positions, and model-error floor")
    parser.add_argument("--sensor", metavar="NAME|FILE.toml", default=None,
                        help="with --identify: the array pressed, a built-in description or a "
                        "description file (docs/howto/sensors.md); its cover's constants are the start "
                        "and what the presses cannot determine is held at (default: the paper's finger)")
    parser.add_argument("--strict", action="store_true", help="exit 1 if any tactel is flagged")
    parser.add_argument("--bench", action="store_true",
                        help="print the per-frame cost of the calibration stage and exit")


def run(args: argparse.Namespace) -> int:
    if args.bench:
        from tactiled_bench.calibration_cost import main as bench_main

        return bench_main()
    if not args.presses or not args.output:
        raise CalibrationError("need PRESSES.npz and -o CAL.json (see tactiled calibrate -h)")
    if args.knots < 2:
        raise CalibrationError(f"--knots must be >= 2, got {args.knots}")
    for name in ("dead_fraction", "nonmonotone_fraction"):
        value = getattr(args, name)
        if not 0.0 <= value <= 1.0:
            raise CalibrationError(f"--{name.replace('_', '-')} must lie in [0, 1], got {value}")
    if not args.min_strain_span >= 0.0:
        raise CalibrationError(f"--min-strain-span must be >= 0, got {args.min_strain_span}")
    if args.sensor_id is not None and not 0 <= args.sensor_id <= 0xFFFF:
        raise CalibrationError(f"--sensor-id must lie in 0..65535, got {args.sensor_id}")

    from tactiled import __version__
    from tactiled.calibration.builder import build_table
    from tactiled.io.calibration import save_calibration
    from tactiled.io.presses import load_presses
    from tactiled.io.files import check_output

    check_output(args.output, CalibrationError)  # before the work, not after it
    presses = load_presses(args.presses)
    if args.identify:
        return _identify(args, presses)
    if presses.strain_ref is None:
        raise CalibrationError(f"{args.presses}: has 'contacts' but no 'strain_ref': use --identify")
    with _naming(args.presses):
        report = build_table(
            presses,
            knots=args.knots,
            sensor_id=args.sensor_id,
            dead_fraction=args.dead_fraction,
            nonmonotone_fraction=args.nonmonotone_fraction,
            min_strain_span=args.min_strain_span,
        )
    build = {"tool": f"tactiled {__version__} calibrate", "presses": report.presses,
             "source": str(args.presses), **report.options}
    path = save_calibration(report.table, args.output, build=build)
    print(report.format())
    print(f"wrote {path}")
    if report.flagged.any():
        print(f"tactiled calibrate: warning: {int(report.flagged.sum())} tactel(s) flagged; "
              "see the flags above (they are recorded in the file)", file=sys.stderr)
        if args.strict:
            return 1
    return 0


@contextlib.contextmanager
def _naming(path: str) -> Iterator[None]:
    """What the presses cannot give (a contact that contradicts the array, too few loaded
    presses...) is said of the press file: its name leads the message."""
    try:
        yield
    except CalibrationError as err:
        if str(err).startswith(str(path)):
            raise
        raise CalibrationError(f"{path}: {err}") from None


def _identify(args: argparse.Namespace, presses) -> int:
    """``--identify``: the finger's model from presses of known contacts."""
    import time

    from tactiled import __version__
    from tactiled.io.calibration import save_calibration
    from tactiled.calibration.identify import identify, format_report

    if presses.contacts is None:
        raise CalibrationError(f"{args.presses}: --identify needs a 'contacts' array (N, 6)")
    if args.sensor_id is not None:
        if presses.sensor_id is not None and presses.sensor_id != args.sensor_id:
            raise CalibrationError(f"--sensor-id {args.sensor_id} does not match the press file's "
                                   f"sensor_id {presses.sensor_id}")
        presses.sensor_id = args.sensor_id
    if presses.sensor_id is None:
        raise CalibrationError(f"{args.presses}: no 'sensor_id'; give --sensor-id")
    t0 = time.monotonic()

    def progress(msg: str) -> None:
        print(f"[{time.monotonic() - t0:5.1f} s] {msg}", file=sys.stderr, flush=True)

    with _naming(args.presses):
        if args.sensor is not None:
            from tactiled.sensors import load_description

            desc = load_description(args.sensor)
            if (desc.rows, desc.cols) != tuple(presses.shape):
                raise CalibrationError(f"presses of a {presses.shape[0]}x{presses.shape[1]} "
                                       f"array, but sensor {desc.name!r} is {desc.rows}x{desc.cols}")
            base = desc.sensor_model()
            result = identify(presses, base.geometry, knots=args.knots, progress=progress,
                              nominal=base, nominal_name=f"description {desc.name}'s")
        else:
            result = identify(presses, knots=args.knots, progress=progress)
    build = {"tool": f"tactiled {__version__} calibrate --identify", "presses": len(presses),
             "source": str(args.presses), "knots": args.knots}
    path = save_calibration(result.table, args.output, build=build, model=result.model)
    print(format_report(result))
    print(f"wrote {path}")
    return 0

"""Make a press file from a recorded calibration session and the known contacts pressed.

RECORDING.tact is the session as `tactiled record` wrote it: the array unloaded for its first
--quiet frames (at least 50 at the default), then each press (load, hold still, lift off fully).
CONTACTS.csv lists the known contact of every press in the order pressed, one line each, under
the header line

  r1_mm,r2_mm,angle_deg,force_n,x_mm,y_mm

(radii of the indenter, r2_mm inf for a cylinder; the direction of a cylinder's axis from +x
toward +y; the force; the centre in the array's frame, tactel [0, 0] at the origin).  A line
with force_n 0 is an unloaded sample, taken from the rest before the next press.  `#` starts a
comment line.

A frame is loaded when a tactel departs from its rest by more than --threshold noise sigmas; a
press is a run of loaded frames, and its counts are the mean of its last --average frames
before the lift-off.  The presses found must be as many as the loaded lines.  The file written
is what `tactiled calibrate --identify` reads (docs/reference/file-formats.md).

Exit status: 0 written; 2 unusable input, with one error line.

Example:
  tactiled record lines:///dev/ttyACM0?rows=16&cols=16 -o session.tact
  tactiled presses session.tact --contacts pressed.csv -o presses.npz
  tactiled calibrate presses.npz -o pad.json --identify --sensor pad16.toml
"""

from __future__ import annotations

import argparse

from tactiled.errors import CalibrationError

HELP = "make a press file from a recorded session and the known contacts pressed"


def add_arguments(p: argparse.ArgumentParser) -> None:
    # Defaults repeated literally (tactiled/calibration/recorded.py) so --help imports no numpy.
    p.add_argument("recording", metavar="RECORDING.tact", help="the session, from tactiled record")
    p.add_argument("--contacts", required=True, metavar="CONTACTS.csv",
                   help="the known contact of every press, in the order pressed")
    p.add_argument("-o", "--output", required=True, metavar="PRESSES.npz",
                   help="the press file to write")
    p.add_argument("--sensor-id", type=int, default=None, metavar="ID",
                   help="the sensor's id (default: the recording's)")
    p.add_argument("--quiet", type=int, default=50, metavar="N",
                   help="frames at rest at the start that set each tactel's rest and noise "
                   "(default 50)")
    p.add_argument("--threshold", type=float, default=8.0, metavar="SIGMAS",
                   help="a frame is loaded when a tactel departs from its rest by more than "
                   "this many noise sigmas (default 8)")
    p.add_argument("--average", type=int, default=32, metavar="N",
                   help="frames averaged per press (default 32)")


def run(args: argparse.Namespace) -> int:
    if args.quiet < 2 or args.average < 1 or not args.threshold > 0:
        raise CalibrationError("--quiet must be >= 2, --average >= 1 and --threshold > 0")
    if args.sensor_id is not None and not 0 <= args.sensor_id <= 0xFFFF:
        raise CalibrationError(f"--sensor-id must lie in 0..65535, got {args.sensor_id}")
    from tactiled.io.presses import save_presses
    from tactiled.calibration.recorded import presses_from_recording, read_contacts, recorded_counts
    from tactiled.io.files import check_output

    check_output(args.output, CalibrationError)
    contacts = read_contacts(args.contacts)
    counts, sensor_id = recorded_counts(args.recording)
    try:
        presses = presses_from_recording(
            counts, contacts, sensor_id if args.sensor_id is None else args.sensor_id,
            quiet=args.quiet, threshold=args.threshold, average=args.average)
    except CalibrationError as err:
        raise CalibrationError(f"{args.recording}: {err}") from None
    path = save_presses(presses, args.output)
    loaded = int((presses.contacts[:, 3] > 0).sum())
    print(f"wrote {path}: {len(presses)} press(es) ({loaded} loaded) of sensor "
          f"{presses.sensor_id}, {presses.shape[0]}x{presses.shape[1]} tactels, from "
          f"{len(counts)} frames")
    return 0

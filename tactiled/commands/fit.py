"""Fit contact parameters to the frames of an .npz file; print one JSON object per frame.

FRAMES.npz holds 'strain', a float array (N, rows, cols) of linearised, zeroed strain, positive
under compression, and optionally the scalars 'dx', 'dy' (tactel pitch, mm).  Each output line:

  {"frame": i, "contact": bool, "model": "cylinder"|"sphere"|"general"|null,
   "x_mm", "y_mm", "force_n", "r1_mm", "r2_mm" (null = infinite), "angle_deg" (psi in [0, 180),
   null for a sphere), "rms", "std": {same keys: 1-sigma Cramer-Rao bounds}, "fit_ms", ...}

Extra keys: label (edge/plane/model), converged, iterations, condition, peak, reasons (why any
value is null or suspect), message.  Contact is decided by a matched filter against a threshold
set for 1e-4 false contacts per noise-only frame.  Sensor noise sigma: --sigma, else the noise
stored in the file by 'tactiled simulate', else 0.0005.  A bad file gets one error line, exit 2.

--calibration CAL.json fits with the sensor's calibration: a version 2 file's identified rubber
constants, tactel positions and model-error floor (docs/calibration.md).  With it, FRAMES.npz
may hold 'counts' (N, rows, cols) raw readings (and optionally 'sensor_id', checked against the
file) in place of 'strain'; they go through the file's tables (strain 0 at the zero-load
point), then the fit.  Uncertainties also widen when the residuals of the frames fitted so far
show the finger departing from its model (docs/fitting.md, "Honest uncertainties").
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from tactiled.calibration.contact import ContactDetector
from tactiled.calibration.fileformat import Calibration, load_calibration_file
from tactiled.config import Geometry, NoiseModel, SensorModel
from tactiled.errors import TactiledError
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.result import FitResult
from tactiled.framefile import load_frame_file

MODELS = ("auto", "cylinder", "sphere", "general")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("frames", metavar="FRAMES.npz", help="frame file to fit")
    p.add_argument("--model", choices=MODELS, default="cylinder",
                   help="contact model; 'auto' picks by the Bayesian information criterion (default cylinder)")
    p.add_argument("--window", type=int, default=4, metavar="N",
                   help="fit an N x N window around the peak, up to the whole array (default 4)")
    p.add_argument("--sigma", type=float, default=None,
                   help="sensor strain noise (1 sigma) for uncertainties and the contact threshold")
    p.add_argument("--calibration", metavar="CAL.json", default=None,
                   help="the sensor's calibration file: its identified model (version 2) is used, "
                   "and FRAMES.npz may then hold raw 'counts'")


def _sensor(args: argparse.Namespace, shape: tuple[int, int], dx: float | None, dy: float | None,
            extras: dict[str, np.ndarray], calibration: Calibration | None = None) -> SensorModel:
    geo = Geometry(rows=shape[0], cols=shape[1], dx=dx or Geometry.dx, dy=dy or Geometry.dy)
    if args.sigma is not None:
        noise = NoiseModel(sigma=args.sigma)
    elif "noise_sigma" in extras:
        noise = NoiseModel(sigma=float(extras["noise_sigma"]), quantum=float(extras.get("noise_quantum", 0.0)))
    else:
        noise = NoiseModel()
    if calibration is not None:
        if calibration.table.shape != shape:
            raise ValueError(f"{calibration.source}: calibration for a {calibration.table.shape} "
                             f"array, but the frames are {shape}")
        return calibration.sensor_model(noise, geo)
    return SensorModel(geometry=geo, noise=noise)


def run(args: argparse.Namespace) -> int:
    if args.window < 2:
        print(f"tactiled fit: error: --window must be at least 2, got {args.window}", file=sys.stderr)
        return 2
    try:
        cal = load_calibration_file(args.calibration) if args.calibration else None
        ff = load_frame_file(args.frames, table=cal.table if cal else None)
        sensor = _sensor(args, ff.strain.shape[1:], ff.dx, ff.dy, ff.extras, cal)
    except (TactiledError, ValueError) as err:
        print(f"tactiled fit: error: {err}", file=sys.stderr)
        return 2
    fitter = Fitter(sensor, FitOptions(window=args.window, learn_floor=True))
    detector = ContactDetector(sensor=sensor)
    out = sys.stdout
    for i, frame in enumerate(ff.strain):
        if detector.statistic(frame) > detector.enter_threshold:
            result = fitter.fit(frame, args.model)
        else:
            result = FitResult(contact=False, message="no contact: below the noise threshold")
        out.write(json.dumps(result.to_json_dict(frame=i), allow_nan=False) + "\n")
    out.flush()
    return 0

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
constants, tactel positions and model-error floor (docs/howto/calibration.md).  With it, FRAMES.npz
may hold 'counts' (N, rows, cols) raw readings (and optionally 'sensor_id', checked against the
file) in place of 'strain'; they go through the file's tables (strain 0 at the zero-load
point), then the fit.  Uncertainties also widen when a frame's residuals say the finger departs
from its model (docs/concepts/uncertainty.md).

The finger is learned first (--learn, the default): a first pass fits up to 2000 of the
file's contact frames, spread over it, in order, learning how far the finger departs from its
model (the model-error floor) and each tactel's gain and position (the flat field).  If they
show a departure beyond the noise, every frame is then fitted with what was learned, its
uncertainties widened to match and its tactels corrected, and stderr says so; if not, the
output is what each frame gives alone.  --no-learn skips the pass.

Every frame is fitted on its own (cold start, the same learned state), so frames can be fitted
in parallel: --jobs N worker processes (default: every core this process may use, for inputs
of 2000 frames or more) take chunks of frames, and the lines are written strictly in frame
order, the same as with --jobs 1 but for the timing key fit_ms.  Progress goes to stderr for
inputs of 1000 frames or more (a bar on a terminal, else a line every 10 s and the totals at
the end); stdout carries only the JSON lines.  For raw
recordings (.tact), which need calibration and zeroing frame by frame, use 'tactiled replay'.

A 3-axis file ('taxels' (N, rows, cols, 3), written by 'tactiled simulate --sensor' on a 3-axis
description) is fitted by the shear model instead: each line then carries the 'shear' and
'slip' tables (tangential force, torsion, friction; docs/concepts/shear.md).
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import signal
import sys
from collections import deque
from dataclasses import replace
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TextIO

import numpy as np

from tactiled.calibration.detection import ContactDetector
from tactiled.io.calibration import Calibration, load_calibration_file
from tactiled.sensors.model import Geometry, NoiseModel, SensorModel
from tactiled.errors import TactiledError
from tactiled.fit.result import FitResult  # light: no scipy
from tactiled.io.framefile import load_frame_file
from tactiled.progress import Progress
from tactiled.sensors import load_description

MODELS = ("auto", "cylinder", "sphere", "general")
#: Inputs at least this long show progress on stderr by default.
LONG_INPUT = 1000
#: Without --jobs, shorter inputs are fitted in this process: starting the workers (a
#: forkserver that imports scipy and the fitter, then a fitter per worker: ~1 s more than fitting
#: here) would cost more than two cores save on fewer frames (~0.8 ms a cold cylinder fit).
PARALLEL_INPUT = 2000
#: Frames per chunk handed to a worker: enough work (~16-256 ms) to drown the cost of sending
#: it (~0.2 ms), small enough to spread evenly over the workers and keep progress moving.
MIN_CHUNK, MAX_CHUNK = 16, 256
#: Chunks in flight per worker: enough to keep every worker busy while the parent writes.
AHEAD = 4
#: The learning pass fits at most this many contact frames (~1-2 s), spread over the file.
LEARN_FITS = 2000
#: Imported once by the forkserver, so the workers forked from it start with the fitter
#: imported and the default sensor's start table built (docs/concepts/pipeline.md, "Workers").
PRELOAD_MODULE = "tactiled.pipeline.preload"


def available_cores() -> int:
    """CPUs this process may run on (its affinity mask, which a container or ``taskset``
    narrows; ``os.cpu_count()`` where the platform has no such mask)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _jobs(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of worker processes, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"--jobs must be at least 1, got {n}")
    return n


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("frames", metavar="FRAMES.npz", help="frame file to fit")
    p.add_argument("--model", choices=MODELS, default="cylinder",
                   help="contact model; 'auto' picks by the Bayesian information criterion (default cylinder)")
    p.add_argument("--window", type=int, default=None, metavar="N",
                   help="fit an N x N window around the peak, up to the whole array (default: "
                   "the --sensor description's, else 4)")
    p.add_argument("--sigma", type=float, default=None,
                   help="sensor strain noise (1 sigma) for uncertainties and the contact threshold")
    p.add_argument("--sensor", metavar="NAME|FILE.toml", default=None,
                   help="the array the frames come from: a built-in description (`tactiled "
                   "sensors` lists them) or a description file (docs/howto/sensors.md); default: the "
                   "paper's finger with the frames' shape and any pitch the file gives (dx, dy)")
    p.add_argument("--calibration", metavar="CAL.json", default=None,
                   help="the sensor's calibration file: its identified model (version 2) is used, "
                   "and FRAMES.npz may then hold raw 'counts'")
    p.add_argument("--jobs", "-j", type=_jobs, default=None, metavar="N",
                   help=f"worker processes fitting in parallel (default: every core available, "
                        f"here {available_cores()}, for inputs of {PARALLEL_INPUT} frames or more; "
                        "shorter ones in this process); the output does not depend on it")
    p.add_argument("--learn", action=argparse.BooleanOptionalAction, default=True,
                   help=f"first learn, from up to {LEARN_FITS} of the file's contact frames, how the "
                   "finger departs from its model (its tactels' gains and positions, the residual "
                   "floor) and fit every frame with it (default on; docs/concepts/fitting.md)")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help=f"progress on stderr (default: for inputs of {LONG_INPUT} frames or more)")


def _check_default_shape(shape: tuple[int, int], dx: float | None, dy: float | None) -> None:
    """Frames named by no description and giving no pitch are fitted as the paper's finger
    only if they are its 8x8 shape: another array fitted with its 3.3 x 3.9 mm pitch would
    give wrong positions and radii without a word (ValueError, naming the built-in
    descriptions of that shape if there are any)."""
    if dx is not None and dy is not None or tuple(shape) == (Geometry.rows, Geometry.cols):
        return
    from tactiled.sensors import builtin_names

    same = [n for n in builtin_names()
            if (load_description(n).rows, load_description(n).cols) == tuple(shape)]
    hint = f" ({', '.join(same)} {'is' if len(same) == 1 else 'are'} {shape[0]}x{shape[1]})" if same else ""
    raise ValueError(f"{shape[0]}x{shape[1]} frames, but no sensor says what array they come "
                     f"from and the file gives no pitch (dx, dy): name it with --sensor "
                     f"NAME|FILE.toml{hint}; `tactiled sensors` lists the built-in arrays")


def _sensor(args: argparse.Namespace, shape: tuple[int, int], dx: float | None, dy: float | None,
            extras: dict[str, np.ndarray], calibration: Calibration | None = None) -> SensorModel:
    base: SensorModel | None = None
    if getattr(args, "sensor", None) is not None:
        desc = load_description(args.sensor)
        if (desc.rows, desc.cols) != tuple(shape):
            raise ValueError(f"sensor {desc.name!r} is a {desc.rows}x{desc.cols} array, but the "
                             f"frames are {shape[0]}x{shape[1]}")
        base = desc.sensor_model()
        geo = base.geometry
    else:
        _check_default_shape(shape, dx, dy)
        geo = Geometry(rows=shape[0], cols=shape[1], dx=dx or Geometry.dx, dy=dy or Geometry.dy)
    if args.sigma is not None:
        noise = NoiseModel(sigma=args.sigma)
    elif "noise_sigma" in extras:
        noise = NoiseModel(sigma=float(extras["noise_sigma"]), quantum=float(extras.get("noise_quantum", 0.0)))
    else:
        noise = base.noise if base is not None else NoiseModel()
    if calibration is not None:
        if calibration.table.shape != shape:
            raise ValueError(f"{calibration.source}: calibration for a {calibration.table.shape} "
                             f"array, but the frames are {shape}")
        return calibration.sensor_model(noise, geo, base=base)
    if base is not None:
        return replace(base, noise=noise)
    return SensorModel(geometry=geo, noise=noise)


# --------------------------------------------------------------------------------------------
# The work, the same in this process and in a worker


class _Fitting:
    """Turns frames into output lines: the contact decision, then a cold fit of each contact
    frame (no state carries from one frame to the next, which is what makes chunks
    independent and the output the same for any number of workers)."""

    def __init__(self, sensor: SensorModel, window: int, model: str, learned: Any = None) -> None:
        # Imported here: a parent that only hands chunks to workers never loads the fitter.
        from tactiled.fit.fitter import FitOptions, Fitter
        from tactiled.fit.multi import contacts_json, fit_contacts

        self._contacts = lambda frame: contacts_json(fit_contacts(self.fitter, frame, self.model))
        self.fitter = Fitter(sensor, FitOptions(window=window, learn_floor=learned is not None))
        if learned is not None:
            self.fitter.adopt(*learned)
        self.detector = ContactDetector(sensor=sensor)
        self.model = model

    def lines(self, first: int, strain: np.ndarray) -> str:
        """JSON lines (each ending in a newline) of frames ``first, first + 1, ...``."""
        out = []
        for i, frame in enumerate(strain, first):
            if self.detector.statistic(frame) > self.detector.enter_threshold:
                line = self._contacts(frame)
            else:
                line = FitResult(contact=False, message="no contact: below the noise threshold").to_json_dict()
            out.append(json.dumps({"frame": i, **line}, allow_nan=False) + "\n")
        return "".join(out)


_worker: _Fitting | None = None  # a worker process's fitter, built once by _init_worker


def _init_worker(sensor: SensorModel, window: int, model: str, learned: Any) -> None:
    # Ctrl-C signals the whole process group; the parent decides what stops, and a worker's
    # traceback for it would only bury the message.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    global _worker
    _worker = _Fitting(sensor, window, model, learned)


def _fit_chunk(first: int, strain: np.ndarray) -> str:
    assert _worker is not None, "worker not initialised"
    return _worker.lines(first, strain)


# --------------------------------------------------------------------------------------------


def learn(sensor: SensorModel, window: int, model: str, strain: np.ndarray,
          progress: bool) -> tuple[Any, str] | None:
    """The learning pass: ``((floor, flat), what they say)`` when up to ``LEARN_FITS`` of the
    contact frames of ``strain``, spread over it, fitted in order, show the finger departing
    from its model; None when they do not (or there are too few to tell)."""
    from tactiled.fit.fitter import FitOptions, Fitter

    detector = ContactDetector(sensor=sensor)
    contact = [i for i, frame in enumerate(strain) if detector.statistic(frame) > detector.enter_threshold]
    if not contact:
        return None
    picked = contact[::max(1, math.ceil(len(contact) / LEARN_FITS))]
    fitter = Fitter(sensor, FitOptions(window=window, learn_floor=True))
    bar = Progress(len(picked), "tactiled fit: learning the finger", progress, unit="frames")
    for i in picked:
        fitter.fit(strain[i], model)
        bar.step()
    flat = fitter.flat  # None on an array too large for one (flatfield.MAX_TACTELS)
    if flat is not None:
        flat.solve()  # on every fit, not only those up to the last scheduled solve
    active = flat is not None and flat.active
    ts, tg = fitter.floor.taus()
    took = f"{len(picked)} frame(s) in {bar.elapsed():.1f} s"
    if not active and ts <= 0.0 and tg <= 0.0:
        bar.finish(f"{took}: no departure from the model beyond the noise")
        return None
    said = []
    if active:
        said.append(f"flat field: {flat.note}")
    elif flat is not None and flat.note:
        said.append(f"no flat field: {flat.note}")
    if ts > 0.0 or tg > 0.0:
        said.append(f"residual floor ~{100 * math.sqrt(ts):.2g} % of the strain and "
                    f"~{1000 * math.sqrt(tg):.2g} um of tactel position")
    message = f"{took}: " + "; ".join(said)
    bar.finish(message)
    return (fitter.floor, flat), message


class _Identifying:
    """The output stream, giving each line's contacts their ids as they are written in frame
    order (:mod:`tactiled.pipeline.association`: consecutive frames of a contact keep its id;
    a frame without contact ends every id)."""

    def __init__(self, out: TextIO, gate_mm: float) -> None:
        from tactiled.pipeline.association import ContactIds

        self._out = out
        self._ids = ContactIds(gate_mm)

    def write(self, text: str) -> None:
        from tactiled.pipeline.association import identified

        lines = [json.dumps(identified(json.loads(t), self._ids), allow_nan=False)
                 for t in text.splitlines()]
        self._out.write("".join(f"{t}\n" for t in lines))

    def flush(self) -> None:
        self._out.flush()

    def fileno(self) -> int:
        return self._out.fileno()


def chunk_size(frames: int, jobs: int) -> int:
    """Frames per chunk: about 8 chunks per worker, within [MIN_CHUNK, MAX_CHUNK]."""
    return max(MIN_CHUNK, min(MAX_CHUNK, math.ceil(frames / (8 * jobs))))


def _serial(work: _Fitting, strain: np.ndarray, out: TextIO, bar: Progress) -> None:
    step = MIN_CHUNK  # written a chunk at a time: a reader of a pipe sees lines as they come
    for lo in range(0, len(strain), step):
        out.write(work.lines(lo, strain[lo:lo + step]))
        bar.step(min(step, len(strain) - lo))


def _parallel(sensor: SensorModel, args: argparse.Namespace, strain: np.ndarray, jobs: int,
              chunk: int, out: TextIO, bar: Progress, learned: Any) -> None:
    """Chunks to ``jobs`` worker processes, at most ``AHEAD`` per worker in flight (memory
    stays bounded however long the input); each chunk's lines are written as soon as every
    chunk before it has been."""
    ctx = multiprocessing.get_context("forkserver")  # never fork: numpy's BLAS may hold threads
    ctx.set_forkserver_preload([PRELOAD_MODULE])
    pending: deque[tuple[int, Future[str]]] = deque()
    with ProcessPoolExecutor(jobs, mp_context=ctx, initializer=_init_worker,
                             initargs=(sensor, args.window, args.model, learned)) as pool:
        try:
            lo = 0
            while lo < len(strain) or pending:
                while lo < len(strain) and len(pending) < AHEAD * jobs:
                    pending.append((lo, pool.submit(_fit_chunk, lo, strain[lo:lo + chunk])))
                    lo += chunk
                first, future = pending.popleft()
                out.write(future.result())
                bar.step(min(chunk, len(strain) - first))
        except BaseException:
            pool.shutdown(wait=True, cancel_futures=True)
            raise


def run(args: argparse.Namespace) -> int:
    from tactiled.commands import shear

    if shear.is_three_axis_file(args.frames):  # x, y, z per taxel (docs/concepts/shear.md)
        return shear.fit(args)
    if args.window is not None and args.window < 2:
        print(f"tactiled fit: error: --window must be at least 2, got {args.window}", file=sys.stderr)
        return 2
    try:
        cal = load_calibration_file(args.calibration) if args.calibration else None
        ff = load_frame_file(args.frames, table=cal.table if cal else None)
        if args.sensor is None and "sensor" in ff.extras:  # written by simulate --sensor
            args.sensor = str(ff.extras["sensor"])
        if args.window is None:
            args.window = load_description(args.sensor).window if args.sensor else 4
        sensor = _sensor(args, ff.strain.shape[1:], ff.dx, ff.dy, ff.extras, cal)
    except (TactiledError, ValueError) as err:
        print(f"tactiled fit: error: {err}", file=sys.stderr)
        return 2
    strain = ff.strain
    frames = len(strain)
    if args.jobs is not None:
        jobs = args.jobs
    else:
        jobs = available_cores() if frames >= PARALLEL_INPUT else 1
    chunk = chunk_size(frames, jobs)
    jobs = max(1, min(jobs, math.ceil(frames / chunk)))  # no worker without a chunk to fit
    show = frames >= LONG_INPUT if args.progress is None else args.progress
    out = _Identifying(sys.stdout, max(sensor.impulse.depth_x, sensor.impulse.depth_y))
    try:
        learned = None
        if args.learn:
            got = learn(sensor, args.window, args.model, strain, show)
            if got is not None:
                learned, said = got
                if not show:  # the bar said it already
                    print(f"tactiled fit: the finger departs from its model (learned from {said}): "
                          "every frame is fitted with that (--no-learn: each frame alone)", file=sys.stderr)
        bar = Progress(frames, "tactiled fit", show, unit="frames")
        if jobs == 1:
            _serial(_Fitting(sensor, args.window, args.model, learned), strain, out, bar)
        else:
            _parallel(sensor, args, strain, jobs, chunk, out, bar, learned)
        out.flush()
    except BrokenPipeError:
        # The reader went away (`tactiled fit big.npz | head`): stop quietly, as cat does.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, out.fileno())  # so the interpreter's last flush does not fail again
        return 0
    except KeyboardInterrupt:
        print("tactiled fit: interrupted", file=sys.stderr)
        return 130
    except BrokenProcessPool as err:
        print(f"tactiled fit: error: a worker process died ({err}); try --jobs 1", file=sys.stderr)
        return 1
    elapsed = bar.elapsed()
    bar.finish(f"{frames} frame(s) in {elapsed:.1f} s ({frames / elapsed if elapsed > 0 else 0:,.0f} frames/s, "
               f"{jobs} job{'s' if jobs > 1 else ''})")
    return 0


"""Write simulated strain frames with known contact parameters to an .npz file, or act as a
simulated fingertip on a serial device.

File mode (OUTPUT.npz): each parameter takes a value or a range LO:HI drawn uniformly per frame
(radius ranges are drawn log-uniformly).  The frames come from the same forward model the fitter
inverts, plus Gaussian noise and quantisation; the true parameters are stored beside 'strain'
(true_r1, true_r2, true_angle, true_force, true_x, true_y), so a fit can be checked against them.

On a 3-axis --sensor (axes = 3, e.g. xela_uskin_4x4) the file holds 'taxels' (N, rows, cols,
3) under tangential loads: --load random (independent frames; --mu, --lam, --torque) or scenes
at 1 kHz, --load push|twist|pull --sequences N (docs/concepts/shear.md).

Presses mode (OUTPUT.npz --presses N): N presses of known contacts on the simulated finger (the
finger flags below), as docs/howto/calibration.md's identification procedure records them (its
indentors, forces 0.25-2 N, centres over the whole array, ~10 % unloaded, each press the mean
of 32 frames of --sigma noise, as raw counts): the press file 'tactiled calibrate --identify'
reads.  The contact flags (--r1, --force...) do not apply.

Device mode (--pty or --serial): a simulated finger plays a scripted scene (--scene) and streams
wire-format frames in real time at --rate Hz until SIGINT/SIGTERM, exactly as the hardware would
(see docs/concepts/simulator.md).  On a 3-axis --sensor, --scene push|twist|pull streams 3-axis
frames (x, y, z per taxel: version 2 of the wire format), each pass 300 frames at rest, then the
scene.  --pty makes a pseudo-terminal and prints its path as the first line
on stdout ("pty: /dev/pts/N"); --link PATH also points a symlink at it, a stable path for a
daemon config.  Frames the reader does not take are dropped (and counted), never queued
without bound.

examples:
  tactiled simulate cyl.npz --r1 10 --angle 45 --force 1 --x 11 --y 13 --frames 20
  tactiled simulate mix.npz --r1 2:40 --angle 30:150 --force 0.5:2 --frames 200 --seed 7
  tactiled fit cyl.npz
  tactiled simulate presses.npz --presses 400 --depth-x 5 --nu-x 0.4 --modulus 0.32
  tactiled calibrate presses.npz -o cal.json --identify
  tactiled simulate --pty --link /tmp/ttyTACT --scene demo --rate 1000   (read serial:///tmp/ttyTACT)
  tactiled simulate --as flexitac --device /tmp/ttyFLEX --rate 100   (read flexitac:///tmp/ttyFLEX)
  tactiled simulate --pty --link /tmp/ttyPALM --scene hand-palm --sensor flat16   (a hand's palm:
      several contacts at once; its fingertips: --scene hand-finger1 .. hand-finger5, each a
      device of its own, on the default finger; docs/performance/hand.md)
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np

from tactiled.sensors.model import Geometry, NoiseModel, SensorModel
from tactiled.errors import TactiledError
from tactiled.io.files import check_output
from tactiled.commands.device_stream import MAX_BATCH, MAX_LAG_S, FrameWriter, make_pty, remove_link, until_signal
from tactiled.sensors.finger import FingerSpec
from tactiled.sensors import SensorDescription, load_description
from tactiled.io.framefile import save_frame_file
from tactiled.frames import encode_frame
from tactiled.physics.contact import Contact
from tactiled.sim.taxel_stream import TaxelScenes
from tactiled.sim import (
    DEFAULT_DRIFT,
    DEFAULT_HYSTERESIS,
    SCENES,
    DriftModel,
    FingerSimulator,
    FrameSchedule,
    HysteresisModel,
    line_length,
    simulate_frames,
)

FILE_SIGMA = 0.0003  # default --sigma of the .npz mode (the device mode uses the sensor's 0.0005)


def _range(text: str) -> tuple[float, float]:
    try:
        if ":" in text:
            lo, hi = (float(t) for t in text.split(":", 1))
        else:
            lo = hi = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number or LO:HI, got {text!r}") from None
    if math.isnan(lo) or math.isnan(hi) or lo > hi:
        raise argparse.ArgumentTypeError(f"bad range {text!r}")
    return lo, hi


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("output", nargs="?", help="the .npz file to write (omit with --pty / --serial)")
    p.add_argument("--r1", type=_range, default=(10.0, 10.0), help="smaller principal radius, mm (default 10)")
    p.add_argument("--r2", type=_range, default=(math.inf, math.inf),
                   help="larger principal radius, mm; 'inf' for a cylinder (default), equal to r1 for a sphere")
    p.add_argument("--sphere", action="store_true", help="make r2 equal to r1 in every frame")
    p.add_argument("--angle", type=_range, default=(90.0, 90.0),
                   help="direction of the R2 axis (a cylinder's axis) from +x toward +y, degrees (default 90)")
    p.add_argument("--force", type=_range, default=(1.0, 1.0), help="normal force, N (default 1)")
    p.add_argument("--x", type=_range, default=None, help="contact centre along the finger, mm (default: array centre)")
    p.add_argument("--y", type=_range, default=None, help="contact centre around the finger, mm (default: array centre)")
    p.add_argument("--frames", type=int, default=10, help="number of frames (default 10)")
    p.add_argument("--sensor", metavar="NAME|FILE.toml", default=None,
                   help="the simulated array: a built-in description (`tactiled sensors`) or a "
                   "description file (default fearing1988, the paper's finger); on a flat array a "
                   "cylinder is a rod longer than the array, its force spread along the array's "
                   "diagonal (true_load_n_per_mm)")
    p.add_argument("--sigma", type=float, default=None,
                   help=f"Gaussian strain noise (default {FILE_SIGMA} for a file, 0.0005 as a device)")
    p.add_argument("--quantum", type=float, default=0.001, help="quantisation step of strain, 0 for none (default 0.001)")
    p.add_argument("--empty", type=float, default=0.0, help="fraction of frames with no contact (default 0)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    fin = p.add_argument_group(
        "the simulated finger (default: the paper's; docs/concepts/simulator.md)",
        "A finger whose rubber and tactels differ from the model the fitter assumes: its frames "
        "are what that finger reads, linearised with nominal gains and zeroed at its true zero. "
        "Tactel gains, displacements and offsets are drawn from --finger-seed.")
    fin.add_argument("--depth-x", type=float, default=None, metavar="MM", help="rubber depth along x, mm (paper 4.3)")
    fin.add_argument("--nu-x", type=float, default=None, metavar="NU", help="Poisson-like ratio along x (paper 0.5)")
    fin.add_argument("--depth-y", type=float, default=None, metavar="MM", help="rubber depth along y, mm (paper 6.0)")
    fin.add_argument("--nu-y", type=float, default=None, metavar="NU", help="Poisson-like ratio along y (paper 0.7)")
    fin.add_argument("--modulus", type=float, default=None, metavar="E", help="Young's modulus, N/mm^2 (paper 0.25)")
    fin.add_argument("--gain-error", type=float, default=None, metavar="SD",
                     help="tactel gains ~ N(1, SD) (0.05: 5 %%)")
    fin.add_argument("--position-error", type=float, default=None, metavar="MM",
                     help="each tactel displaced ~ N(0, MM) along x and along y")
    fin.add_argument("--offset-counts", type=float, default=None, metavar="COUNTS",
                     help="device mode: count offsets at zero load, uniform within +/-COUNTS")
    fin.add_argument("--finger-seed", type=int, default=None, metavar="N", help="seed of the tactels' draws (default 0)")
    prs = p.add_argument_group("presses mode: a press file for tactiled calibrate --identify")
    prs.add_argument("--presses", type=int, default=None, metavar="N",
                     help="write N presses of known contacts (with --sensor-id) instead of frames; "
                     "docs/howto/calibration.md recommends about 400, identification needs 20 loaded")
    dev = p.add_argument_group("device mode: stream a scene's wire frames in real time")
    where = dev.add_mutually_exclusive_group()
    where.add_argument("--pty", action="store_true",
                       help="create a pseudo-terminal, print 'pty: PATH' and stream to it")
    where.add_argument("--serial", metavar="PORT", help="stream to an existing serial device or pty")
    dev.add_argument("--link", metavar="PATH", help="with --pty: make PATH a symlink to the pty")
    dev.add_argument("--scene", default="demo", help=f"scene to play, looped: {', '.join(SCENES)} (default demo); on a "
                     "3-axis --sensor also push, twist, pull (x, y, z per taxel)")
    dev.add_argument("--rate", type=float, default=1000.0, help="frames per second (default 1000)")
    dev.add_argument("--sensor-id", type=int, default=0, help="sensor id in the frames, 0..65535 (default 0)")
    dev.add_argument("--drift", type=float, default=DEFAULT_DRIFT.amplitude,
                     help=f"peak baseline drift, strain; 0 for none (default {DEFAULT_DRIFT.amplitude})")
    dev.add_argument("--hysteresis", type=float, default=DEFAULT_HYSTERESIS.fraction,
                     help="fraction of a released strain kept by the rubber, decaying with tau "
                     f"{DEFAULT_HYSTERESIS.tau_s} s; 0 for none (default {DEFAULT_HYSTERESIS.fraction})")
    dev.add_argument("--baud", type=int, default=1_000_000,
                     help="with --serial: baud rate (default 1000000; a 1 kHz 8x8 stream needs ~1.6 Mbaud)")
    from tactiled.commands import shear

    shear.add_arguments(p)
    vendor = p.add_argument_group(
        "vendor device mode: stream the scene as a lab's sensor does (docs/howto/drivers.md)")
    vendor.add_argument("--as", dest="as_kind", metavar="KIND",
                        help="lines, flexitac, robotiq (a pty) or xela (a WebSocket server)")
    vendor.add_argument("--device", metavar="PATH_OR_PORT",
                        help="with --as: the pty's symlink path, or xela's port on 127.0.0.1 (0: any)")


def _draw(rng: np.random.Generator, lo_hi: tuple[float, float], log: bool = False) -> float:
    lo, hi = lo_hi
    if lo == hi:
        return lo
    if log and lo > 0:
        return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    return float(rng.uniform(lo, hi))


def finger_spec(args: argparse.Namespace) -> FingerSpec:
    """The finger the flags describe, departing from the --sensor description's cover (the
    paper's finger when none is given); ValueError naming the flag for a bad value."""
    given = {k: getattr(args, k) for k in FingerSpec.PARAMS if getattr(args, k, None) is not None}
    try:
        return FingerSpec.from_params(given, description(args).sensor_model())
    except ValueError as err:
        raise ValueError(f"the simulated finger: {err}") from None


def description(args: argparse.Namespace) -> SensorDescription:
    """The simulated array (--sensor; default the paper's finger): ConfigError naming the key
    of a bad description."""
    return load_description(getattr(args, "sensor", None))


def sensor_geometry(args: argparse.Namespace) -> Geometry:
    """The simulated array's geometry, the one place every mode takes it from."""
    return description(args).geometry()


def _run_presses(args: argparse.Namespace) -> int:
    """Presses mode: a press file of known contacts on the finger the flags describe."""
    from tactiled.calibration.presses import synthesize_contact_presses
    from tactiled.io.presses import save_presses

    if args.presses < 1:
        return _error(f"--presses must be at least 1, got {args.presses}")
    if not 0 <= args.sensor_id <= 0xFFFF:
        return _error(f"--sensor-id must lie in 0..65535, got {args.sensor_id}")
    sigma = NoiseModel.sigma if args.sigma is None else args.sigma
    if not (math.isfinite(sigma) and sigma >= 0):
        return _error(f"--sigma must be a finite non-negative strain, got {sigma}")
    try:
        finger = finger_spec(args)
    except ValueError as err:
        return _error(str(err))
    geo = sensor_geometry(args)
    presses = synthesize_contact_presses(finger, args.presses, geometry=geo, noise_sigma=sigma,
                                         sensor_id=args.sensor_id, seed=args.seed)
    save_presses(presses, args.output)
    loaded = int((presses.contacts[:, 3] > 0).sum())
    print(f"wrote {len(presses)} press(es) ({loaded} loaded) of sensor {args.sensor_id}, "
          f"{geo.rows}x{geo.cols}, to {args.output}", file=sys.stderr)
    return 0


def _error(message: str) -> int:
    print(f"tactiled simulate: error: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    if args.as_kind or args.device:
        if args.output or args.pty or args.serial:
            return _error("--as/--device is a device of its own: no output file, --pty or --serial")
        from tactiled.commands.simulate_as import run as run_vendor_device

        return run_vendor_device(args)
    if args.pty or args.serial:
        if args.output:
            return _error(f"give either an output file ({args.output}) or --pty/--serial, not both")
        return _run_device(args)
    if args.link:
        return _error("--link needs --pty")
    if not args.output:
        return _error("give an output .npz file, or --pty / --serial to act as a device")
    check_output(args.output)  # before the work: a refusal to save it comes first, not last
    if args.presses is not None:
        return _run_presses(args)
    try:
        desc = description(args)
    except TactiledError as err:
        return _error(str(err))
    if desc.axes == 3:  # x, y, z per taxel: tangential loads (docs/concepts/shear.md)
        from tactiled.commands import shear

        return shear.simulate(args, desc)
    if args.sigma is None:
        args.sigma = FILE_SIGMA
    if args.frames < 1:
        print("tactiled simulate: error: --frames must be at least 1", file=sys.stderr)
        return 2
    try:
        noise = NoiseModel(sigma=args.sigma, quantum=args.quantum)
    except ValueError as err:
        print(f"tactiled simulate: error: {err}", file=sys.stderr)
        return 2
    try:
        finger = finger_spec(args)
    except ValueError as err:
        return _error(str(err))
    geo = sensor_geometry(args)
    sensor = finger.sensor(geo, noise)
    x_rng = args.x or (geo.span_x / 2, geo.span_x / 2)
    y_rng = args.y or (geo.span_y / 2, geo.span_y / 2)
    rng = np.random.default_rng(args.seed)
    contacts: list[Contact | None] = []
    truth = {k: np.full(args.frames, np.nan) for k in ("true_r1", "true_r2", "true_angle", "true_force", "true_x", "true_y")}
    for i in range(args.frames):
        if rng.uniform() < args.empty:
            contacts.append(None)
            continue
        r1 = _draw(rng, args.r1, log=True)
        r2 = r1 if args.sphere else _draw(rng, args.r2, log=True)
        if r2 < r1:
            r1, r2 = r2, r1
        try:
            c = Contact(r1, r2, _draw(rng, args.angle) % 180.0, _draw(rng, args.force), _draw(rng, x_rng), _draw(rng, y_rng))
        except ValueError as err:
            print(f"tactiled simulate: error: {err}", file=sys.stderr)
            return 2
        contacts.append(c)
        for k, v in zip(truth, (c.r1, c.r2, c.psi_deg, c.force, c.x0, c.y0)):
            truth[k][i] = v
    try:
        strain = simulate_frames(contacts, sensor, noise, seed=args.seed) * finger.gains(geo)
    except ValueError as err:
        print(f"tactiled simulate: error: {err}", file=sys.stderr)
        return 2
    if geo.flat:  # a cylinder on a flat array is a line: its load per length is the truth
        truth["true_load_n_per_mm"] = np.where(np.isinf(truth["true_r2"]),
                                               truth["true_force"] / line_length(geo), np.nan)
    save_frame_file(args.output, strain, geo.dx, geo.dy, **truth,
                    noise_sigma=np.float64(noise.sigma), noise_quantum=np.float64(noise.quantum),
                    sensor=np.str_(description(args).name))
    print(f"wrote {args.frames} frame(s) of {geo.rows}x{geo.cols} to {args.output}", file=sys.stderr)
    return 0


# --------------------------------------------------------------------------------------------
# Device mode


def _run_device(args: argparse.Namespace) -> int:
    if args.link and not args.pty:
        return _error("--link needs --pty")
    if args.link:
        check_output(args.link)  # a link in a directory that does not exist: one line, now
    if not (math.isfinite(args.rate) and 0 < args.rate <= 100_000):
        return _error(f"--rate must be a frame rate in Hz in (0, 100000], got {args.rate!r}")
    if args.seed < 0:
        return _error(f"--seed must be >= 0, got {args.seed}")
    from tactiled.sim.shear import SEQUENCES

    if args.scene in SEQUENCES:  # 3-axis frames (version 2 on the wire) of a tangential scene
        try:
            scenes = TaxelScenes(description(args), args.scene, args.seed, args.rate,
                                 sensor_id=args.sensor_id)
        except (ValueError, TactiledError) as err:
            return _error(str(err))
        return until_signal(lambda stop: _serve(args, scenes, stop))
    try:
        finger = finger_spec(args)
        sim = FingerSimulator(
            description(args).sensor_model(),
            finger=finger,
            scene=args.scene,
            seed=args.seed,
            rate_hz=args.rate,
            noise=args.sigma,
            drift=DriftModel(amplitude=args.drift) if args.drift else None,
            hysteresis=HysteresisModel(fraction=args.hysteresis) if args.hysteresis else None,
            sensor_id=args.sensor_id,
            loop=True,
        )
    except ValueError as err:
        return _error(str(err))

    return until_signal(lambda stop: _serve(args, sim, stop))


def _serve(args: argparse.Namespace, sim: FingerSimulator | TaxelScenes,
           stop: list[int]) -> int:
    """Open the device, stream until ``stop`` is non-empty, close the device."""
    port = None
    if args.pty:
        try:
            fd, name = make_pty(args.link)
        except OSError as err:
            return _error(f"cannot create the pty{' link ' + args.link if args.link else ''}: {err}")
        print(f"pty: {name}", flush=True)
        if args.link:
            print(f"link: {args.link}", flush=True)
    else:
        import serial  # only this mode needs pyserial

        name = args.serial
        try:
            # pyserial opens the device O_NONBLOCK; we write to its descriptor directly because
            # Serial.write with write_timeout=0 spins on EAGAIN instead of returning.
            port = serial.Serial(name, baudrate=args.baud, timeout=0)
        except (serial.SerialException, OSError, ValueError) as err:
            return _error(f"cannot open serial port {name}: {err}")
        fd = port.fileno()

    writer = FrameWriter(fd, name)
    schedule = FrameSchedule(args.rate, time.monotonic(), MAX_LAG_S)
    print(f"tactiled simulate: streaming scene {args.scene!r} at {args.rate:g} Hz to {name}; "
          "stop with Ctrl-C or SIGTERM", file=sys.stderr)
    try:
        while not stop:
            skip, send = schedule.take(time.monotonic(), MAX_BATCH)
            if skip:
                sim.skip(skip)
            for _ in range(send):
                writer.send(encode_frame(sim.next_frame()))
            writer.flush()
            delay = schedule.next_due() - time.monotonic()
            if delay > 0:
                time.sleep(min(delay, 0.05))  # short: a signal is noticed within 50 ms
    finally:
        if port is not None:
            port.close()
        else:
            os.close(fd)
            remove_link(args.link, name)
    print(f"tactiled simulate: sent {writer.sent} frame(s), dropped {writer.dropped} "
          f"(device full), skipped {schedule.skipped} (behind schedule)", file=sys.stderr)
    return 0

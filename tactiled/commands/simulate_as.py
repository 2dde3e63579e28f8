"""``tactiled simulate --as KIND --device PATH_OR_PORT``: a simulated vendor device.

The scene simulator renders frames on the device's array (:func:`tactiled.sensors.devices.device_array`:
its shape, pitch and nominal counts scaling) and streams them in the vendor's own format, so
``tactiled run`` and ``tactiled record`` can be tried on each driver without hardware:

``--sensor NAME|FILE.toml`` plays another array on the device: any shape for ``lines`` and
``flexitac`` (the daemon's URL then gives ``rows`` and ``cols``), 4x6 for ``xela``.

- ``lines``, ``flexitac``, ``robotiq``: a pseudo-terminal in raw mode; ``--device PATH`` is made a
  symlink to it.  Prints ``pty: /dev/pts/N`` and ``link: PATH``.  The Robotiq device streams both
  fingers, and only between the auto-send command that starts it and the one that stops it, as
  the sensor does.
- ``paxini``: a pseudo-terminal as for the serial devices, answering each distributed-force
  request (:func:`tactiled_drivers.paxini.request`) with the newest rendered frame, as the PX-6AX
  module answers its host (it sends nothing unasked).  With ``--scene push``, ``twist`` or
  ``pull`` every point's x, y and z follow the 3-axis model on ``paxini_px6ax`` (or
  ``--sensor``), as for ``xela``.
- ``xela``: a WebSocket server on 127.0.0.1 (``--device PORT``, 0 for any free port) speaking as
  ``xela_server`` does (a welcome message, then one message per tick with sensors 1 and 2).
  Prints ``xela: ws://127.0.0.1:PORT``.  With ``--scene push``, ``twist`` or ``pull`` (the
  tangential scenes of :mod:`tactiled.sim.shear`) every taxel's x, y and z follow the 3-axis model
  on ``xela_uskin_4x4`` or ``--sensor`` (sensor 1; sensor 2 rests): 300 frames at rest, then the scene, looped
  with a new sphere each time.

Runs until SIGINT/SIGTERM.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from tactiled.sensors.devices import KINDS, DeviceArray, device_array
from tactiled.errors import TactiledError
from tactiled.commands.device_stream import MAX_BATCH, MAX_LAG_S, FrameWriter, make_pty, remove_link, until_signal
from tactiled.sim import DriftModel, FingerSimulator, FrameSchedule, HysteresisModel

#: XELA magnetic taxels: x and y counts at rest (mid-range of 16 bits), and their wobble.
XELA_REST = 0x8000
XELA_SHEAR_SD = 40.0


#: kind -> the array shapes its device can have, None: any (the URL's rows and cols say)
SHAPES: dict[str, tuple[tuple[int, int], ...] | None] = {
    "lines": None, "flexitac": None, "robotiq": ((7, 4),), "xela": ((4, 4), (4, 6))}
#: kind -> the 3-axis array its tangential scenes (--scene push|twist|pull) play by default
TANGENTIAL_ARRAYS = {"xela": "xela_uskin_4x4", "paxini": "paxini_px6ax"}
#: XELA's model names, as xela_server sends them, by array shape
XELA_MODELS = {(4, 4): "XR1944", (4, 6): "XR1946"}


def simulated_array(args: argparse.Namespace) -> DeviceArray:
    """The ``--as`` device's array: its own built-in description's, or ``--sensor``'s when
    given (any shape for a text-lines pad or a FlexiTac mat, the shapes the device has
    otherwise: ValueError naming them)."""
    kind, name = args.as_kind, getattr(args, "sensor", None)
    if name is None:
        return device_array(kind)
    from tactiled.sensors import load_description

    desc = load_description(name)
    shapes = SHAPES[kind]
    if shapes is not None and (desc.rows, desc.cols) not in shapes:
        have = " or ".join(f"{r}x{c}" for r, c in shapes)
        raise ValueError(f"--sensor {desc.name} is {desc.rows}x{desc.cols}, but a {kind} "
                         f"device's array is {have}")
    array = device_array(kind, desc.rows, desc.cols)
    return replace(array, model=desc.sensor_model(), description=desc.name)


def simulators(args: argparse.Namespace, count: int) -> list[FingerSimulator]:
    """``count`` simulated arrays of the ``--as`` kind (seeds ``--seed``, ``--seed + 1``...)."""
    array = simulated_array(args)
    return [FingerSimulator(
        sensor=array.model, scene=args.scene, seed=args.seed + k, rate_hz=args.rate,
        noise=args.sigma,
        drift=DriftModel(amplitude=args.drift) if args.drift else None,
        hysteresis=HysteresisModel(fraction=args.hysteresis) if args.hysteresis else None,
        calibration=array.nominal_table(), sensor_id=0, loop=True) for k in range(count)]


def _error(message: str) -> int:
    print(f"tactiled simulate: error: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    """Serve the simulated device until a signal; exit 2 on bad arguments."""
    if args.as_kind not in KINDS:
        return _error(f"--as must be one of {', '.join(KINDS)}, got {args.as_kind!r}")
    if not args.device:
        return _error("--as needs --device (a path for the pty link, or a port for xela)")
    if not (math.isfinite(args.rate) and 0 < args.rate <= 10_000):
        return _error(f"--rate must be a frame rate in Hz in (0, 10000], got {args.rate!r}")
    if args.seed < 0:
        return _error(f"--seed must be >= 0, got {args.seed}")
    from tactiled.sim.shear import SEQUENCES

    if args.scene in SEQUENCES and args.as_kind not in TANGENTIAL_ARRAYS:
        return _error(f"--scene {args.scene} (a tangential scene) needs --as xela or paxini")
    try:
        sims = ([] if args.scene in SEQUENCES
                else simulators(args, 2 if args.as_kind in ("robotiq", "xela") else 1))
        if args.scene in SEQUENCES:
            args.taxel_scenes = _taxel_scenes(args, TANGENTIAL_ARRAYS[args.as_kind])
    except (ValueError, TactiledError) as err:
        return _error(str(err))

    serve = _serve_xela if args.as_kind == "xela" else _serve_pty
    return until_signal(lambda stop: serve(args, sims, stop))


# --------------------------------------------------------------------------------------------
# Serial devices on a pty


def _encoder(kind: str, sims: list[FingerSimulator]) -> Callable[[], bytes]:
    """One tick of the device as its bytes."""
    if kind == "lines":
        from tactiled_drivers.lines import encode as encode_line

        return lambda: encode_line(sims[0].next_frame().raw)
    if kind == "flexitac":
        from tactiled_drivers.flexitac import encode as encode_flexitac

        return lambda: encode_flexitac(np.clip(sims[0].next_frame().raw, 0, 255))
    from tactiled_drivers.robotiq import encode_finger

    def robotiq() -> bytes:
        out = b""
        for finger, sim in enumerate(sims):
            frame = sim.next_frame()
            t_ms = frame.device_time_us // 1000
            # gravity on the accelerometer's y axis, as Robotiq's own simulator puts it
            out += encode_finger(finger, frame.raw, dynamic=int(frame.raw.sum()) % 2000 - 1000,
                                 accelerometer=(0, 4096, 0), timestamp_ms=t_ms)
        return out

    return robotiq


class _AutoSend:
    """The Robotiq device's side of the auto-send command: streaming only between start and stop."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.streaming = False

    def hear(self, data: bytes) -> None:
        from tactiled_drivers.robotiq import COMMAND_AUTOSEND, START

        self.buf += data
        while True:
            start = self.buf.find(START)
            if start < 0 or len(self.buf) - start < 5:
                del self.buf[:max(0, start)]
                return
            if self.buf[start + 2] == COMMAND_AUTOSEND and self.buf[start + 3] == 1:
                self.streaming = self.buf[start + 4] != 0
            del self.buf[:start + 1]


def _serve_pty(args: argparse.Namespace, sims: list[FingerSimulator], stop: list[int]) -> int:
    try:
        fd, name = make_pty(args.device)
    except OSError as err:
        return _error(f"cannot create the pty link {args.device}: {err}")
    print(f"pty: {name}", flush=True)
    print(f"link: {args.device}", flush=True)
    writer = FrameWriter(fd, name)
    paxini = args.as_kind == "paxini"
    try:
        (_answer_paxini if paxini else _stream)(args, sims, stop, fd, writer)
    finally:
        os.close(fd)
        remove_link(args.device, name)
    what = "answered {} request(s)" if paxini else "sent {} frame(s)"
    print(f"tactiled simulate: {what.format(writer.sent)}, dropped {writer.dropped}",
          file=sys.stderr)
    return 0


def _stream(args: argparse.Namespace, sims: list[FingerSimulator], stop: list[int], fd: int,
            writer: Any) -> None:
    """Stream the device's frames at ``--rate`` until a signal (the Robotiq device only while
    auto-send is on)."""
    tick = _encoder(args.as_kind, sims)
    command = _AutoSend() if args.as_kind == "robotiq" else None
    schedule = FrameSchedule(args.rate, time.monotonic(), MAX_LAG_S)
    print(f"tactiled simulate: a {args.as_kind} device playing {args.scene!r} at {args.rate:g} Hz "
          f"on {args.device}; stop with Ctrl-C or SIGTERM", file=sys.stderr)
    while not stop:
        if command is not None:
            try:
                command.hear(os.read(fd, 4096))
            except (BlockingIOError, OSError):
                pass
        skip, send = schedule.take(time.monotonic(), MAX_BATCH)
        for sim in sims:
            if skip:
                sim.skip(skip)
        for _ in range(send):
            data = tick()
            if command is None or command.streaming:
                writer.send(data)
        writer.flush()
        delay = schedule.next_due() - time.monotonic()
        if delay > 0:
            time.sleep(min(delay, 0.05))


def _taxel_scenes(args: argparse.Namespace, default: str) -> Any:
    """The tangential scene of ``--scene`` on ``--sensor`` (default: ``default``), a
    :class:`~tactiled.sim.taxel_stream.TaxelScenes` (ValueError: a 1-axis array, or a shape
    the device does not have)."""
    from tactiled.sensors import load_description
    from tactiled.sim.taxel_stream import TaxelScenes

    desc = load_description(getattr(args, "sensor", None) or default)
    shapes = SHAPES.get(args.as_kind)
    if shapes is not None and (desc.rows, desc.cols) not in shapes:
        have = " or ".join(f"{r}x{c}" for r, c in shapes)
        raise ValueError(f"--sensor {desc.name} is {desc.rows}x{desc.cols}, but a "
                         f"{args.as_kind} device's array is {have}")
    return TaxelScenes(desc, args.scene, args.seed)


def paxini_readings(readings: np.ndarray) -> np.ndarray:
    """A PX-6AX answer's points ``(n, 3)`` from 3-axis readings ``(rows, cols, 3)`` (0.1 N
    steps): x and y signed bytes, z an unsigned byte, rounded and clipped as the module sends
    them."""
    pts = np.round(np.asarray(readings, dtype=float).reshape(-1, 3))
    return np.column_stack([np.clip(pts[:, :2], -128, 127), np.clip(pts[:, 2], 0, 255)]
                           ).astype(np.int64)


def paxini_points(raw: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A PX-6AX answer's points ``(n, 3)`` from a rendered frame of counts: z the counts less
    the 0x8000 offset (0..255), x and y a small signed wobble."""
    from tactiled_drivers.paxini import ZERO_COUNTS

    z = np.clip(raw.astype(np.int64).reshape(-1) - ZERO_COUNTS, 0, 255)
    xy = np.clip(rng.normal(0.0, 1.0, (z.size, 2)).round(), -128, 127).astype(np.int64)
    return np.column_stack([xy, z])


def _answer_paxini(args: argparse.Namespace, sims: list[FingerSimulator], stop: list[int],
                   fd: int, writer: Any) -> None:
    """Answer requests on the pty until a signal: each one with the newest frame (rendered at
    ``--rate``)."""
    import select

    from tactiled_drivers.paxini import request, response

    rng = np.random.default_rng(args.seed)
    scenes = getattr(args, "taxel_scenes", None)  # a tangential scene: x, y, z of the 3-axis model
    if scenes is not None:
        def tick() -> np.ndarray:
            return paxini_readings(scenes.next_readings())
        skip_frames, points = scenes.skip, scenes.desc.rows * scenes.desc.cols
    else:
        def tick() -> np.ndarray:
            return paxini_points(sims[0].next_frame().raw, rng)
        g = sims[0].sensor.geometry
        skip_frames, points = sims[0].skip, g.rows * g.cols
    asked = request(0, points)
    schedule = FrameSchedule(args.rate, time.monotonic(), MAX_LAG_S)
    heard = bytearray()
    latest = tick()
    print(f"tactiled simulate: a paxini module playing {args.scene!r} at {args.rate:g} Hz on "
          f"{args.device}; stop with Ctrl-C or SIGTERM", file=sys.stderr)
    while not stop:
        skip, send = schedule.take(time.monotonic(), MAX_BATCH)
        if skip:
            skip_frames(skip)
        for _ in range(send):
            latest = tick()
        if select.select([fd], [], [], 0.01)[0]:
            try:
                heard += os.read(fd, 4096)
            except (BlockingIOError, OSError):
                pass
        while (k := heard.find(asked)) >= 0:
            del heard[:k + len(asked)]
            writer.send(response(0, latest))
        del heard[:max(0, len(heard) - len(asked))]
        writer.flush()


# --------------------------------------------------------------------------------------------
# XELA: a WebSocket server


def _serve_xela(args: argparse.Namespace, sims: list[FingerSimulator], stop: list[int]) -> int:
    text = str(args.device)
    host, _, port_text = text.rpartition(":")
    if not port_text.isdigit() or not 0 <= int(port_text) < 65536:
        return _error(f"--device for xela is a port (or 127.0.0.1:PORT), got {text!r}")
    if host not in ("", "127.0.0.1", "localhost"):
        return _error(f"the simulated xela_server listens on 127.0.0.1 only, got {host!r}")
    return asyncio.run(_xela_main(args, sims, int(port_text), stop))


async def _xela_main(args: argparse.Namespace, sims: list[FingerSimulator], port: int,
                     stop: list[int]) -> int:
    from websockets.asyncio.server import broadcast, serve

    from tactiled_drivers.xela import WELCOME, message

    clients: set = set()
    rng = np.random.default_rng(args.seed)
    scenes = getattr(args, "taxel_scenes", None)  # a tangential scene, or the scene simulator's
    shape = ((scenes.desc.rows, scenes.desc.cols) if scenes is not None
             else (sims[0].sensor.geometry.rows, sims[0].sensor.geometry.cols))
    model = XELA_MODELS[shape]

    async def handler(ws) -> None:  # noqa: ANN001 (a websockets connection)
        await ws.send(WELCOME)
        clients.add(ws)
        try:
            await ws.wait_closed()
        finally:
            clients.discard(ws)

    async with serve(handler, "127.0.0.1", port) as server:
        bound = server.sockets[0].getsockname()[1]
        print(f"xela: ws://127.0.0.1:{bound}", flush=True)
        print(f"tactiled simulate: a xela_server playing {args.scene!r} at {args.rate:g} Hz on "
              f"ws://127.0.0.1:{bound}; stop with Ctrl-C or SIGTERM", file=sys.stderr)
        schedule = FrameSchedule(args.rate, time.monotonic(), MAX_LAG_S)
        number = 0
        while not stop:
            skip, send = schedule.take(time.monotonic(), MAX_BATCH)
            for _ in range(send):
                sensors = ({} if scenes is None else
                           {1: (model, scenes.next_counts()), 2: (model, scenes.resting())})
                for k, sim in enumerate(sims):
                    if skip:
                        sim.skip(skip)
                    z = sim.next_frame().raw.astype(np.int64)
                    shear = rng.normal(XELA_REST, XELA_SHEAR_SD, (2, *z.shape)).round()
                    xyz = np.stack([shear[0], shear[1], z], axis=-1).clip(0, 0xFFFF)
                    sensors[k + 1] = (model, xyz)
                number += 1
                broadcast(clients, message(number, sensors, time.time()))
                skip = 0
            delay = schedule.next_due() - time.monotonic()
            await asyncio.sleep(min(max(delay, 0.0), 0.05))
    return 0

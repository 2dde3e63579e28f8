"""Record the frames of a frame source to a recording file (docs/reference/file-formats.md).

Every frame the source delivers intact is written with its host receive time; corrupt wire
data is dropped by the decoder and counted in the summary.  Stops after --seconds or --frames,
at the end of the stream, or on Ctrl-C / SIGTERM; the file is flushed and fsync'ed either way.

examples:
  tactiled record serial:///dev/ttyACM0 -o session.tact --seconds 60
  tactiled record 'sim://?scene=demo&seed=1' -o demo.tact --seconds 5
  tactiled replay demo.tact
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
import sys
import time
from pathlib import Path

from tactiled.errors import TactiledError
from tactiled.io.files import check_output
from tactiled.io.recording import Recorder
from tactiled.sources import FrameSource, open_source


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("url", metavar="URL",
                   help="frame source: serial:///dev/ttyACM0, sim://?scene=demo, replay://FILE")
    p.add_argument("-o", "--output", required=True, metavar="FILE",
                   help="recording to write (refused if it exists, unless --append)")
    p.add_argument("--seconds", type=float, default=None, metavar="S",
                   help="stop after S seconds (default: until the stream ends or Ctrl-C)")
    p.add_argument("--frames", type=int, default=None, metavar="N", help="stop after N frames")
    p.add_argument("--append", action="store_true",
                   help="continue an existing recording of the same sensor")


async def _record(source: FrameSource, path: Path, args: argparse.Namespace) -> tuple[int, float]:
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    recorder: Recorder | None = None
    count = 0
    start = time.monotonic()

    async def pump() -> None:
        nonlocal recorder, count
        async with contextlib.aclosing(source.frames()) as frames:
            async for frame in frames:
                if recorder is None:  # the file header needs the sensor id of the frames
                    device = source.device_array()  # a vendor device: replayed as it reads
                    recorder = Recorder(path, sensor_id=frame.sensor_id, append=args.append,
                                        device=None if device is None else device.kind)
                recorder.record(frame)
                count += 1
                if args.frames is not None and count >= args.frames:
                    return

    await source.open()
    try:
        pump_task = asyncio.create_task(pump())
        stop_task = asyncio.create_task(stop.wait())
        done, _ = await asyncio.wait({pump_task, stop_task}, timeout=args.seconds,
                                     return_when=asyncio.FIRST_COMPLETED)
        for task in (pump_task, stop_task):
            task.cancel()
        await asyncio.gather(pump_task, stop_task, return_exceptions=True)
        if pump_task in done and pump_task.exception() is not None:
            raise pump_task.exception()  # type: ignore[misc]
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.remove_signal_handler(sig)
        await source.close()
        if recorder is not None:
            recorder.close()
    return count, time.monotonic() - start


def run(args: argparse.Namespace) -> int:
    if args.seconds is not None and not args.seconds > 0:
        print("tactiled record: error: --seconds must be positive", file=sys.stderr)
        return 2
    if args.frames is not None and args.frames < 1:
        print("tactiled record: error: --frames must be at least 1", file=sys.stderr)
        return 2
    try:
        path = check_output(args.output)
    except TactiledError as err:
        print(f"tactiled record: error: {err}", file=sys.stderr)
        return 2
    if path.exists() and not args.append:
        print(f"tactiled record: error: {path} exists (use --append to continue it)",
              file=sys.stderr)
        return 2
    try:
        source = open_source(args.url)
    except (ValueError, TactiledError) as err:
        print(f"tactiled record: error: {err}", file=sys.stderr)
        return 2
    try:
        count, elapsed = asyncio.run(_record(source, path, args))
    except (TactiledError, OSError) as err:
        print(f"tactiled record: error: {err}", file=sys.stderr)
        return 2
    d = source.decoder.stats
    print(f"recorded {count} frame(s) in {elapsed:.1f} s to {path} (corrupt chunks "
          f"{d.rejected}, crc errors {d.crc_errors}, lost {d.lost}, duplicated {d.duplicated})",
          file=sys.stderr)
    return 0

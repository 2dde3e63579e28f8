"""Run a recording through the acquisition pipeline; print one JSON estimate per line.

Each line is an estimate as the daemon publishes it: "type": "estimate", sensor, sensor_id,
seq, device_time_us, host_time, time, latency_ms, worker_ms, gate ("fit", "no_contact",
"unchanged"), fitted_seq, then the keys of a `tactiled fit` line (contact, model, x_mm, y_mm,
force_n, r1_mm, r2_mm, angle_deg, rms, std, fit_ms, ...).

--mode lossless (the default) fits every frame the gate passes, waiting for each fit before
reading on, so two replays of one file print the same estimates; --no-timing drops the keys
that vary from run to run (host_time, time, latency_ms, worker_ms, fit_ms) so the output is
identical byte for byte.  --mode live behaves as the daemon does with a live sensor: while a
fit runs, newer frames replace the waiting one (latest frame wins), so what is fitted depends
on timing.

examples:
  tactiled replay session.tact --speed 0 --no-timing > estimates.jsonl
  tactiled replay session.tact --speed 1 --mode live --model cylinder
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from pathlib import Path
from typing import Any
from urllib.parse import quote

from tactiled import native
from tactiled.errors import TactiledError
from tactiled.io.files import check_input
from tactiled.io.recording import RecordingReader
from tactiled.settings import MODELS, load_settings


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE", help="recording made by 'tactiled record'")
    p.add_argument("--speed", type=float, default=0.0, metavar="X",
                   help="pace: 1 = as recorded, 2 = twice as fast, 0 = as fast as possible "
                        "(default 0)")
    p.add_argument("--mode", choices=("lossless", "live"), default="lossless",
                   help="lossless: fit every frame the gate passes (default); live: latest "
                        "frame wins, as the daemon does")
    add_sensor_arguments(p, "replay", "sensor name in the output")
    p.add_argument("--zeroed-frames", action="store_true",
                   help="also print the zeroed frames (\"class\": \"frame\")")
    p.add_argument("--no-timing", action="store_true",
                   help="omit the keys that vary between runs (for diffing replays)")


def add_sensor_arguments(p: argparse.ArgumentParser, name: str, name_help: str) -> None:
    """The flags that say how a recording's sensor is fitted (replay and export share them)."""
    p.add_argument("--model", choices=MODELS, default="auto",
                   help="contact model (default auto: chosen per frame by BIC)")
    p.add_argument("--sensor", metavar="NAME|FILE.toml", default=None,
                   help="the recorded array: a built-in description or a description file "
                   "(docs/howto/sensors.md; default fearing1988, the paper's finger)")
    p.add_argument("--window", type=int, default=None, metavar="N",
                   help="fit window side in tactels (default: the description's, 4)")
    p.add_argument("--sigma", type=float, default=None,
                   help="strain noise of a tactel, 1 sigma (default: the description's, 0.0005)")
    p.add_argument("--calibration", default=None, metavar="FILE",
                   help="lookup-table file (default: the nominal linear table)")
    p.add_argument("--name", default=name, help=f"{name_help} (default {name})")


#: fit.timeout of a lossless replay, s (its fits' time budget is half of it).
LOSSLESS_FIT_TIMEOUT = 120.0


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    path = Path(args.file).resolve()
    speed = repr(float(args.speed))
    out: dict[str, Any] = {
        "sensor[0].name": args.name,
        "sensor[0].url": f"replay://{quote(str(path))}?speed={speed}",
        "sensor[0].model": args.model,
        "fit.workers": 1,
    }
    if args.mode == "lossless":
        # offline, every frame waits for its fit: no real-time budget, so the output depends
        # on the recording only, not on how fast (or how loaded) the machine is (a frame far
        # outside the model can take a second or more to fit)
        out["fit.timeout"] = LOSSLESS_FIT_TIMEOUT
    if args.window is not None:
        out["sensor[0].window"] = args.window
    if args.sigma is not None:
        out["sensor[0].noise_sigma"] = args.sigma
    if args.calibration is not None:
        out["sensor[0].calibration"] = args.calibration
    if getattr(args, "sensor", None) is not None:
        out["sensor[0].description"] = args.sensor
    return out


async def _replay(args: argparse.Namespace) -> dict[str, Any]:
    from tactiled.pipeline import Daemon, without_timing

    settings = load_settings(None, {}, _overrides(args))
    # a replay neither starts from nor overwrites what a live daemon learned of its finger
    daemon = Daemon(settings, lossless=args.mode == "lossless", keep_learned=False)
    out = sys.stdout

    def emit(item: Any) -> None:
        if item.kind == "frame" and not args.zeroed_frames:
            return
        line = item.to_json_dict()
        if args.no_timing:
            line = without_timing(line)
        out.write(json.dumps(line, allow_nan=False) + "\n")

    daemon.hub.add_listener(emit)
    await daemon.start()
    try:
        await daemon.wait_finished()
    finally:
        stats = daemon.stats(args.name)
        await daemon.stop()
    out.flush()
    return stats


def run(args: argparse.Namespace) -> int:
    try:
        # Every record's framing is checked now (seeking over the payloads: ~1 s per million
        # records), so a file corrupt in the middle is refused with one clear error before any
        # worker starts or any estimate is printed, instead of stopping half-way.
        with RecordingReader(check_input(args.file)) as reader:
            reader.scan()
    except OSError as err:
        print(f"tactiled replay: error: cannot open {args.file}: {err.strerror or err}",
              file=sys.stderr)
        return 2
    except TactiledError as err:
        print(f"tactiled replay: error: {err}", file=sys.stderr)
        return 2
    if not args.speed >= 0:
        print("tactiled replay: error: --speed must be >= 0", file=sys.stderr)
        return 2
    stats = asyncio.run(_replay(args))
    print(f"replayed {stats['frames']} frame(s): {stats['published']} estimates, "
          f"{stats['fitted']} fitted, skipped {stats['skipped']}, superseded "
          f"{stats['superseded']}, errors {stats['fit_errors'] + stats['errors']}, "
          f"core {native.name()}", file=sys.stderr)
    return 0

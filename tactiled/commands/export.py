"""Export a recording: its ROS 2 messages to MCAP, or its raw frames to npz.

-o OUT.mcap replays the recording through the pipeline exactly as `tactiled replay` does
(lossless: every frame the gate passes is fitted, so the output depends on the file only)
and writes what the daemon publishes on ROS 2 (docs/howto/ros2.md), as an MCAP file with the
ros2 profile that `ros2 bag play` replays and Foxglove opens:
  <namespace>/<sensor>/wrench    geometry_msgs/msg/WrenchStamped  every estimate (N, N*m)
  <namespace>/<sensor>/contact   tactiled_msgs/msg/Contact         every estimate
  <namespace>/<sensor>/markers   visualization_msgs/msg/MarkerArray every estimate
  <namespace>/<sensor>/strain    sensor_msgs/msg/Image (32FC1)     every zeroed frame
  <namespace>/<sensor>/taxels    sensor_msgs/msg/Image (32FC3)     a 3-axis array's zeroed
                                 readings (x, y, z channels), every zeroed frame
  /diagnostics                   diagnostic_msgs/msg/DiagnosticArray once a recorded second
Times are the recording's own: header stamps and log times are the file's creation time plus
each frame's recorded host time since the first frame.  latency_ms, worker_ms and fit_ms are
NaN (they would measure this machine, not the recording), so two exports of one file are
identical byte for byte.  Needs the ros2 extra (pip install 'tactiled[ros2]').

-o OUT.npz writes the raw frames as arrays, no pipeline: counts (N, rows, cols) uint16,
host_time_s (N,) float64 (the recorded monotonic host times), seq (N,) int64, sensor_id (N,)
int64 -- an input `tactiled fit --calibration CAL.json OUT.npz` reads.  A recording of a
3-axis array also gives taxel_counts (N, rows, cols, 3) uint16, the x, y, z counts as
received (counts holds z).

The output is never overwritten (an existing file is an error).  A progress bar goes to
stderr on a terminal.

examples:
  tactiled export session.tact -o session.mcap
  tactiled export session.tact -o session.npz
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tactiled import io
from tactiled.commands import replay
from tactiled.errors import ConfigError, TactiledError
from tactiled.io.files import check_input, check_output
from tactiled.frames import new_decoder
from tactiled.progress import Progress
from tactiled.io.recording import RecordingReader
from tactiled.settings import load_settings

if TYPE_CHECKING:
    from tactiled.pipeline.sensor_stats import SensorStats

FORMATS = (".mcap", ".npz")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE", help="recording made by 'tactiled record' or the daemon")
    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="output file: OUT.mcap (ROS 2 messages) or OUT.npz (raw frames)")
    replay.add_sensor_arguments(p, "finger0", "sensor name: the topics' <sensor>")
    p.add_argument("--namespace", default="/tactiled",
                   help="ROS namespace of the topics (default /tactiled, as [ros2] namespace)")
    p.add_argument("--frame-id", default="{sensor}",
                   help="header.frame_id; {sensor} is the sensor's name (default {sensor})")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bar on stderr (default: when stderr is a terminal)")


def _fail(message: str) -> int:
    print(f"tactiled export: error: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    out = Path(args.output)
    try:
        check_output(out)  # a directory, or one that does not exist: said now, not at the end
    except TactiledError as err:
        return _fail(str(err))
    if out.suffix.lower() not in FORMATS:
        return _fail(f"-o {args.output}: the output must end in .mcap or .npz")
    if out.exists():
        return _fail(f"-o {args.output}: exists (an export never overwrites a file)")
    try:
        with RecordingReader(check_input(args.file)) as reader:
            records = reader.scan()
            created = reader.header.created
            first = next(iter(reader), None)
    except OSError as err:
        return _fail(f"cannot open {args.file}: {err.strerror or err}")
    except TactiledError as err:
        return _fail(str(err))
    if first is None:
        return _fail(f"{args.file}: the recording holds no frame")
    progress = Progress(records, f"export {Path(args.file).name}", args.progress, unit="frames")
    if out.suffix.lower() == ".npz":
        n = export_npz(args.file, out, progress)
        print(f"exported {n} frame(s) to {out}", file=sys.stderr)
        return 0
    try:
        McapWriter = io.writer("messages", out)  # tactiled_service's, through its entry point
    except (ImportError, ValueError) as err:
        return _fail(f"writing MCAP needs the ros2 extra: pip install 'tactiled[ros2]' ({err})")
    try:
        settings = load_settings(None, {}, {**_overrides(args), "ros2.namespace": args.namespace})
    except ConfigError as err:
        return _fail(str(err))
    writer = McapWriter(out, namespace=settings.ros2.namespace, frame_id=args.frame_id)
    try:
        stats = asyncio.run(_export_mcap(settings, writer, created, first[0], progress))
    finally:
        writer.close()
    print(f"exported {stats['frames']} frame(s), {stats['published']} estimates: "
          f"{writer.messages} messages to {out}", file=sys.stderr)
    return 0


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    """Replay's settings (lossless, one worker), the frames stamped with their recorded host
    times (``clock=recorded``) so that the export does not depend on when it runs."""
    ns = argparse.Namespace(file=args.file, speed=0.0, model=args.model, mode="lossless",
                            window=args.window, sigma=args.sigma,
                            calibration=args.calibration, name=args.name, sensor=args.sensor)
    out = replay._overrides(ns)
    out["sensor[0].url"] += "&clock=recorded"
    return out


async def _export_mcap(settings: Any, writer: Any, created: float, t0: float,
                       progress: Progress) -> dict[str, Any]:
    """Replay through the pipeline into ``writer``; a recorded host time ``t`` is the Unix
    time ``created + (t - t0)`` (``t0``: the first frame's)."""
    from tactiled.pipeline import Daemon, without_timing

    daemon = Daemon(settings, lossless=True)
    name = settings.sensors[0].name
    hardware_ids = {name: settings.sensors[0].url}
    state = {"due": -np.inf, "errors": 0}  # next diagnostics' recorded time; errors so far

    def on_item(item: Any) -> None:
        stamp = created + (item.host_time - t0)
        if item.kind == "estimate":
            est = without_timing(item.to_json_dict(), blank=True)
            writer.write_estimate(est, stamp)
            return
        writer.write_zeroed(item, stamp)
        progress.step()
        if stamp >= state["due"]:
            state["due"] = stamp + 1.0
            writer.write_diagnostics(_health(daemon.sensor_stats(name), state), stamp,
                                     hardware_ids)

    daemon.hub.add_listener(on_item)
    await daemon.start()
    try:
        await daemon.wait_finished()
    finally:
        stats = daemon.stats(name)
        await daemon.stop()
    return stats


def _health(stats: SensorStats, state: dict[str, Any]) -> dict[str, Any]:
    """A health document from a replayed sensor's counters: WARN when frames were corrupt,
    lost or duplicated, or fits failed, since the previous one (the recording's own health;
    the daemon's timing rules -- silence, stale estimates -- mean nothing in a replay)."""
    counts = {"corrupt chunks": stats.decoded("crc_errors") + stats.decoded("length_errors"),
              "lost frames": stats.decoded("lost"),
              "duplicated frames": stats.decoded("duplicated"),
              "fit errors": stats.fit_errors}
    total = sum(counts.values())
    grew = total > state["errors"]
    state["errors"] = total
    reason = ", ".join(f"{n} {what}" for what, n in counts.items() if n) if grew else ""
    return {"sensors": {stats.sensor: {
        "status": "WARN" if grew else "OK",
        "reason": f"since start: {reason}" if reason else "",
        "frames": stats.frames, "published": stats.published}}}


def export_npz(path: str, out: Path, progress: Progress) -> int:
    """The raw frames of a recording into ``out`` (see the module docstring); the count."""
    decoder = new_decoder()
    counts, taxels, host_time, seq, sensor_id = [], [], [], [], []
    with RecordingReader(path) as reader:
        for t, data in reader:
            for frame in decoder.feed(data, t):
                counts.append(np.asarray(frame.raw))
                taxels.append(frame.taxels)
                host_time.append(t)
                seq.append(frame.seq)
                sensor_id.append(frame.sensor_id)
            progress.step()
    shape = counts[0].shape if counts else (0, 0)
    arrays = {"counts": np.stack(counts) if counts else np.zeros((0, *shape), np.uint16),
              "host_time_s": np.asarray(host_time, np.float64), "seq": np.asarray(seq, np.int64),
              "sensor_id": np.asarray(sensor_id, np.int64)}
    if counts and all(x is not None and x.shape == taxels[0].shape for x in taxels):
        arrays["taxel_counts"] = np.stack(taxels)  # a 3-axis array's x, y, z counts
    with open(out, "xb") as fh:
        np.savez_compressed(fh, **arrays)
    return len(counts)

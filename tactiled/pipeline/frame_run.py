"""A read's frames through the calibration stage in one call into the core, and the frames with
no contact published without the per-frame Python path (:meth:`SensorPipeline.on_frames`).
"""

# The run: CalibrationStage.process_run takes the read's frames (counts of this sensor, of the
# grid's shape) until the first in contact, in one call.  A frame with no contact while
# nothing waits for, or is in, a fit (the pipeline "quiet") changes nothing but counters: its
# zeroed frame and its "no contact" estimate are published here, the same records the
# per-frame path (``_after_stage``) publishes; a frame that is not quiet, and the contact frame
# that ends a run, take that path.  ``pipe.quiet_at``: the arrival number of the last frame
# after which the pipeline was quiet (any frame since through the per-frame path moves
# ``_ordinal`` past it; with nothing in a fit, no result can come back in between).  While a
# contact is tracked, the run goes on past contact (:mod:`.tracked_run`).  ``TACTILED_CORE=python`` (or
# ``SensorPipeline.batched = False``) runs every frame through the per-frame path, the
# reference the run is held to (tests/pipeline/test_frame_run.py).

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from tactiled.frames import Frame
from tactiled.pipeline import tracked_run
from tactiled.pipeline.estimate import GATE_NO_CONTACT, Estimate, published_stamp

if TYPE_CHECKING:
    from tactiled.pipeline.sensor import SensorPipeline

log = logging.getLogger(__name__)

#: Most frames one run takes: a read of more (after a stall) goes in several runs, so the
#: loop's other tasks get their turn between them (``SLICE_S``).
MAX_RUN = 64


def runnable(pipe: SensorPipeline, until_busy: bool) -> bool:
    """Whether the next frames of ``pipe`` can go through a run: the stage's compiled path
    applies, the counts arrive in grid order, no 3-axis shear to follow, and (``until_busy``:
    lossless replay, every frame waits for its fit) nothing is in a fit."""
    stage = pipe.stage
    return (stage is not None and pipe.shear is None and stage.can_run()
            and pipe.description.wire_order == "row-major"
            and (not until_busy or pipe._idle()))


def take_run(pipe: SensorPipeline, frames: Sequence[Frame], k: int, end: int, now: float,
             dispatch: bool) -> int:
    """Frames ``k`` to at most ``end`` of a read through one run (module comment); returns how
    many it took (0: the next frame takes the per-frame path)."""
    stage = pipe.stage
    assert stage is not None
    sid = stage.table.sensor_id
    shape = pipe._grid_shape
    times = stage.run_times  # (the device times, s: written here, read by the core)
    if len(times) < MAX_RUN:
        times = stage.run_times = np.empty(MAX_RUN)
    raws = []
    n = 0
    for f in frames[k:min(end, k + MAX_RUN)]:
        raw = f.raw
        if f.sensor_id != sid or raw.shape != shape or raw.dtype.kind not in "ui":
            break
        raws.append(raw)
        times[n] = f.device_time_us * 1e-6
        n += 1
    if not n:
        return 0
    run = frames[k:k + n]
    z = np.empty((n, *shape))
    track = tracked_run.plan(pipe) if stage.zeroer.in_contact else None  # (plan needs it)
    try:
        taken, statistic, peak = stage.process_run(raws, times, z, track)
    except Exception:  # a bug must not stop the sensor: its frames take the per-frame path
        pipe.batched = False
        pipe.errors += 1
        log.exception("%s: the core's run failed; per-frame path from now on", pipe.name)
        return 0
    if not taken:
        return 0
    z.setflags(write=False)
    if track is not None:  # a tracked contact's run (tactiled.pipeline.tracked_run)
        track.publish(pipe, run, z, statistic, peak, taken, now, dispatch)
        return taken
    # the frames before the one in contact, if any: quiet ones published together
    last = taken - 1 if stage.zeroer.in_contact else taken
    quiet = pipe.quiet_at == pipe._ordinal and pipe._idle() and not pipe.tracking.pending
    i = 0
    while i < taken:
        if quiet and i < last:
            _publish_quiet(pipe, run, z, statistic, i, last)
            i = last
            continue
        frame = run[i]
        strain = tracked_run.took(pipe, frame, z[i])
        contact = i == last
        pipe._guarded(frame, dispatch, pipe._after_stage, frame, strain, contact, False, now,
                      statistic[i], peak[i])
        quiet = not contact and pipe._idle() and not pipe.tracking.pending
        if quiet:
            pipe.quiet_at = pipe._ordinal
        i += 1
    return taken


def _publish_quiet(pipe: SensorPipeline, run: Sequence[Frame], z: np.ndarray,
                   statistic: list[float], i: int, end: int) -> None:
    """Frames ``i`` to ``end`` of a run, with no contact after another, nothing waiting for or
    in a fit: what ``_after_stage`` does then (contact ended already, ids cleared, the gate
    reset), less the steps that change nothing a second time; the counters moved once."""
    hub, name, fit, record = pipe.hub, pipe.name, pipe._no_contact_fit, pipe.record_path
    ordinal = pipe._ordinal
    for j in range(i, end):
        frame = run[j]
        if record is not None:
            pipe._record(frame)
        frame.strain = strain = z[j]
        sensor_id, seq, device_us, host, stamp = (frame.sensor_id, frame.seq,
                                                  frame.device_time_us, frame.host_time,
                                                  frame.time)
        hub.publish_frame(name, sensor_id, seq, device_us, host, False, statistic[j], strain,
                          stamp)
        ordinal += 1
        pipe._send(Estimate(name, sensor_id, seq, device_us, host, time.monotonic(),
                            published_stamp(stamp), GATE_NO_CONTACT, None, 0.0, fit), ordinal)
    pipe.frames += end - i
    pipe.skipped[GATE_NO_CONTACT] += end - i
    pipe._ordinal = pipe.quiet_at = ordinal

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
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from tactiled.frames import Frame
from tactiled.pipeline import tracked_run
from tactiled.pipeline.estimate import GATE_NO_CONTACT, make_estimate, make_zeroed_frame

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
    raws = []
    for j in range(k, min(end, k + MAX_RUN)):
        f = frames[j]
        raw = f.raw
        if f.sensor_id != sid or raw.shape != shape or raw.dtype.kind not in "ui":
            break
        raws.append(raw)
    n = len(raws)
    if not n:
        return 0
    run = frames[k:k + n]
    times = np.fromiter((f.device_time_us for f in run), float, n) * 1e-6
    z = np.empty((n, *shape))
    track = tracked_run.plan(pipe)
    try:
        taken, stats, peaks = stage.process_run(raws, times, z, track)
    except Exception:  # a bug must not stop the sensor: its frames take the per-frame path
        pipe.batched = False
        pipe.errors += 1
        log.exception("%s: the core's run failed; per-frame path from now on", pipe.name)
        return 0
    if not taken:
        return 0
    z.setflags(write=False)
    if track is not None:  # a tracked contact's run (tactiled.pipeline.tracked_run)
        track.publish(pipe, run, z, stats.tolist(), peaks.tolist(), taken, now, dispatch)
        return taken
    ends_in_contact = stage.zeroer.in_contact
    statistic, peak = stats.tolist(), peaks.tolist()
    quiet = pipe.quiet_at == pipe._ordinal and pipe._idle() and not pipe.tracking.pending
    for i in range(taken):
        frame = run[i]
        strain = tracked_run.took(pipe, frame, z[i])
        contact = ends_in_contact and i == taken - 1
        if quiet and not contact:
            _publish_quiet(pipe, frame, strain, statistic[i])
            continue
        pipe._guarded(frame, dispatch, pipe._after_stage, frame, strain, contact, False, now,
                      statistic[i], peak[i])
        quiet = not contact and pipe._idle() and not pipe.tracking.pending
        if quiet:
            pipe.quiet_at = pipe._ordinal
    return taken


def _publish_quiet(pipe: SensorPipeline, frame: Frame, strain: np.ndarray,
                   statistic: float) -> None:
    """A frame with no contact after another, nothing waiting for or in a fit: what
    ``_after_stage`` does then (contact ended already, ids cleared, the gate reset), less the
    steps that change nothing a second time."""
    pipe._ordinal = pipe.quiet_at = pipe._ordinal + 1
    pipe.hub.publish(make_zeroed_frame(
        sensor=pipe.name, sensor_id=frame.sensor_id, seq=frame.seq,
        device_time_us=frame.device_time_us, host_time=frame.host_time, contact=False,
        statistic=statistic, strain=strain, stamp=frame.time))
    pipe.skipped[GATE_NO_CONTACT] += 1
    pipe._send(make_estimate(
        sensor=pipe.name, sensor_id=frame.sensor_id, seq=frame.seq,
        device_time_us=frame.device_time_us, host_time=frame.host_time, gate=GATE_NO_CONTACT,
        fitted_seq=None, worker_ms=0.0, fit=pipe._no_contact_fit, stamp=frame.time),
        pipe._ordinal)

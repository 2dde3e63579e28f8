"""A tracked contact's frames through one core call, and their estimates published from its
arrays (:func:`plan`, called by :func:`tactiled.pipeline.frame_run.take_run`)."""

# While a sensor's contact is tracked (the tracker holds a linearisation and an estimate,
# no frame waits for a fit, nothing but a relinearisation is in one), the next frames of a read
# go through ``_core.track_run`` (core/track_run.cpp) in one call: each through the calibration
# stage (the stage's ZeroRun), the tests ContactTracking.track makes before a step, each
# contact's TrackStep and the estimate's numbers.  The state stays in the core objects that
# hold it between frames (the stage's ZeroRun, each Tracker's TrackStep); Python then keeps
# per frame what the per-frame path keeps (the tracker's time and frame counts) and publishes
# the zeroed frame and the estimate (``Tracker.estimate_from``: the rules that withhold a value
# stay in Python).  The run stops at the first frame whose path differs, zeroed but not
# stepped, and hands it to ``SensorPipeline._after_stage`` (the per-frame path): the contact
# ended, another pressed (``ContactTracking._pressed_elsewhere``), the signal grown
# (``_signal_grown``), a step that is not "tracked" (refit, restart, a jump; undone in the
# core), the residuals' fold due (``Tracker._fold``).  After a tracked frame the zeroer's drift
# step follows (``follow_drift``, every ``DRIFT_STEP_S``), or whose state wants a
# relinearisation, the run ends and Python does what ``ContactTracking.track`` does then.  Several contacts go through it when no window overlaps
# another (otherwise each frame's windows move with the others' states: the per-frame path).

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from tactiled import native
from tactiled.calibration.zeroing import DRIFT_STEP_S
from tactiled.frames import Frame
from tactiled.pipeline.contact_filter import MEAN_RESIDUAL_FOLD, RELINEARIZE_SIGMA, SHARPEN
from tactiled.pipeline.estimate import GATE_UNCHANGED
from tactiled.pipeline.sensor_tracking import MIN_RELINEARIZE_S, REFIT_SIGNAL_RATIO, _Waiting

if TYPE_CHECKING:
    from tactiled.pipeline.sensor import SensorPipeline

#: why a run ended (core/track_run.cpp's Stop, in order): the read ran out; a frame the
#: compiled path does not take; then a frame zeroed but left to the per-frame path: the
#: contact ended, the residuals' fold due, another contact pressed, the signal grown, a
#: frame a contact cannot measure, a step not "tracked"; last, a tracked frame after which
#: the zeroer's drift step is due, or whose state wants a relinearisation
STOPS = ("read", "untaken", "ended", "fold", "elsewhere", "grown", "unmeasured", "step",
         "drift", "relinearize")
_ENDED = STOPS.index("ended")
_AFTER = (STOPS.index("drift"), STOPS.index("relinearize"))
#: the estimate's numbers per contact in the run's output (TrackStep.estimate's 14, then the
#: state's rates and their variances)
_NUMBERS = 14


class TrackedRun:
    """One run's inputs (from the pipeline's state now) and, after it, what it did."""

    def __init__(self, pipe: SensorPipeline) -> None:
        tracking = pipe.tracking
        trackers = tracking.tracker.trackers
        self.trackers = trackers
        self.steps = [tr._kernel() for tr in trackers]
        self.ats = tracking.tracker.measured_at()
        self.per = np.array([(tr.t, tr.excess) for tr in trackers], dtype=np.float64)
        self.k = [step.z.size for step in self.steps]
        peak0 = tracking.base.get("peak") if tracking.base is not None else None
        zr = pipe.stage.zeroer  # type: ignore[union-attr]
        drift_t = (math.inf if tracking._drift_ref is None
                   else math.nan if zr._drift_t is None else zr._drift_t)
        self.tests = np.array((
            # (frames it may step before the one that folds the residuals: Tracker._fold)
            min(MEAN_RESIDUAL_FOLD - 1 - tr._eframes for tr in trackers), drift_t, DRIFT_STEP_S - 1e-9,
            pipe._elsewhere_strain,
            REFIT_SIGNAL_RATIO * peak0 if peak0 is not None and peak0 > 0.0 else math.nan,
            tracking.lin_asked_t, MIN_RELINEARIZE_S, RELINEARIZE_SIGMA, SHARPEN))
        outside = tracking._outside
        self.outside, self.expected = outside if outside is not None else (_NO_INDEX, _NO_VALUES)
        self.mask = (_NO_MASK if pipe.mask is None
                     else np.ascontiguousarray(pipe.mask, dtype=bool).reshape(-1).view(np.uint8))
        self.out: np.ndarray | None = None
        self.tracked = 0
        self.stop = 0

    def __call__(self, runner, raws: list[np.ndarray], times: np.ndarray, z: np.ndarray,
                 stats: np.ndarray, peaks: np.ndarray, state: np.ndarray) -> int:
        """The run (CalibrationStage.process_run's ``track``): returns the frames taken."""
        self.out = np.empty((len(raws), len(self.steps), _NUMBERS + 2 * max(self.k)))
        taken, self.tracked, self.stop = native.core.track_run(
            runner, raws, times, z, stats, peaks, state, self.steps, self.ats, self.per,
            self.tests, self.outside, self.expected, self.mask, self.out)
        return taken

    def publish(self, pipe: SensorPipeline, run: Sequence[Frame], z: np.ndarray,
                stats: list[float], peaks: list[float], taken: int, now: float,
                dispatch: bool) -> None:
        """The run's frames published: each tracked one's zeroed frame and estimate, as
        ``ContactTracking.track`` publishes them; the frame it stopped at, if taken, through
        the per-frame path."""
        tracking = pipe.tracking
        tracked = self.tracked
        rows = self.out.tolist() if tracked else []  # type: ignore[union-attr]
        w = None
        for i in range(tracked):
            frame = run[i]
            strain = took(pipe, frame, z[i])
            numbers = [(r[:6], r[6:12], r[12], int(r[13]), r[14:14 + k], r[14 + k:14 + 2 * k])
                       for r, k in zip(rows[i], self.k)]
            w = _Waiting(0, frame.seq, frame.sensor_id, frame.device_time_us, frame.host_time,
                         strain, now, frame.device_time_us * 1e-6, peak=peaks[i],
                         stamp=frame.time)
            pipe._guarded(frame, dispatch, self._publish_one, pipe, w, stats[i],
                          numbers)
        if tracked:
            tracking.tracked += tracked
            pipe.tracked_rate.tick_many(time.monotonic(), tracked)
        if self.stop in _AFTER and w is not None:  # what track does after the estimate
            tracking.follow_drift(w)
            tracking._maybe_relinearize(w)
        if taken > tracked:  # the frame the run stopped at: the per-frame path from the stage on
            frame = run[tracked]
            strain = took(pipe, frame, z[tracked])
            pipe._guarded(frame, dispatch, pipe._after_stage, frame, strain,
                          self.stop != _ENDED, False, now, stats[tracked], peaks[tracked])

    def _publish_one(self, pipe: SensorPipeline, w: _Waiting, statistic: float,
                     numbers: list[tuple]) -> None:
        """A tracked frame: what ``_after_stage`` and ``ContactTracking.track`` do with it."""
        pipe._ordinal += 1
        w.ordinal = pipe._ordinal
        pipe.hub.publish_frame(pipe.name, w.sensor_id, w.seq, w.device_time_us, w.host_time, True,
                               statistic, w.strain, w.stamp)
        for tr in self.trackers:
            tr.stepped(w.t)
        pipe.skipped[GATE_UNCHANGED] += 1
        tracking = pipe.tracking
        fit = tracking.tracker.estimate_from(tracking.base, numbers)
        pipe._publish(w, GATE_UNCHANGED, tracking.base_seq, 0.0, fit, fresh=True)


def took(pipe: SensorPipeline, frame: Frame, strain: np.ndarray) -> np.ndarray:
    """A frame a run took (this module's or :mod:`.frame_run`'s): counted, recorded, its
    zeroed ``strain`` (read-only) given it."""
    pipe.frames += 1
    if pipe.record_path is not None:
        pipe._record(frame)
    frame.strain = strain
    return strain


_NO_INDEX = np.zeros(0, dtype=np.int64)
_NO_VALUES = np.zeros(0)
_NO_MASK = np.zeros(0, dtype=np.uint8)


def plan(pipe: SensorPipeline) -> TrackedRun | None:
    """The next frames' tracked run, when the sensor's contact is tracked (module comment);
    None: a plain run (:meth:`CalibrationStage.process_run`)."""
    s = pipe.settings
    tracking = pipe.tracking
    tracker = tracking.tracker
    stage = pipe.stage
    waiting = pipe._waiting
    if not (s.track and s.reuse_unchanged and stage is not None and stage.zeroer.in_contact
            and not tracking.pending and tracker.active and tracker.started
            and tracking.base is not None and pipe._in_flight is None
            and (waiting is None or waiting.kind == "lin") and native.core is not None):
        return None
    if tracker.several and (tracker.overlapping() or len(tracking.tracker.bases)
                            != len(tracker.trackers)):
        return None
    if any(tr.t is None for tr in tracker.trackers):
        return None
    return TrackedRun(pipe)

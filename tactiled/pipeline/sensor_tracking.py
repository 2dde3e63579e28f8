"""A contact's track and its fits: the tracking half of a sensor's loop (``settings.track``).

:class:`ContactTracking` holds what :class:`~tactiled.pipeline.sensor.SensorPipeline` does with
a contact frame once the frame's path (linearise, zero, gate) is done.  The rules are in
docs/concepts/pipeline.md ("The tracker").
"""

# It measures a contact frame through the tracker at once when it can, else keeps it (with the
# frames after it, in arrival order) until a fit comes back, then measures them all through that
# fit's linearisation; asks for relinearisations as the contact moves; follows drift around a
# held contact; and hands a frame to a fit when another contact is pressed beside the tracked
# one.  The pipeline owns one and hands it each contact frame (:meth:`ContactTracking.track`) and
# each fit's answer (:meth:`ContactTracking.result`).

from __future__ import annotations

import asyncio
import logging
import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from tactiled.fit.warm import SEVERAL
from tactiled.pipeline.estimate import GATE_FIT, GATE_NO_CONTACT, GATE_UNCHANGED
from tactiled.pipeline.kernels import largest_excess
from tactiled.pipeline.contact_filter import untracked

if TYPE_CHECKING:
    from tactiled.pipeline.multi_contact import ContactTrackers
    from tactiled.pipeline.jobs import FitJob
    from tactiled.pipeline.sensor import SensorPipeline

log = logging.getLogger("tactiled.pipeline.sensor")


@dataclass
class _Waiting:
    """A frame waiting for (or in) a fit."""

    ordinal: int
    seq: int
    sensor_id: int
    device_time_us: int
    host_time: float
    strain: np.ndarray
    since: float  # monotonic s it started waiting
    t: float = 0.0  # device time, s
    #: a fit of the frame ("fit"; "fit+lin" with its linearisation, for the tracker), or only
    #: its linearisation at ``at`` (the tracker's state, "lin")
    kind: str = "fit"
    at: tuple[str, tuple[float, ...]] | None = None
    #: the contact ended while this job was in flight: its result answers nothing
    dropped: bool = False
    #: the frame's largest strain, when the calibration stage gave it (NaN: not known)
    peak: float = math.nan
    #: the frame's time, Unix s (tactiled.clock; NaN: not stamped)
    stamp: float = math.nan


#: Frames of a contact that wait for a fit before the tracker can measure them (they left the
#: linear range); beyond this many the oldest (but the one being fitted) is given up (counted
#: superseded).
MAX_PENDING = 64
#: ... and none waits longer than this (s): past it, the waiting frames get the contact
#: predicted to their time and go out (counted predicted), so a slow fit (a loaded machine,
#: a frame far outside the model) costs precision for a while, never latency.  A timer on the
#: event loop sends them at that time, not when the sensor's next frame comes.  Live only: in
#: lossless mode every frame waits for its fit.
MAX_WAIT_S = 0.005
#: A relinearisation is asked for at most once per this much device time (s).
MIN_RELINEARIZE_S = 0.004
#: A tracked contact whose frame's largest strain grows past this many times that of the frame
#: its fit was of is fitted again (:meth:`ContactTracking._signal_grown`): each value's
#: single-frame sigma is then half what that fit had, or less.  A contact pressed from a light
#: touch costs a fit each time its signal doubles.
REFIT_SIGNAL_RATIO = 2.0


class ContactTracking:
    """A sensor's contact through time (``settings.track``): the tracker, the frames waiting
    for a fit before it can measure them (in arrival order), the fit its estimates build on,
    and the tracking counters.  It answers frames through its pipeline ``pipe`` (publishing,
    the one-frame slot, the gate), which owns it."""

    def __init__(self, pipe: SensorPipeline, tracker: ContactTrackers) -> None:
        self.pipe = pipe
        self.tracker = tracker
        self.pending: list[_Waiting] = []
        #: the fit the tracked estimates build on, and its frame's seq
        self.base: dict[str, Any] | None = None
        self.base_seq: int | None = None
        #: (strain on the whole array, window mask) of the tracker's linearisation: what the
        #: zeroer follows drift around while the contact is held (follow_drift)
        self._drift_ref: tuple[np.ndarray, np.ndarray] | None = None
        #: (flat indices outside the linearisation's window, its strain there)
        self._outside: tuple[np.ndarray, np.ndarray] | None = None
        self.lin_asked_t = -math.inf  # device time (s) a relinearisation was last asked for
        self.tracked = 0  # contact frames measured by the tracker, without a fit of their own
        self.predicted = 0  # ... of which the tracker could only predict, not measure
        self.relinearized = 0  # the tracker's point moved (a linearisation, no fit)
        self.drift_followed = 0  # times the zeroer followed drift around a held contact
        #: tracked frames sent to a fit because a tactel outside the contact's window rose
        #: (another contact pressed)
        self.pressed_elsewhere = 0
        #: tracked frames sent to a fit because their signal doubled since the tracked fit's
        #: frame (a light touch pressed harder: its model and curvatures fitted again)
        self.signal_grown = 0
        #: the event loop's call that sends the waiting frames at MAX_WAIT_S (_arm_flush)
        self._flush_timer: asyncio.TimerHandle | None = None

    def track(self, w: _Waiting, contact: bool, nonfinite: bool) -> None:
        """One frame through the tracker: measured at once when it can be, else it waits for
        a fit (with the frames after it, so the estimates keep their order)."""
        tracker = self.tracker
        if not contact:
            self.pipe._end_contact()
            self.pipe.skipped[GATE_NO_CONTACT] += 1
            self.pipe._publish(w, GATE_NO_CONTACT, None, 0.0, self.pipe._no_contact_fit)
            return
        if (self.pending and not self.pipe.lossless
                and w.since - self.pending[0].since > MAX_WAIT_S):
            self._flush_pending()
        if self.pending or not tracker.active or not self.pipe.settings.reuse_unchanged:
            if not self.pending and self.pipe._reuse_unchanged(w):
                return
            self._wait_for_fit(w)
            return
        if nonfinite:  # a reading the zeroer had to patch: never let it into the estimate
            tracker.skip()
            if tracker.started:
                self.predicted += 1
                self._publish_tracked(w, predicted=True)
            else:
                self.pipe.superseded += 1
            return
        if self._pressed_elsewhere(w.strain):
            self.pressed_elsewhere += 1
            self._wait_for_fit(w)
            return
        if self._signal_grown(w):
            self.signal_grown += 1
            self._wait_for_fit(w)
            return
        if tracker.step(w.strain.ravel(), w.t) == "refit":
            self._wait_for_fit(w)
            return
        self._publish_tracked(w)
        self.follow_drift(w)
        self._maybe_relinearize(w)

    def _signal_grown(self, w: _Waiting) -> bool:
        """The frame's largest strain is over ``REFIT_SIGNAL_RATIO`` times that of the frame
        the tracked estimates rest on: a contact pressed well beyond the frame whose fit chose
        its model and its curvatures.  What that frame could not resolve (a light touch's
        radius, a ball taken for a plane) the filter cannot learn from linearised steps about
        that fit's point, which hold the curvature the fit gave; a fit of this frame, with
        twice the signal (half the sigma on every value), can."""
        peak0 = None if self.base is None else self.base.get("peak")
        if peak0 is None or not peak0 > 0.0:
            return False
        return self.pipe._frame_peak(w, 0.0) > REFIT_SIGNAL_RATIO * peak0

    def _pressed_elsewhere(self, strain: np.ndarray) -> bool:
        """Outside the tracked contact's window, a tactel stands above what the contact
        explains there by more than any noise does: another contact (the tracker measures the
        window only, so a fit must say what the frame holds now)."""
        ref = self._outside
        if ref is None:
            return False
        index, predicted = ref
        return largest_excess(strain.ravel(), index, predicted) > self.pipe._elsewhere_strain

    def _flush_pending(self) -> None:
        """The waiting frames' fit is late: publish each with the contact predicted to its
        time (the fit, when it comes, still moves the tracker).  Before the contact's first
        fit there is nothing to predict from: those frames are given up (counted superseded),
        all but the one being fitted, so what is published stays fresh, as latest-frame-wins
        keeps it without tracking."""
        if self.tracker.started:
            for p in self.pending:
                self.predicted += 1
                self._publish_tracked(p, predicted=True)
            self.pending.clear()
            return
        busy = self.pipe._in_flight.ordinal if self.pipe._in_flight is not None else None
        keep = [p for p in self.pending if p.ordinal == busy]
        self.pipe.superseded += len(self.pending) - len(keep)
        self.pending = keep

    def _arm_flush(self) -> None:
        """Frames wait for a fit of a contact the tracker follows: they go out predicted
        ``MAX_WAIT_S`` after the oldest arrived (:meth:`_flush_due`), whenever the sensor's
        next frame comes.  Before the contact's first fit there is nothing to predict: the
        next frame gives those up (:meth:`_flush_pending`), as it did."""
        if self._flush_timer is not None or self.pipe.lossless or not self.tracker.started:
            return
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # driven without a loop (a test's hand): the next frame flushes
            return
        self._flush_timer = loop.call_at(self.pending[0].since + MAX_WAIT_S, self._flush_due)

    def _flush_due(self) -> None:
        """The timer of :meth:`_arm_flush`: the oldest waiting frame is ``MAX_WAIT_S`` old."""
        self._flush_timer = None
        if not self.pending or not self.tracker.started:
            return
        if time.monotonic() - self.pending[0].since < MAX_WAIT_S:  # a newer oldest frame
            self._arm_flush()
            return
        try:
            self._flush_pending()
        except Exception:  # a bug must cost these frames (counted), not the event loop's call
            self.pipe.errors += len(self.pending)
            self.pending.clear()
            log.exception("%s: the frames waiting for a late fit failed", self.pipe.name)
        self.pipe._check_settled()

    def _disarm_flush(self) -> None:
        if self._flush_timer is not None:
            self._flush_timer.cancel()
            self._flush_timer = None

    def _wait_for_fit(self, w: _Waiting) -> None:
        self.pending.append(w)
        self._arm_flush()
        if len(self.pending) > MAX_PENDING:
            # give up the oldest, but never the frame being fitted: its fit may be slow (a
            # frame far outside the model runs into its time budget) and it is answered
            busy = self.pipe._in_flight.ordinal if self.pipe._in_flight is not None else None
            drop = 1 if self.pending[0].ordinal == busy else 0
            self.pending.pop(drop)
            self.pipe.superseded += 1
        # latest frame wins: the newest pending frame is the one to fit (a waiting
        # relinearisation is no longer wanted); its warm start is computed when it is taken
        w.kind = "fit+lin"
        self.pipe._waiting = w
        self.pipe.pool.wake()

    def _maybe_relinearize(self, w: _Waiting) -> None:
        """The state has moved from the linearisation point (or sharpened well past it):
        a worker linearises again where the contact now is (no frame waits for it)."""
        if self.pipe._waiting is not None and self.pipe._waiting.kind != "lin":
            return
        if 0.0 <= w.t - self.lin_asked_t < MIN_RELINEARIZE_S:
            return  # (a device clock that went back, a restarted device, asks at once)
        at = self.tracker.wants_linearization()
        if at is not None:
            self.lin_asked_t = w.t
            point = at if at[0] == SEVERAL else (at[0], tuple(map(float, at[1])))
            self.pipe._waiting = _Waiting(w.ordinal, w.seq, w.sensor_id, w.device_time_us,
                                          w.host_time, w.strain, w.since, w.t, "lin", point,
                                          stamp=w.stamp)
            self.pipe.pool.wake()

    def _publish_tracked(self, w: _Waiting, gate: str = GATE_UNCHANGED,
                         worker_ms: float = 0.0, predicted: bool = False) -> None:
        assert self.base is not None
        if gate == GATE_UNCHANGED:
            if not predicted:
                self.tracked += 1
                self.pipe.tracked_rate.tick(time.monotonic())
            self.pipe.skipped[GATE_UNCHANGED] += 1
        fit = self.tracker.estimate(self.base, at=w.t if predicted else None)
        self.pipe._publish(w, gate, self.base_seq, worker_ms, fit, fresh=True)

    def _zero_var(self) -> float:
        return 0.0 if self.pipe.stage is None else self.pipe.stage.zeroer.baseline_var

    def clear(self) -> None:
        """The contact ended (or a tare, new settings): forget it; frames still waiting for a
        fit are given up (counted superseded)."""
        self.tracker.clear()
        self.base = self.base_seq = None
        self._drift_ref = self._outside = None
        self.pipe.superseded += len(self.pending)
        self.pending.clear()
        self._disarm_flush()

    def result(self, w: _Waiting, job: FitJob, fit: dict[str, Any], worker_ms: float,
               warm: tuple[str, tuple[float, ...]] | None, lin: Any) -> None:
        """A fit (or relinearisation) came back: measure the frames that waited for it."""
        tracker = self.tracker
        if job.kind == "lin":
            # (not a linearisation of a contact that has ended since it was asked for, nor one
            # a fit's own has replaced meanwhile)
            if (not w.dropped and lin is not None and tracker.active and lin.model == tracker.model
                    and self._adopt(lin)):
                self.relinearized += 1
            return
        if w.dropped:
            return  # the contact ended while it was fitted (its frames were counted then)
        if self.pipe._waiting is not None and self.pipe._waiting.kind != "lin":
            self.pipe._waiting = None  # set again below if a frame still needs a fit
        # ``w`` itself may be gone: given up past MAX_PENDING, or out already with a
        # prediction (MAX_WAIT_S); its fit still serves the tracker and the frames after it
        pending, self.pending = self.pending, []
        mine = any(p.ordinal == w.ordinal for p in pending)
        # (a contact whose radii both lie beyond the array's span, label "plane", gives the
        # filter no curvature to hold: its frames are fitted, each as it comes)
        usable = (fit.get("contact") and lin is not None and fit.get("label") != "plane"
                  and all(fit.get(k) is not None for k in ("x_mm", "y_mm")))
        if not usable and not mine and tracker.started:
            # a late fit with nothing to give: the tracker goes on predicting; any frame
            # waiting now needs a fit of its own
            self.pending = pending
            if pending:
                self._wait_for_fit(self.pending.pop())
            return
        if not usable:
            # nothing to track from (no contact in the window, a fit without a linearisation):
            # the frame gets the fit as it is; those before it are given up; those after it
            # reuse it while the gate finds them unchanged
            tracker.clear()
            self._obsolete_lin()
            self.base = self.base_seq = None
            # several contacts: each next fit starts from this one's (tactiled.fit.multi)
            self.pipe._warm = warm if warm is not None and warm[0] == SEVERAL else None
            later = [p for p in pending if p.ordinal > w.ordinal]
            self.pipe.superseded += len(pending) - len(later) - mine
            self.pipe._last_fit = None
            if mine:
                est = self.pipe._publish(w, GATE_FIT, w.seq, worker_ms,
                                    untracked(fit, 1, "no tracked contact"))
                if est.contact:
                    self.pipe._last_fit = est
                    self.pipe.gate.fitted(w.strain)
            while later and self.pipe._reuse_unchanged(later[0]):
                later.pop(0)
            if later:
                self.pending = later
                self._wait_for_fit(self.pending.pop())
            return
        self.pipe._last_fit = None  # the tracker answers from here
        self.pipe.gate.reset()
        self._adopt(lin, fit)
        self.follow_drift(w, fitted=True)
        self._obsolete_lin()
        self.base, self.base_seq, self.pipe._warm = fit, w.seq, warm
        if not mine and (tracker.t is None or w.t >= tracker.t):
            tracker.step(w.strain.ravel(), w.t, fitted=True)  # its estimate went out already
        if not pending:
            self._maybe_relinearize(w)
            return
        self.pending, last = pending, pending[-1]
        try:
            while self.pending:
                p = self.pending[0]
                if p.ordinal == w.ordinal:
                    tracker.step(p.strain.ravel(), p.t, fitted=True)
                    self._publish_tracked(self.pending.pop(0), GATE_FIT, worker_ms)
                elif tracker.step(p.strain.ravel(), p.t) != "refit":
                    self._publish_tracked(self.pending.pop(0))
                elif p.ordinal > w.ordinal:  # it and those after it wait for the next fit
                    self._wait_for_fit(self.pending.pop())
                    return
                elif tracker.started:
                    # older than the fit and outside its linear range too (a fast move): the
                    # contact predicted to its time, not a stale estimate, and not none
                    self.predicted += 1
                    self._publish_tracked(self.pending.pop(0), predicted=True)
                else:  # the contact's first frames, before any estimate: nothing to predict
                    self.pending.pop(0)
                    self.pipe.superseded += 1
        except Exception:  # a bug must cost these frames (counted), not the sensor's stream
            self.pipe.errors += len(self.pending)
            self.pending.clear()
            log.exception("%s: the frames waiting for the fit of seq %d failed", self.pipe.name, w.seq)
            self.pipe._end_contact()
            return
        self._maybe_relinearize(last)

    def _adopt(self, lin: Any, fit: dict[str, Any] | None = None) -> bool:
        """The tracker measures from the linearisation ``lin`` (of the fit ``fit``, or a
        relinearisation) now; the zeroer follows drift around the contact(s) it predicts.
        False when a relinearisation no longer fits the contacts held (nothing changes)."""
        if not self.tracker.adopt(lin, self._zero_var(), fit):
            return False
        self._drift_ref = self._outside = None
        predicted = lin.predicted  # (several contacts': their sum, computed on each access)
        if predicted is not None:
            window = np.zeros(predicted.size, dtype=bool)
            for one in getattr(lin, "lins", (lin,)):  # (several: each one's window)
                window[one.index] = True
            self._drift_ref = (predicted, window.reshape(predicted.shape))
            # (the tactels outside the window, and what the contact gives there: each frame
            # is tested there by _pressed_elsewhere)
            index = np.flatnonzero(~window).astype(np.intp)
            if index.size:
                self._outside = (index, np.ascontiguousarray(predicted.ravel()[index],
                                                             dtype=np.float64))
        return True

    def follow_drift(self, w: _Waiting, fitted: bool = False) -> None:
        """A frame the tracker measured as it came (or, ``fitted``, the frame the fit whose
        linearisation it adopted was of): the zeroer follows drift around the contact where
        the linearisation's prediction explains the frame (``Zeroer.follow_drift``; a contact
        held for minutes would otherwise drift off its frozen baseline until the finger never
        let go)."""
        ref = self._drift_ref
        if ref is not None and self.pipe.stage is not None:
            self.drift_followed += self.pipe.stage.zeroer.follow_drift(w.strain, w.t, *ref, fitted=fitted)

    def _obsolete_lin(self) -> None:
        """A relinearisation in flight was asked for at a point the tracker no longer holds (a
        fit brought its own linearisation, or nothing to track): its answer is ignored."""
        if self.pipe._lin_in_flight is not None:
            self.pipe._lin_in_flight.dropped = True

    def drop_pending(self, w: _Waiting) -> int:
        """The fit of pending frame ``w`` is lost: the frames still waiting get a fit of the
        newest of them.  1 if ``w`` was still waiting (the caller counts it), else 0 (it was
        given up before, and counted then)."""
        before = len(self.pending)
        self.pending = [p for p in self.pending if p.ordinal != w.ordinal]
        if self.pending and (self.pipe._waiting is None or self.pipe._waiting.kind == "lin"):
            self._wait_for_fit(self.pending.pop())
        return before - len(self.pending)

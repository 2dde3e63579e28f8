"""A 3-axis array's shear, torsion, friction and slip in the daemon (docs/concepts/shear.md)."""

# For a sensor whose description says ``axes = 3`` and whose frames carry ``Frame.taxels``, the
# pipeline hands every frame here (:meth:`ShearTrack.on_frame`) beside its own 1-axis path:
#
# * the readings' zero (what the zeroed frames' ``taxels`` are read from) is the mean of the last :data:`ZERO_FRAMES` frames the contact detector
#   called free of contact (x, y and z of every taxel; frozen while a contact lasts);
# * during a contact the newest zeroed frame is fitted with the shear fit
#   (:class:`tactiled.fit.shear.ShearFitter`, warm-started from the contact's previous fit) in
#   one background thread, one fit at a time, the newest frame winning (a frame superseded while
#   a fit runs is counted, never queued);
# * every frame of the contact after its first fit is estimated at frame rate by the step from
#   the newest fit (:class:`tactiled.fit.shear.ShearStep`: one matrix-vector product, no fit)
#   and feeds the contact's slip detector (:class:`tactiled.fit.slip.SlipDetector`, which keeps
#   the contact's shear filter, the tracked shear state); an onset or end is published on the
#   hub as a ``slip`` item with the frame it was declared on;
# * :meth:`ShearTrack.annotate` gives every estimate the contact's newest ``shear`` and ``slip``
#   tables (the strongest contact's: the fit's window is centred on the array's peak; the tables
#   are the newest frame's: ``fx_n``, ``fy_n``, ``torque_nmm`` and ``q_over_p`` the filter's,
#   the rest the step estimate's), or null with the reason in ``reasons``.

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
import math
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from tactiled.frames import Frame
from tactiled.sensors.description import SensorDescription

log = logging.getLogger(__name__)

#: Frames without contact averaged into the readings' zero.
ZERO_FRAMES = 50
NO_ZERO = "no zero yet: the array has not been seen free of contact"
NO_FIT = "no shear fit of this contact yet"
NO_TAXELS = "the frames carry no 3-axis readings (a 1-axis source of a 3-axis array)"
NOT_STRONGEST = "shear is fitted for the strongest contact only"


@dataclass(frozen=True)
class SlipItem:
    """A slip event of one contact, published on the hub (kind ``slip``): ``event`` is
    ``onset`` or ``end``; ``seq``, ``device_time_us``, ``host_time`` and ``wall_time`` are the
    frame's it was declared on."""

    sensor: str
    sensor_id: int
    seq: int
    device_time_us: int
    host_time: float
    wall_time: float
    event: str
    contact_id: int | None
    state: str

    kind = "slip"

    def to_json_dict(self) -> dict[str, Any]:
        return {"type": "slip", "sensor": self.sensor, "sensor_id": self.sensor_id,
                "seq": self.seq, "device_time_us": self.device_time_us,
                "host_time": self.host_time, "time": self.wall_time, "event": self.event,
                "contact_id": self.contact_id, "state": self.state}


@dataclass
class _Job:
    readings: np.ndarray
    seq: int
    sensor_id: int
    device_time_us: int
    host_time: float
    wall_time: float
    contact: int  # the contact's number (a new one per press)


class ShearTrack:
    """The shear state of one 3-axis sensor; every method runs on the event loop's thread."""

    def __init__(self, desc: SensorDescription, sensor: str,
                 publish: Callable[[SlipItem], None]) -> None:
        from tactiled.fit.shear import ShearFitter
        from tactiled.fit.slip import SlipDetector

        self.sensor = sensor
        self.shape = (desc.rows, desc.cols, 3)
        self._fitter = ShearFitter(desc)
        self._detector_type = SlipDetector
        self._publish = publish
        self._pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix=f"shear-{sensor}")
        self._free: deque[np.ndarray] = deque(maxlen=ZERO_FRAMES)
        self._free_sum = np.zeros(self.shape)
        self._contact = 0
        self._in_contact = False
        self._next: _Job | None = None
        self._busy = False
        self._start: np.ndarray | None = None
        self._detector = SlipDetector()
        self._tracked = 0
        self._step: Any = None  # the newest fit's ShearStep for this contact
        # (seq, step estimate, slip state, the filter's shear values)
        self._newest: tuple[int, Any, str | None, dict[str, tuple[float, float]] | None] | None = None
        self._onset: dict[str, Any] | None = None
        self._end: dict[str, Any] | None = None
        self._closed = False
        self._contact_id: int | None = None  # the strongest contact's id in the estimates
        # counters
        self.frames = 0
        self.without_taxels = 0
        self.fits = 0
        self.steps = 0
        self.fit_errors = 0
        self.superseded = 0
        self.events = {"onset": 0, "end": 0}

    # -- frames ---------------------------------------------------------------------------------

    def on_frame(self, frame: Frame, contact: bool) -> np.ndarray | None:
        """One frame of the sensor and the contact detector's verdict on it; returns its zeroed
        readings ``(rows, cols, 3)`` (None: no 3-axis readings, or no zero yet)."""
        self.frames += 1
        taxels = frame.taxels
        if taxels is None or taxels.shape != self.shape:
            self.without_taxels += 1
            return None
        values = taxels.astype(float)
        readings = values - self._free_sum / len(self._free) if self._free else None
        if readings is not None:
            readings.setflags(write=False)  # shared by the published frame and the fit
        if not contact:
            if self._in_contact:
                self._released(frame)
            if len(self._free) == self._free.maxlen:
                self._free_sum -= self._free[0]
            self._free.append(values)
            self._free_sum += values
            return readings
        if not self._in_contact:
            self._in_contact = True
            self._contact += 1
        if readings is None:
            return None
        if self._step is not None:
            self._track(frame, readings)
        job = _Job(readings, frame.seq, frame.sensor_id, frame.device_time_us, frame.host_time,
                   time.time(), self._contact)
        if self._busy:
            if self._next is not None:
                self.superseded += 1
            self._next = job
        else:
            self._submit(job)
        return readings

    def _released(self, frame: Frame) -> None:
        """The contact ended: a slip in progress ends with it; the next press starts afresh."""
        if self._detector.sliding:
            self._event("end", frame.seq, frame.sensor_id, frame.device_time_us,
                        frame.host_time, time.time())
        self._in_contact = False
        self._next = None
        self._start = None
        self._step = None
        self._newest = None
        self._onset = self._end = None
        self._detector = self._detector_type()
        self._tracked = 0

    def _submit(self, job: _Job) -> None:
        if self._closed:
            return
        self._busy = True
        start = self._start
        loop = asyncio.get_running_loop()
        fut = self._pool.submit(self._fit, job.readings, start)
        def done(f: concurrent.futures.Future) -> None:  # the fit's thread
            if not f.cancelled():
                with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                    loop.call_soon_threadsafe(self._done, job, f)

        fut.add_done_callback(done)

    def _fit(self, readings: np.ndarray, start: np.ndarray | None) -> tuple[Any, Any]:
        """In the fit's thread: the fit of ``readings`` and its step."""
        est = self._fitter.fit(readings, start)
        return est, self._fitter.step(est)

    def _done(self, job: _Job, fut: concurrent.futures.Future) -> None:
        self._busy = False
        try:
            est, step = fut.result()
        except Exception as err:  # a fit that fails costs its frame, never the sensor
            self.fit_errors += 1
            log.warning("%s: shear fit of seq %d failed: %s", self.sensor, job.seq, err)
            est = step = None
        if est is not None and job.contact == self._contact and self._in_contact:
            self.fits += 1
            self._start = est.params.copy() if est.converged else None
            self._step = step
        nxt, self._next = self._next, None
        if nxt is not None and nxt.contact == self._contact:
            self._submit(nxt)

    def _track(self, frame: Frame, readings: np.ndarray) -> None:
        """One frame of the contact: its step estimate through the slip detector."""
        self.steps += 1
        self._tracked += 1
        est, state, event = self._detector.track(self._tracked, self._step, readings)
        if event is not None:
            self._event(event.kind, frame.seq, frame.sensor_id, frame.device_time_us,
                        frame.host_time, time.time(), state)
        tracking = self._detector.tracking  # the contact's filter, fed by the detector
        filtered = tracking.shear() if tracking.x is not None else None
        self._newest = (frame.seq, est, state, filtered)

    def _tables(self) -> tuple[dict[str, Any], dict[str, Any]] | None:
        """The ``shear`` and ``slip`` tables of the newest step estimate."""
        if self._newest is None:
            return None
        seq, est, state, filtered = self._newest
        doc = est.to_json()
        shear = {**doc["shear"], "seq": seq, "rms_over_noise": doc["rms_over_noise"],
                 "reasons": doc["reasons"]}
        if filtered is not None:  # the contact's filter: the forces tracked through time
            shear["std"] = dict(shear["std"])
            for key, (value, sigma) in filtered.items():
                if math.isfinite(value) and math.isfinite(sigma):
                    shear[key], shear["std"][key] = value, sigma
        slip = {"state": state, "lam": doc["slip"]["lam"], "lam_std": doc["slip"]["lam_std"],
                "onset": self._onset, "end": self._end}
        return shear, slip

    def _event(self, kind: str, seq: int, sensor_id: int, device_time_us: int,
               host_time: float, wall_time: float, state: str | None = None) -> None:
        self.events[kind] += 1
        mark = {"seq": seq, "device_time_us": device_time_us, "time": wall_time}
        if kind == "onset":
            self._onset, self._end = mark, None
        else:
            self._end = mark
        self._publish(SlipItem(self.sensor, sensor_id, seq, device_time_us, host_time,
                               wall_time, kind, self._contact_id, state or ("slip" if kind == "onset" else "stick")))

    # -- estimates --------------------------------------------------------------------------------

    def annotate(self, fit: dict[str, Any]) -> dict[str, Any]:
        """``fit`` (not changed) with the ``shear`` and ``slip`` tables of its strongest contact."""
        if not fit.get("contact"):
            return fit
        self._contact_id = fit.get("contact_id")
        tables = self._tables()
        if tables is None:
            why = NO_TAXELS if self.without_taxels == self.frames else (
                NO_ZERO if not self._free else NO_FIT)
            reasons = {**(fit.get("reasons") or {}), "shear": why}
            shear: Any = None
            slip: Any = None
        else:
            shear, slip = tables
            reasons = fit.get("reasons")
        out = {**fit, "shear": shear, "slip": slip}
        if reasons is not None:
            out["reasons"] = reasons
        contacts = fit.get("contacts")
        if isinstance(contacts, list) and contacts:
            top = fit.get("contact_id")
            out["contacts"] = [
                {**c, "shear": shear, "slip": slip} if c.get("contact_id") == top
                else {**c, "shear": None, "slip": None,
                      "reasons": {**(c.get("reasons") or {}), "shear": NOT_STRONGEST}}
                for c in contacts]
        return out

    def stats(self) -> dict[str, Any]:
        return {"frames": self.frames, "without_taxels": self.without_taxels,
                "fits": self.fits, "steps": self.steps, "fit_errors": self.fit_errors,
                "superseded": self.superseded, "events": dict(self.events),
                "zero_frames": len(self._free), "in_contact": self._in_contact}

    def close(self) -> None:
        self._closed = True
        self._pool.shutdown(wait=False, cancel_futures=True)


def for_sensor(desc: SensorDescription, sensor: str,
               publish: Callable[[SlipItem], None]) -> ShearTrack | None:
    """A :class:`ShearTrack` for a 3-axis description, None for a 1-axis one."""
    if getattr(desc, "axes", 1) != 3:
        return None
    return ShearTrack(desc, sensor, publish)

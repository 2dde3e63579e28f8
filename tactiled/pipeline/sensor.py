"""One sensor's loop: read -> (decode, in the source) -> linearise -> zero -> gate -> fit -> publish.

The frames of each read are handled synchronously, in one call (:meth:`SensorPipeline.on_frames`);
only the fit leaves the loop, to a worker process.  Latest frame wins, except in ``lossless``
mode (replay, regression tests), where every frame gets its estimate, deterministically.  A
contact through time (``settings.track``) is :mod:`tactiled.pipeline.sensor_tracking`'s.
"""

# Latest frame wins: a frame to fit waits in a one-frame slot, a newer one replaces it
# (``superseded``), at most one fit per sensor is in flight, and a fit older than the last
# estimate published is dropped (``stale_dropped``); order is the pipeline's own arrival count
# (``ordinal``), not ``seq`` (it wraps, and restarts with the device).  ``lossless`` mode waits
# for each fit instead.

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from dataclasses import replace
from pathlib import Path
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from tactiled.io.calibration import Calibration, load_calibration_file
from tactiled.calibration.lut import LookupTable
from tactiled.calibration.stage import CalibrationStage
from tactiled.clock import FrameClock
from tactiled.sensors.model import NoiseModel
from tactiled.sensors import load_description
from tactiled.errors import CalibrationError, ConfigError, DriverError, FrameError
from tactiled.fit.budget import budget_spent
from tactiled.fit.result import FitResult
from tactiled.fit.verdict import ArrayLimits, carry, judge, judge_fresh
from tactiled.frames import Frame
from tactiled.pipeline.estimate import (
    GATE_FIT,
    GATE_NO_CONTACT,
    GATE_UNCHANGED,
    Estimate,
    plain,
    published_stamp,
)
from tactiled.pipeline.gate import Gate
from tactiled import native
from tactiled.pipeline import frame_run, learned
from tactiled.fit.regions import SIGNIFICANT_Z
from tactiled.pipeline.association import ContactIds, identified
from tactiled.pipeline.hub import Hub
from tactiled.pipeline.meters import Histogram, RateMeter, WindowMean
from tactiled.pipeline.jobs import FitJob, warm_start
from tactiled.pipeline.pool import WorkerPool
from tactiled.pipeline.sensor_stats import SensorStats
from tactiled.pipeline.multi_contact import ContactTrackers
from tactiled.pipeline import shear_track
from tactiled.pipeline.contact_filter import Tracker, untracked
from tactiled.pipeline.sensor_tracking import ContactTracking, _Waiting
from tactiled.io.recording import Recorder
from tactiled.settings import SensorSettings
from tactiled.sources import FrameSource, open_source

log = logging.getLogger(__name__)

RETRY_MIN, RETRY_MAX = 0.1, 2.0  # s, backoff between attempts to open a failing source
#: Longest a sensor handles one read's frames before it lets the loop's other tasks run (s).
SLICE_S = 0.01

#: The daemon withholds a radius whose Cramer-Rao bound exceeds half of it ("force too low
#: for curvature"; docs/concepts/model.md: radius is not observable at low force).
WITHHOLD_RELATIVE_SIGMA = 0.5


def worker_fit_options(window: int) -> tuple[tuple[str, Any], ...]:
    """``FitOptions`` keyword arguments as a hashable tuple: the worker builds the FitOptions,
    so this process never imports the fitter (and scipy with it)."""
    return (("window", window), ("withhold_relative_sigma", WITHHOLD_RELATIVE_SIGMA),
            ("learn_floor", True))


#: Why a contact of several carries no rates: each such frame is fitted, none tracked.
SEVERAL_UNTRACKED = "several contacts on the array: each frame is fitted, not tracked"

class SensorPipeline:
    """The acquisition loop of one sensor, publishing to ``hub`` and fitting on ``pool``.

    Construction loads the calibration file (``CalibrationError``) and builds the source from
    its URL (``ValueError``), without any I/O on the device.
    """

    #: a read's frames in runs, one call into the core each (:mod:`.frame_run`); False: per frame
    batched = native.core is not None

    def __init__(self, settings: SensorSettings, *, pool: WorkerPool, hub: Hub,
                 record_path: Path | None = None, lossless: bool = False,
                 source: FrameSource | None = None, state_dir: Path | None = None) -> None:
        self.settings = settings
        self.name = settings.name
        self.pool = pool
        self.hub = hub
        self.lossless = lossless
        self.record_path = record_path
        self.table: LookupTable | None = None
        self.expected_id = settings.wire_id
        #: the calibration file's content (None: the nominal table and the paper's model)
        self.calibration: Calibration | None = None
        if settings.calibration is not None:
            self.calibration = load_calibration_file(settings.calibration)
            self.table = self.calibration.table
            if self.expected_id is not None and self.table.sensor_id != self.expected_id:
                raise CalibrationError(
                    f"{settings.calibration}: calibration of sensor {self.table.sensor_id}, "
                    f"but wire_id is {self.expected_id}")
            self.expected_id = self.table.sensor_id
        #: what the array is: grid, surface, cover, wiring (docs/howto/sensors.md)
        self.description = load_description(settings.description)
        # Tactels the description names dead, or the calibration found dead or never
        # exercised, are left out of every fit.
        self.mask = self.description.dead_mask()
        if self.table is not None and self.table.dead_mask.any():
            self.mask = ~self.table.dead_mask if self.mask is None else self.mask & ~self.table.dead_mask
        self._any_usable = self.mask is None or bool(self.mask.any())
        noise = NoiseModel(sigma=settings.noise_sigma)
        # the description's array; an identified finger's rubber, tactel positions and
        # model-error floor (version 2 calibration files) in place of its cover's constants
        base = self.description.sensor_model(settings.noise_sigma)
        self.sensor_model = (base if self.calibration is None
                             else self.calibration.sensor_model(noise, base.geometry, base=base))
        g = self.sensor_model.geometry
        self._grid_shape = (g.rows, g.cols)  # a frame's raw counts' shape, in grid order
        if self.table is not None and self.table.shape != (g.rows, g.cols):
            raise CalibrationError(f"{settings.calibration}: table shape {self.table.shape} is "
                                   f"not the sensor's {(g.rows, g.cols)}")
        self.state_dir = state_dir
        #: the learned flat field's file: fits it was loaded with, files refused (and why)
        self.learned = learned.LearnedFile(state_dir)
        if state_dir is not None:
            self.learned.check(self._owner())
        self.spec = pool.register_spec(self.sensor_model, self._fit_options(), self.name)
        self.model = settings.model
        self.gate = Gate(settings.noise_sigma, settings.unchanged_z, settings.reuse_unchanged)
        self.source: FrameSource = source if source is not None else open_source(settings.url)
        # a vendor driver's array: its nominal counts -> strain table, when it is this shape
        device = self.source.device_array()
        if device is not None and device.shape != (g.rows, g.cols):
            raise ConfigError(
                f"sensor {self.name}: the {device.kind} device's array is "
                f"{device.shape[0]}x{device.shape[1]}, but its description "
                f"{self.description.name!r} is {g.rows}x{g.cols}: set the sensor's description "
                "to the array's (docs/howto/sensors.md)")
        self.device = device
        sent = self.source.sent_id()
        if sent is not None and self.expected_id is not None and sent != self.expected_id:
            said, fix = ((f"its calibration {settings.calibration} is of sensor id "
                          f"{self.expected_id}", f"calibrate with --sensor-id {sent}")
                         if settings.wire_id is None else
                         (f"its wire_id is {self.expected_id}", f"set wire_id = {sent}"))
            raise ConfigError(f"sensor {self.name}: {settings.url} sends sensor id {sent}, but "
                              f"{said}: every frame would be dropped ({fix})")
        #: a 3-axis array's shear, torsion and slip (None for a 1-axis array)
        self.shear = shear_track.for_sensor(self.description, self.name, hub.publish)
        self.stage: CalibrationStage | None = None
        self.sensor_id: int | None = self.expected_id
        self._no_contact_fit = {**untracked(plain(FitResult(
            contact=False, message="no contact: below the detection threshold").to_json_dict()),
            0, "no contact"), "contact_id": None, "contacts": []}
        #: each contact's id from frame to frame (a contact moves far less than a cover depth
        #: between frames, and two contacts the detector tells apart lie further apart)
        self._elsewhere_strain = SIGNIFICANT_Z * settings.noise_sigma
        self._limits = ArrayLimits.of(self.sensor_model)
        self.ids = ContactIds(gate_mm=max(self.sensor_model.impulse.depth_x,
                                          self.sensor_model.impulse.depth_y))
        #: the contact through time (settings.track) and the frames waiting for its fits
        self.tracking = ContactTracking(self, ContactTrackers(
            lambda: Tracker(withhold_relative_sigma=WITHHOLD_RELATIVE_SIGMA, geometry=g),
            gate_mm=self.ids.gate_mm))
        #: every frame's time (tactiled/clock.py): the estimates' ``time``, ROS 2's stamps
        self.clock = FrameClock(settings.rate_hz)
        # -- state
        self._ordinal, self.quiet_at = 0, -1  # frames in; the last one quiet after (frame_run)
        self._last_published = 0  # ordinal of the last estimate published
        self._waiting: _Waiting | None = None
        self._in_flight: _Waiting | None = None  # the frame being fitted
        #: a relinearisation in flight (the tracker's; it answers no frame, so a frame's fit
        #: never waits for it: see take_job)
        self._lin_in_flight: _Waiting | None = None
        self._last_fit: Estimate | None = None
        self._warm: tuple[str, tuple[float, ...]] | None = None  # previous fit: a warm start
        self._settled = asyncio.Event()
        self._task: asyncio.Task[None] | None = None
        self._recorder: Recorder | None = None
        self._record_failed = False
        self.finished, self.read_left = False, 0  # read_left: the read's frames not yet handled
        self.last_error = ""
        # -- counters
        self.frames = 0
        self.superseded = 0
        self.fitted = 0
        self.published = 0
        self.skipped = {GATE_NO_CONTACT: 0, GATE_UNCHANGED: 0}
        self.stale_dropped = 0
        self.relinearize_lost = 0
        self.fit_failed = 0
        self.fit_errors = 0
        self.fits_budget_spent = 0  # fits the fit budget stopped (tactiled.fit.budget)
        self.wrong_sensor = 0
        self.bad_shape = 0
        self.errors = 0
        self.source_errors = 0
        self.record_errors = 0
        self.last_frame_at: float | None = None
        self.frame_rate = RateMeter()
        self.fit_rate = RateMeter()  # every fit a worker returns, relinearisations too
        self.tracked_rate = RateMeter()  # contact frames the tracker measured without a fit
        self.latency_ms = WindowMean()
        self.worker_ms = WindowMean()
        #: since start: host receive -> published, per gate; and a fit's worker round trip (s)
        self.latency_hist = {g: Histogram() for g in (GATE_FIT, GATE_UNCHANGED, GATE_NO_CONTACT)}
        self.fit_hist = Histogram()

    # -- running --------------------------------------------------------------------------------

    def start(self) -> None:
        """Start reading (a task on the running loop)."""
        if self._task is None:
            self._task = asyncio.create_task(self._run(), name=f"tactiled-sensor-{self.name}")

    async def stop_reading(self) -> None:
        """Stop the read loop (frames already handed to the pool still get their fits)."""
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    async def _close_source(self) -> None:
        try:
            await self.source.close()
        except Exception as err:  # closing must not stop the shutdown of everything else
            log.warning("%s: closing %s: %s", self.name, self.source.url.url, err)

    async def close(self) -> None:
        """Close the source and flush and close the recording."""
        await self.stop_reading()
        await self._close_source()
        if self.shear is not None:
            self.shear.close()
        if self._recorder is not None:
            try:
                self._recorder.close()  # flush + fsync; kept for its frames_written count
            except OSError as err:
                log.error("%s: closing recording %s: %s", self.name, self.record_path, err)
            self._record_failed = True  # nothing more is written after close

    async def _run(self) -> None:
        delay = RETRY_MIN
        while True:
            try:
                if not self.source.is_open:
                    await self.source.open()
                delay = RETRY_MIN
                async with contextlib.aclosing(self.source.frame_batches()) as batches:
                    async for batch in batches:  # the frames of one read
                        self.clock.stamp(batch)  # together: they arrived together
                        done, lossless = 0, self.lossless
                        while done < len(batch):  # lossless: each frame's fit awaited; else
                            # a read of many frames (a stall) in slices, the loop's other
                            # tasks (sensors, fit results) run between them
                            done = self.on_frames(batch, done, not lossless, until_busy=lossless)
                            self.read_left = len(batch) - done
                            if lossless:  # (no coroutine made when nothing is to wait for)
                                self._idle() or await self.wait_settled()
                            elif self.read_left:
                                await asyncio.sleep(0)
                        self.read_left = 0
                break  # the stream ended (a replay finished)
            except DriverError as err:
                # A device that failed to open or vanished: it may come back, so retry.
                self.source_errors += 1
                if str(err) != self.last_error:
                    log.warning("%s: %s (retrying)", self.name, err)
                self.last_error = str(err)
                await self._close_source()
                await self.source.retry_pause(delay)  # early if the device reappears
                delay = min(delay * 2.0, RETRY_MAX)
            except Exception as err:
                # Anything else (a corrupt recording, a driver bug) would fail again the same
                # way, and re-reading a replay from the start would repeat its frames: give up
                # on this sensor, say why, and keep the others running.
                self.source_errors += 1
                self.last_error = f"source failed: {type(err).__name__}: {err}"
                log.error("%s: %s; this sensor stops", self.name, self.last_error)
                await self._close_source()
                break
        self.finished = True
        log.info("%s: source %s ended after %d frames", self.name, self.source.url.url,
                 self.frames)

    async def wait_settled(self) -> None:
        """Wait until no frame of this sensor waits for, or is in, a fit (nor a
        relinearisation)."""
        while not self._idle():
            self._settled.clear()
            await self._settled.wait()

    def _idle(self) -> bool:
        return self._waiting is None and self._in_flight is None and self._lin_in_flight is None

    @property
    def settled(self) -> bool:
        """No frame waits for a fit or is in one, none of the read in hand waits its turn."""
        return self._idle() and not self.tracking.pending and not self.read_left

    def _check_settled(self) -> None:
        if self._idle():
            self._settled.set()

    # -- the frame's path -----------------------------------------------------------------------

    def on_frame(self, frame: Frame) -> None:
        """Handle one decoded frame; never raises (problems are counted)."""
        if frame.time is None:  # a frame handed over alone, not from this sensor's reads
            self.clock.stamp([frame])
        self.on_frames((frame,), dispatch=False)

    def on_frames(self, frames: Sequence[Frame], start: int = 0, dispatch: bool = True,
                  until_busy: bool = False) -> int:
        """Handle the frames of one read (stamped by ``self.clock``), from index ``start``, in
        one call: the time of arrival and the rate meter taken once, the frames through the
        stage in runs, one core call each (:mod:`.frame_run`).  Stops after the frame that
        takes the call past ``SLICE_S`` (``until_busy``: that leaves a fit to wait for), so the
        loop's other tasks get their turn; returns the index of the next frame (``len(frames)``:
        all done).  ``dispatch``: a fit due goes to the pool at once.  Never raises."""
        now = time.monotonic()
        end = len(frames)
        k = start
        while k < end:
            taken = (frame_run.take_run(self, frames, k, end, now, dispatch)
                     if self.batched and frame_run.runnable(self, until_busy) else 0)
            if not taken:
                frame = frames[k]
                self.frames += 1
                self._guarded(frame, dispatch, self._process, frame, now)
                taken = 1
            k += taken
            if k < end and ((until_busy and not self._idle()) or time.monotonic() - now > SLICE_S):
                break
        self.frame_rate.tick_many(now, k - start)
        self.last_frame_at = now
        return k

    def _guarded(self, frame: Frame, dispatch: bool, step: Callable[..., None], *args: Any) -> None:
        """``step(*args)``: a bug costs the frame (counted), not the loop; ``dispatch``: a fit
        made due goes to the pool now, not after the other frames and reads the loop holds."""
        before = self._waiting
        try:
            step(*args)
        except Exception as err:
            self.errors += 1
            self.last_error = f"{type(err).__name__}: {err}"
            log.exception("%s: frame seq %d failed", self.name, frame.seq)
        if dispatch and self._fit_due(before):
            self.pool.dispatch_now()

    def _record(self, frame: Frame) -> None:
        if self.record_path is None or self._record_failed:
            return
        try:
            if self._recorder is None:
                self._recorder = Recorder(self.record_path, sensor_id=frame.sensor_id,
                                          append=True, device=self.device and self.device.kind)
            self._recorder.record(frame)
        except ValueError as err:  # this frame cannot be encoded (not wire counts): skip it
            self.record_errors += 1
            self.last_error = f"frame seq {frame.seq} not recorded: {err}"
        except (OSError, FrameError) as err:  # disk full, a file of another sensor: stop
            self._record_failed = True
            self.record_errors += 1
            self.last_error = f"recording to {self.record_path} stopped: {err}"
            log.error("%s: %s", self.name, self.last_error)

    def _process(self, frame: Frame, now: float) -> None:
        self._record(frame)
        if self.expected_id is not None and frame.sensor_id != self.expected_id:
            self.wrong_sensor += 1
            if self.wrong_sensor == 1:
                log.warning("%s: frame from sensor id %d, expected %d: dropped (miswired?)",
                            self.name, frame.sensor_id, self.expected_id)
            return
        if frame.raw.shape != self._grid_shape:
            self.bad_shape += 1
            return
        if self.description.wire_order != "row-major":  # counts in wire order: to the grid
            frame.raw = self.description.to_grid(frame.raw)
        if self.stage is None:
            self._build_stage(frame.sensor_id)
        assert self.stage is not None
        nonfinite = self.stage.zeroer.nonfinite_frames
        contact = self.stage.process(frame)
        nonfinite = self.stage.zeroer.nonfinite_frames != nonfinite
        strain = frame.strain
        assert strain is not None
        # the zeroer never lets NaN out (the compiled path checks every value); belt and braces
        # (a sum is finite unless a value is not, or it overflows: then the copy changes nothing)
        if not self.stage.finite and not math.isfinite(strain.sum()):
            strain = np.nan_to_num(strain, nan=0.0, posinf=0.0, neginf=0.0)
        strain.setflags(write=False)
        self._after_stage(frame, strain, contact, nonfinite, now,
                          self.stage.zeroer.detector.last_statistic, self.stage.peak)

    def _after_stage(self, frame: Frame, strain: np.ndarray, contact: bool, nonfinite: bool,
                     now: float, statistic: float, peak: float) -> None:
        """A frame the stage took (``strain`` read-only; ``statistic``: the detector's after it,
        ``peak``: its largest strain or NaN): published, then gated, tracked or sent to a fit."""
        self._ordinal += 1
        ordinal = self._ordinal
        taxels = None if self.shear is None else self.shear.on_frame(frame, contact)
        self.hub.publish_frame(self.name, frame.sensor_id, frame.seq, frame.device_time_us,
                               frame.host_time, contact, statistic, strain, frame.time, taxels)
        waiting = _Waiting(ordinal, frame.seq, frame.sensor_id, frame.device_time_us,
                           frame.host_time, strain, now, frame.device_time_us * 1e-6,
                           peak=peak if contact else math.nan, stamp=frame.time)
        if self.settings.track:
            self.tracking.track(waiting, contact, nonfinite)
            return
        if self._waiting is not None or self._in_flight is not None:
            # A fit is outstanding for a frame that had changed: its result will be fresher than
            # the reference, so reusing the old estimate now would make it stale.  Only the contact
            # flag matters; the waiting frame is gated again when it arrives (_regate_waiting).
            action = GATE_NO_CONTACT if not contact else GATE_FIT
        else:
            action = self.gate.decide(strain, contact).action
        if action == GATE_NO_CONTACT:
            self.gate.reset()
            self._last_fit = None
            self._warm = None
            self.skipped[GATE_NO_CONTACT] += 1
            self._supersede_waiting()
            self._publish(waiting, GATE_NO_CONTACT, None, 0.0, self._no_contact_fit)
        elif not (action == GATE_UNCHANGED and self._last_fit is not None
                  and self._publish_reuse(waiting, self._last_fit)):
            if self._waiting is not None:
                self.superseded += 1
            self._waiting = waiting
            self.pool.wake()

    def _reuse_unchanged(self, w: _Waiting) -> bool:
        """With nothing to track (the contact's last fit could not place it: a light touch), a
        frame the gate finds unchanged since that fit is answered with it, as without tracking:
        refitting would give the same contact, at the price of the slowest fits there are."""
        last = self._last_fit
        if last is None or self.gate.decide(w.strain, True).action != GATE_UNCHANGED:
            return False
        return self._publish_reuse(w, last)

    def _publish_reuse(self, w: _Waiting, last: Estimate) -> bool:
        """Answer ``w`` with ``last``'s fit carried to it (the gate found it unchanged since:
        :func:`~tactiled.fit.verdict.carry`); False when a fit is due instead."""
        frames = w.seq - last.fitted_seq if last.fitted_seq is not None else 0
        fit = carry(last.fit, self.gate.change, frames, self._limits,
                    withhold_relative_sigma=WITHHOLD_RELATIVE_SIGMA)
        if fit is None:
            self.gate.refused += 1
            return False
        self.skipped[GATE_UNCHANGED] += 1
        self._publish(w, GATE_UNCHANGED, last.fitted_seq, 0.0, fit, fresh=True)
        return True

    def _fit_due(self, before: _Waiting | None) -> bool:
        """A frame has just started waiting for a fit (it was not ``before``), and no fit of
        this sensor is in flight: a worker could take it at once."""
        w = self._waiting
        return w is not None and w is not before and w.kind != "lin" and self._in_flight is None

    def _regate_waiting(self) -> None:
        """After a new fit is published, a waiting frame unchanged since is answered with it."""
        if self._waiting is not None and self._reuse_unchanged(self._waiting):
            self._waiting = None

    def _end_contact(self) -> None:
        """The contact ended (a tare, new settings): forget it; waiting frames are given up."""
        self.tracking.clear()
        self.gate.reset()
        self._last_fit = None
        self._warm = None
        self._waiting = None
        for busy in (self._in_flight, self._lin_in_flight):
            if busy is not None:
                busy.dropped = True
        self._check_settled()

    def _build_stage(self, sensor_id: int) -> None:
        g = self.sensor_model.geometry
        table = self.table or (LookupTable.linear(g.rows, g.cols, sensor_id=sensor_id)
                               if self.device is None else self.device.nominal_table(sensor_id))
        s = self.settings
        self.stage = CalibrationStage.for_sensor(table, self.sensor_model, s.noise_sigma,
                                                 s.false_rate, s.detector_average, s.hysteresis)
        self.sensor_id = sensor_id

    def _supersede_waiting(self) -> None:
        if self._waiting is not None:
            self._waiting = None
            self.superseded += 1
            self._check_settled()

    def _untracked_element(self, c: dict[str, Any]) -> dict[str, Any]:
        return c if "frames_used" in c else untracked(c, 1, SEVERAL_UNTRACKED)

    def _publish(self, w: _Waiting, gate: str, fitted_seq: int | None, worker_ms: float,
                 fit: dict[str, Any], fresh: bool = False) -> Estimate:
        """Publish ``fit`` as the estimate of frame ``w``.  ``fresh``: ``fit`` (and its
        contacts) were made for this estimate alone (a tracker's), so they are completed in
        place; any other (a worker's fit, reused for later frames) is copied."""
        if fit.get("peak") is not None:  # the frame's own, not that of the fit it rests on
            peak = self._frame_peak(w, fit["peak"])
            if fresh:
                fit["peak"] = peak
            else:
                fit = {**fit, "peak": peak}
        fit = identified(fit, self.ids, self._untracked_element, fresh)  # (a copy unless fresh)
        if self.shear is not None:
            fit = self.shear.annotate(fit)
        rule = judge_fresh if fresh else judge  # the one rule on all (tactiled.fit.verdict)
        rule(fit, self._limits, withhold_relative_sigma=WITHHOLD_RELATIVE_SIGMA)
        stamp = published_stamp(w.stamp)
        est = Estimate(self.name, w.sensor_id, w.seq, w.device_time_us, w.host_time,
                       time.monotonic(), stamp, gate, fitted_seq, worker_ms, fit)
        self._send(est, w.ordinal)
        return est

    def _send(self, est: Estimate, ordinal: int) -> None:
        """Count and publish the estimate of the frame of arrival number ``ordinal``."""
        self._last_published = ordinal
        self.published += 1
        latency_ms = (est.published_time - est.host_time) * 1e3  # (est.latency_ms)
        if math.isfinite(latency_ms):
            self.latency_ms.add(est.published_time, latency_ms)
            self.latency_hist[est.gate].observe(latency_ms / 1e3)
        self.hub.publish(est)

    def _frame_peak(self, w: _Waiting, fallback: float) -> float:
        """The largest strain of a frame's usable tactels (``fallback`` if none is): the
        calibration stage's when every tactel is usable; the frame's strain is finite
        (_process)."""
        if self.mask is None:
            return w.peak if w.peak == w.peak else float(w.strain.max())
        return float(w.strain[self.mask].max()) if self._any_usable else fallback

    # -- the pool's side (JobOwner) -------------------------------------------------------------

    def job_waiting_since(self) -> float | None:
        w = self._waiting
        if w is None or self._in_flight is not None:
            return None
        # A frame's fit goes out even while a relinearisation is in flight (its answer brings
        # a linearisation of its own, and the older one is then ignored: _tracked_result);
        # one relinearisation at a time, and none while a frame is fitted.
        if w.kind == "lin" and self._lin_in_flight is not None:
            return None
        return w.since

    def job_background(self) -> bool:
        return self._waiting is not None and self._waiting.kind == "lin"

    def take_job(self) -> FitJob:
        w = self._waiting
        assert w is not None and self._in_flight is None
        if w.kind == "lin":
            assert self._lin_in_flight is None
            self._waiting, self._lin_in_flight = None, w
        else:
            self._waiting, self._in_flight = None, w
        if w.kind == "fit+lin":  # the tracker's prediction at the frame's time, now
            w.at = self.tracking.tracker.predicted(w.t) or self._warm
        warm = warm_start(w.at if w.kind != "fit" else self._warm, self.sensor_model.geometry)
        return FitJob(owner=self, ordinal=w.ordinal, seq=w.seq, strain=w.strain,
                      model=self.model, spec=self.spec, mask=self.mask, warm=warm, kind=w.kind)

    def on_fit_result(self, job: FitJob, fit: dict[str, Any] | None, worker_ms: float,
                      error: str | None, warm: tuple[str, tuple[float, ...]] | None = None,
                      lin: Any = None) -> None:
        w = self._settle_job(job)
        try:
            if w is None or w.ordinal != job.ordinal:  # cannot happen: one job of a kind in flight
                log.error("%s: result for an unknown job (ordinal %d)", self.name, job.ordinal)
                return
            if job.kind == "lin":  # not a frame's fit: it only moves the tracker's point
                if error is not None:
                    self.relinearize_lost += 1
                    log.warning("%s: linearisation at seq %d failed: %s", self.name, w.seq, error)
                    return
                self.fit_rate.tick(time.monotonic())  # a fit all the same (workers.fits counts it)
                if self.settings.track:
                    self.tracking.result(w, job, {}, worker_ms, warm, lin)
                return
            self.fitted += 1
            if error is not None or fit is None:
                self.fit_errors += 1 if not self.settings.track else self.tracking.drop_pending(w)
                self.last_error = f"fit of seq {w.seq} failed: {error}"
                log.error("%s: %s", self.name, self.last_error)
                return
            if budget_spent(fit.get("reasons") or {}):
                self.fits_budget_spent += 1
            now = time.monotonic()
            self.fit_rate.tick(now)
            self.worker_ms.add(now, worker_ms)
            self.fit_hist.observe(worker_ms / 1e3)
            if self.settings.track:
                self.tracking.result(w, job, fit or {}, worker_ms, warm, lin)
                return
            fit = untracked(fit, 1, "tracking off (sensor setting track = false)")
            if w.ordinal <= self._last_published:
                self.stale_dropped += 1  # a newer frame's estimate is out already
                return
            est = self._publish(w, GATE_FIT, w.seq, worker_ms, fit)
            if est.contact and all(fit.get(k) is not None for k in ("x_mm", "y_mm")):
                self._last_fit = est
                self._warm = warm  # the contact persists: start the next fit here
                self.gate.fitted(w.strain)
                self._regate_waiting()
            else:
                self._last_fit = None
                self._warm = None
                self.gate.reset()
        finally:
            self._check_settled()

    def _settle_job(self, job: FitJob) -> _Waiting | None:
        """The frame (or relinearisation) ``job`` was for, no longer in flight."""
        if job.kind == "lin":
            w, self._lin_in_flight = self._lin_in_flight, None
        else:
            w, self._in_flight = self._in_flight, None
        return w

    def on_fit_failed(self, job: FitJob, reason: str) -> None:
        w = self._settle_job(job)
        if w is not None:
            self.last_error = f"fit of seq {w.seq} lost: worker {reason}"
        if job.kind == "lin":
            self.relinearize_lost += 1  # not a frame's fit: counted apart
        elif not self.settings.track:
            self.fit_failed += 1
        elif w is not None:
            self.fit_failed += self.tracking.drop_pending(w)
        self._check_settled()

    # -- control --------------------------------------------------------------------------------

    def tare(self) -> None:
        """Re-zero on the next frame (nothing may touch the finger) and refit from scratch."""
        if self.stage is not None:
            self.stage.tare()
        self._end_contact()

    def runtime_config(self) -> dict[str, Any]:
        from tactiled.settings import RUNTIME_SENSOR_KEYS

        return {k: getattr(self.settings, k) for k in RUNTIME_SENSOR_KEYS}

    def configure(self, changes: dict[str, Any]) -> None:
        """Apply already validated runtime changes (see ``settings.RUNTIME_SENSOR_KEYS``)."""
        s = replace(self.settings, **changes)
        self.settings = s
        self.model = s.model
        if s.noise_sigma != self.sensor_model.noise.sigma:
            self.sensor_model = replace(self.sensor_model, noise=NoiseModel(sigma=s.noise_sigma))
            self.learned.restore = False  # it was learned through the model before the change
        self.spec = self.pool.register_spec(self.sensor_model, self._fit_options(), self.name)
        self._elsewhere_strain = SIGNIFICANT_Z * s.noise_sigma
        self.gate.configure(sigma=s.noise_sigma, z=s.unchanged_z,
                            reuse_unchanged=s.reuse_unchanged)
        if self.stage is not None:
            self.stage.zeroer.detector.configure(sigma=s.noise_sigma, false_rate=s.false_rate)
            self.stage.zeroer.set_hysteresis(s.hysteresis)
        # A fit made under other settings must not be reused for new frames.
        self._end_contact()

    def _owner(self) -> learned.Owner:
        return learned.Owner(self.name, self.expected_id,
                             learned.fingerprint(self.sensor_model, self.settings.calibration,
                                                 self.description.fingerprint()))

    def _fit_options(self) -> tuple[tuple[str, Any], ...]:
        """The workers' fit options, with where this sensor's flat field is kept."""
        options = worker_fit_options(self.settings.window)
        return options if self.state_dir is None else (*options,
                                                       *self.learned.fit_options(self._owner()))

    # -- reporting ------------------------------------------------------------------------------

    def stats(self) -> SensorStats:
        """Counters and rates of this sensor now (rates in Hz, times in s / ms)."""
        return SensorStats.of(self)

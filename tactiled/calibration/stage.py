"""The calibration stage of the pipeline: raw frame -> linearised, zeroed strain + contact flag.

``Frame(raw) -> LookupTable.to_strain -> Zeroer.update (ContactDetector inside) -> frame.strain``,
one call per frame, no I/O.  Times come from the device clock (``device_time_us``), so the zeroing
time constants hold whatever the host's scheduling jitter.
"""

# A frame of counts takes the compiled path (:mod:`tactiled.calibration.fused`): the same
# arithmetic in two kernel calls instead of a dozen numpy calls, with the decisions and the state
# kept in the objects above.  The objects' own methods (the reference path) take the frames the
# kernels do not cover: the first frame and the one after a tare, a frame with non-finite values,
# a detector averaging several frames.

from __future__ import annotations

import math
import os
import struct
from collections.abc import Callable

import numpy as np

from tactiled.calibration.detection import ContactDetector
from tactiled.calibration.fused import ZeroRun, zero_frame
from tactiled.calibration.fused_reference import RUN_STATE
from tactiled.calibration.hysteresis import MIN_PEAK_SIGMAS, NOISE_MARGIN
from tactiled.calibration.lut import LookupTable
from tactiled.calibration.segments import Segments
from tactiled.calibration.zeroing import MAX_STEP_SIGMAS, Zeroer
from tactiled.errors import CalibrationError
from tactiled.frames import Frame
from tactiled.sensors.model import SensorModel

#: a run's state vector (``RUN_STATE``) as the core reads it: float64, native order
_STATE = struct.Struct(f"={len(RUN_STATE)}d")


class CalibrationStage:
    """Applies one sensor's table and zeroing to its frames.

    A frame from another sensor (``frame.sensor_id != table.sensor_id``) raises
    :class:`CalibrationError`: a table applied to the wrong sensor gives plausible-looking
    nonsense, so it must not pass silently.
    """

    def __init__(self, table: LookupTable, zeroer: Zeroer | None = None) -> None:
        self.table = table
        self.zeroer = Zeroer(table.shape) if zeroer is None else zeroer
        self.finite = False
        #: the last frame's largest strain, as the compiled path returned it (NaN: the frame
        #: took the reference path); a frame whose contact ends may be changed after it
        #: (the baseline's pull clips an implausible frame), a contact frame never is
        self.peak = math.nan
        self._runner: ZeroRun | None = None  # process_run's, kept between runs ...
        self._run_key: tuple | None = None  # ... while its constants ...
        self._run_on: tuple = ()  # ... and the arrays it writes are the stage's
        self._run_out = (np.empty(0), np.empty(0))  # a run's statistics and peaks
        #: a run's device times (s), written by its caller (tactiled.pipeline.frame_run)
        self.run_times = np.empty(0)
        if self.zeroer.shape != table.shape:
            raise ValueError(f"zeroer shape {self.zeroer.shape} != table shape {table.shape}")

    @classmethod
    def for_sensor(cls, table: LookupTable, sensor: SensorModel, sigma: float,
                   false_rate: float, average: int, hysteresis: bool) -> CalibrationStage:
        """The stage of a sensor's settings: ``table``, and a zeroer whose detector holds
        ``sensor``'s matched filter at noise ``sigma`` (strain) and ``false_rate``, averaging
        ``average`` frames; ``hysteresis``: learn the rubber's and take it out."""
        detector = ContactDetector(sigma, sensor=sensor, false_rate=false_rate, average=average)
        return cls(table, Zeroer(table.shape, detector=detector, hysteresis=hysteresis))

    def process(self, frame: Frame) -> bool:
        """Fill ``frame.strain`` (zeroed, float64) and return whether a contact is present."""
        if frame.sensor_id != self.table.sensor_id:
            raise CalibrationError(
                f"frame from sensor {frame.sensor_id}, but the calibration is for sensor "
                f"{self.table.sensor_id}"
            )
        t = frame.device_time_us * 1e-6
        z = self._compiled(frame.raw, t) if self.compiled else None
        #: the last frame's strain is known finite (the compiled path checked every value)
        self.finite = z is not None
        if z is None:  # the reference path
            self.peak = math.nan
            z = self.zeroer.update(self.table.to_strain(frame.raw), t)
        frame.strain = z
        return self.zeroer.in_contact

    #: take the compiled path where it applies (False: the reference path for every frame;
    #: the environment variable TACTILED_STAGE=reference sets False, to measure the difference)
    compiled = os.environ.get("TACTILED_STAGE", "") != "reference"

    def _compiled(self, raw: np.ndarray, t: float) -> np.ndarray | None:
        """:meth:`Zeroer.update` of ``table.to_strain(raw)`` at time ``t`` (s) by the kernels,
        or None (nothing changed) where they do not apply."""
        zr = self.zeroer
        det = zr.detector
        shape = zr.shape
        if (zr.baseline is None or zr._pending_tare or raw.shape != shape
                or raw.dtype.kind not in "ui" or not zr.baseline.flags.c_contiguous):
            return None
        seg = self.table._forward
        if not isinstance(seg, Segments):
            return None
        comp = zr.hysteresis
        dt = t - zr._last_t if zr._last_t is not None else 0.0
        f = comp.fraction
        sigma = det.sigma
        z = np.empty(shape)
        residual = np.empty(shape) if f > 0.0 else z  # (untouched without compensation)
        tmap = np.empty(det._total.size)
        state, stat, peak = zero_frame(
            raw.reshape(-1), seg._offset, seg._breaks, seg._first, seg._params, zr.baseline.reshape(-1),
            comp._peak.reshape(-1), f, math.exp(-dt / comp.tau_s) if dt > 0.0 else 1.0,
            MIN_PEAK_SIGMAS * sigma, NOISE_MARGIN * sigma, comp._active,
            det._ax, det._ay_t, det._bands, z.reshape(-1), residual.reshape(-1), tmap)
        if state < 0:
            return None
        self.peak = peak
        zr._frames += 1
        settling = t < zr._settle_until
        zr._last_t = t
        zr._residual = residual if state & 1 else None
        if f > 0.0:
            comp._active = bool(state & 2)
        # while the baseline forms, its own noise would raise false contacts: learn only
        if settling:
            contact = False
        else:
            contact = det.decide(det.average_map(tmap) if det.average > 1 else stat)
        zr._settle_frame(z, t, dt, contact)
        return z

    def can_run(self) -> bool:
        """Whether :meth:`process_run` can take the next frames (the compiled path applies:
        the baseline is formed, no tare pending, the table is piecewise)."""
        zr = self.zeroer
        return (self.compiled and zr.baseline is not None and not zr._pending_tare
                and zr._last_t is not None and zr.baseline.flags.c_contiguous
                and isinstance(self.table._forward, Segments))

    def process_run(self, raws: list[np.ndarray], times: np.ndarray, z: np.ndarray,
                    track: Callable[..., int] | None = None) -> tuple[int, list[float], list[float]]:
        """:meth:`process` for a read's frames in one call into the core
        (:class:`~tactiled.calibration.fused.ZeroRun`): ``raws`` (integer counts of this
        table's shape) at device times ``times`` (s; at least one per frame); their zeroed
        strain into ``z`` (``(N, rows, cols)`` float64).  Stops after the first frame in
        contact (that frame taken: :attr:`in_contact` is then True) and before a frame the
        compiled path does not take.  Returns ``(frames taken, statistics, largest strains)``:
        the detector's ``last_statistic`` after each frame taken and each one's largest strain.
        Call only when :meth:`can_run`; the objects' state is the same as after :meth:`process`
        of each.  ``track``: the run goes on past contact, ``track(runner, raws, times, z,
        stats, peaks, state)`` runs it (:mod:`tactiled.pipeline.tracked_run`) and returns the
        frames taken."""
        zr = self.zeroer
        det = zr.detector
        comp = zr.hysteresis
        key = (comp.fraction, comp.tau_s, det.sigma, det.enter_threshold, det.exit_threshold,
               det.average)
        if (self._runner is None or self._run_key != key or self._run_on[0] is not zr.baseline
                or self._run_on[1] is not comp._peak or self._run_on[2] is not det._ring):
            self._runner = self._new_runner()
            self._run_key, self._run_on = key, (zr.baseline, comp._peak, det._ring)
        state = self._run_state
        # (packed, not assigned through numpy: a read of one frame pays this per frame)
        _STATE.pack_into(state, 0, zr._last_t, zr._frames, zr._settle_until,
                         zr._release_until, zr.baseline_var, zr.in_contact, comp._active,
                         det._count, det._head, det.last_statistic, det.in_contact, False,
                         self.peak, False)
        stats, peaks = self._run_out
        if len(stats) < len(raws):  # (kept between runs: the core writes the first ones)
            stats, peaks = self._run_out = np.empty(len(raws)), np.empty(len(raws))
        taken = (self._runner.run(raws, times, z, stats, peaks, state) if track is None
                 else track(self._runner, raws, times, z, stats, peaks, state))
        if not taken:
            return 0, [], []
        (zr._last_t, frames, _, zr._release_until, zr.baseline_var, in_contact, active,
         count, head, det.last_statistic, det_in, residual_valid, self.peak,
         released) = _STATE.unpack_from(state)
        zr._frames, det._count, det._head = int(frames), int(count), int(head)
        zr.in_contact, det.in_contact = bool(in_contact), bool(det_in)
        if comp.fraction > 0.0:
            comp._active = bool(active)
        zr._residual = self._run_residual.copy() if residual_valid else None
        if released:
            zr._drift_t = None
        self.finite = True
        if taken < len(stats):
            stats, peaks = stats[:taken], peaks[:taken]
        return taken, stats.tolist(), peaks.tolist()

    def _new_runner(self) -> ZeroRun:
        """The stage's :class:`~tactiled.calibration.fused.ZeroRun`: its arrays (flat views,
        written in place) and its constants (``RUN_CONSTANTS``), checked once."""
        zr = self.zeroer
        det = zr.detector
        comp = zr.hysteresis
        seg = self.table._forward
        sigma = det.sigma
        constants = np.array((comp.fraction, comp.tau_s, MIN_PEAK_SIGMAS * sigma,
                              NOISE_MARGIN * sigma, sigma, det.enter_threshold,
                              det.exit_threshold, zr.tau_drift, zr.tau_release, zr.holdoff,
                              MAX_STEP_SIGMAS * sigma, det.average))
        self._run_state = np.zeros(len(RUN_STATE))
        self._run_residual = np.empty(zr.shape)
        return ZeroRun(seg._offset, seg._breaks, seg._first, seg._params,
                       zr.baseline.reshape(-1), comp._peak.reshape(-1), det._ax, det._ay_t,
                       det._bands, det._ring, det._total, self._run_residual.reshape(-1),
                       constants)

    @property
    def in_contact(self) -> bool:
        return self.zeroer.in_contact

    def tare(self) -> None:
        """Re-zero on the next frame."""
        self.zeroer.tare()

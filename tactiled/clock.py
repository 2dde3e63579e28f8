"""Frame time: the one place every stamp comes from (``Frame.time``, the estimate's ``time``,
ROS 2's ``header.stamp``).

A frame's time is when the device measured it, on the host's clock (Unix seconds).
"""

# A frame's time is when the device measured it, on the host's clock (Unix seconds), so stamps
# of different sensors and hosts compare, and a controller can compute rates from them.  Two
# cases:
#
# * **The device sends its clock** (the wire protocol's ``device_time_us``, Robotiq's
#   timestamp field, XELA's ``time``; ``Frame.clocked`` True): device time ``d`` is mapped onto
#   host time by :class:`OffsetDriftFilter`.  Each frame's arrival ``h`` (``Frame.host_time``,
#   monotonic s) is its send time plus a transport delay that is never negative, so ``h - d`` is
#   the clock offset plus that delay; the filter follows the *lower envelope* of ``h - d`` (the
#   frames that came fastest), as NTP's clock filter keeps its least-delay samples: a sample
#   below the envelope moves it down at once; the envelope's slope (the device crystal's drift
#   against the host's, parts per million) is the slope between the least-delay samples of
#   successive windows of :data:`WINDOW_S`, smoothed; at each window's end the envelope moves
#   up to that window's least-delay sample if it lies above (a device clock slower than the
#   host's), unless it lies further above than :data:`MAX_DRIFT` allows: then the host stalled
#   and every frame of the window came late, and the window is no evidence at all.  A device clock that goes back or jumps (a restarted device, a wrapped counter the
#   driver did not unwrap) starts the filter afresh.
# * **The device sends no clock** (FlexiTac, text lines without a time column; ``clocked``
#   False): the frames of one read arrived together, but were sent one period apart.  The last
#   of them is stamped with the arrival time and each earlier one a period per sequence step
#   before it; the period is ``1 / rate_hz`` of the sensor's settings, else the measured mean
#   interval between frames.
#
# Either way the stamps of a sensor **strictly increase and never go back**: where the mapping
# would put a frame at or before its predecessor (the envelope moved down, reads came late),
# the stamp advances by at least half the frame's own interval instead, so time slews back
# onto the mapping within a few frames rather than stepping back or repeating.
#
# Clear Python on purpose: this is the reference a faster frame path is checked against.

from __future__ import annotations

import math
import time
from collections.abc import Sequence

from tactiled.frames import Frame

WINDOW_S = 1.0  # device seconds per least-delay window (drift estimate)
DRIFT_GAIN = 0.25  # weight of each window's slope in the smoothed drift
MAX_DRIFT = 1e-3  # |drift| beyond 1000 ppm is no crystal: a window's slope is clipped to it
STALL_S = 1e-4  # a window's least delay this far above what drift allows: the host stalled
JUMP_S = 2.0  # |offset change| beyond this: the device clock jumped (restart), start afresh
MIN_STEP_S = 1e-6  # stamps differ by at least 1 us
SEQ_MOD = 1 << 32


class OffsetDriftFilter:
    """Device seconds -> host seconds (monotonic): the lower envelope of ``host - device``
    with its drift (see the module text).  :meth:`update` feeds a frame, :meth:`map` maps."""

    def __init__(self) -> None:
        self.anchor_d = math.nan  # device s of the envelope's anchor point
        self.anchor_x = math.nan  # host - device at that point, s
        self.drift = 0.0  # envelope slope, s per device s
        self._last_d = math.nan
        self._window_start = math.nan
        self._window_min: tuple[float, float] | None = None  # (d, x) least delay this window
        self._prev_min: tuple[float, float] | None = None  # ... of the previous window
        self.restarts = 0

    @property
    def started(self) -> bool:
        return not math.isnan(self.anchor_d)

    def offset(self, d: float) -> float:
        """The envelope at device time ``d``: host - device, s."""
        return self.anchor_x + self.drift * (d - self.anchor_d)

    def map(self, d: float) -> float:
        """Device seconds -> host monotonic seconds."""
        return d + self.offset(d)

    def update(self, d: float, h: float) -> None:
        """A frame of device time ``d`` arrived at host time ``h`` (both seconds)."""
        x = h - d
        started = self.started
        o = self.offset(d) if started else math.nan  # the envelope here (once: it is the same)
        if not started or d < self._last_d or abs(x - o) > JUMP_S:
            if started:
                self.restarts += 1
            self._restart(d, x)
            return
        self._last_d = d
        if x < o:  # a faster frame than the envelope allows: it is lower
            self.anchor_d, self.anchor_x = d, x
        if self._window_min is None or x < self._window_min[1]:
            self._window_min = (d, x)
        if d - self._window_start >= WINDOW_S:
            self._close_window()
            self._window_start = d

    def _restart(self, d: float, x: float) -> None:
        self.anchor_d, self.anchor_x, self._last_d = d, x, d
        self.drift = 0.0
        self._window_start = d
        self._window_min = (d, x)
        self._prev_min = None

    def _close_window(self) -> None:
        now, self._window_min = self._window_min, None
        assert now is not None
        excess = now[1] - self.offset(now[0])
        if excess > MAX_DRIFT * max(0.0, now[0] - self.anchor_d) + STALL_S:
            return  # every frame of the window came late (the host stalled): no evidence
        prev, self._prev_min = self._prev_min, now
        if prev is not None and now[0] > prev[0]:
            slope = (now[1] - prev[1]) / (now[0] - prev[0])
            slope = min(MAX_DRIFT, max(-MAX_DRIFT, slope))
            self.drift += DRIFT_GAIN * (slope - self.drift)
        if now[0] > self.anchor_d and excess > 0:  # the envelope rose (a slow device clock)
            self.anchor_d, self.anchor_x = now


class FrameClock:
    """The stamps of one sensor's frames (see the module text).  ``rate_hz``: the sensor's
    nominal rate, used to spread frames of a clock-less device that arrived together (None:
    measured).  ``wall_offset``: Unix - monotonic seconds (default: now's)."""

    def __init__(self, rate_hz: float | None = None, wall_offset: float | None = None) -> None:
        self.rate_hz = rate_hz
        self.wall_offset = time.time() - time.monotonic() if wall_offset is None else wall_offset
        self.filter = OffsetDriftFilter()
        self._last = -math.inf  # the last stamp, monotonic s
        self._last_d = math.nan  # the last clocked frame's device time, s
        self._last_seq: int | None = None
        self._last_h = math.nan  # arrival of the last clock-less read
        self._period = 1.0 / rate_hz if rate_hz else math.nan  # measured when not configured
        self.slewed = 0  # frames whose mapping was at or before their predecessor's stamp

    def stamp(self, frames: Sequence[Frame]) -> None:
        """Set ``frame.time`` (Unix s) on the frames of one read, in order."""
        if len(frames) == 1 and frames[0].clocked:  # a live port's read: one clocked frame
            frame = frames[0]
            frame.time = self._monotone(*self._mapped(frame)) + self.wall_offset
            return
        spread = [f for f in frames if not f.clocked]
        if not spread:  # every frame carries the device's clock (the common case): mapped
            for frame in frames:
                t, floor = self._mapped(frame)
                frame.time = self._monotone(t, floor) + self.wall_offset
            return
        times = self._spread(spread)
        for frame in frames:
            if frame.clocked:
                t, floor = self._mapped(frame)
            else:
                t, floor = times[id(frame)], 0.5 * self._known_period()
            frame.time = self._monotone(t, floor) + self.wall_offset

    # -- a device clock ---------------------------------------------------------------------

    def _mapped(self, frame: Frame) -> tuple[float, float]:
        d = frame.device_time_us * 1e-6
        self.filter.update(d, frame.host_time)
        step = d - self._last_d if d > self._last_d else 0.0
        self._last_d = d
        return min(self.filter.map(d), frame.host_time), 0.5 * step

    # -- no device clock ----------------------------------------------------------------------

    def _known_period(self) -> float:
        return self._period if math.isfinite(self._period) else 0.0

    def _spread(self, frames: Sequence[Frame]) -> dict[int, float]:
        """Arrival time spread back over frames that arrived together, by seq and period."""
        h = frames[-1].host_time
        last_seq = frames[-1].seq
        if self.rate_hz is None and self._last_seq is not None and h > self._last_h:
            steps = (last_seq - self._last_seq) % SEQ_MOD
            if 0 < steps < SEQ_MOD // 2:
                measured = (h - self._last_h) / steps
                self._period = measured if math.isnan(self._period) else (
                    self._period + 0.05 * (measured - self._period))
        self._last_seq, self._last_h = last_seq, h
        period = self._known_period()
        out = {}
        for i, f in enumerate(frames):
            steps = (last_seq - f.seq) % SEQ_MOD
            if steps > 4 * len(frames):  # the seq restarted within the read: count frames
                steps = len(frames) - 1 - i
            out[id(f)] = f.host_time - steps * period
        return out

    # -- never back, never the same --------------------------------------------------------------

    def _monotone(self, t: float, floor: float) -> float:
        least = self._last + max(floor, MIN_STEP_S)
        if t < least:
            self.slewed += 1
            t = least
        self._last = t
        return t

"""What the vendor formats' framers share: their counters, and a seq and device clock for
formats that send neither.

Each framer is a :class:`tactiled.sources.Framer` (pure, no I/O, like
:class:`tactiled.frames.FrameDecoder`) and counts everything it drops in :class:`FramerStats`,
whose counters that mean the same as the wire-format decoder's carry the same names
(``crc_errors``, ``truncated``, ``oversize``, ``lost``...).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from tactiled.frames import Frame, NativeFraming

SEQ_MOD = 1 << 32  # seq numbers wrap as the wire format's uint32 does


@dataclass
class FramerStats:
    """Counters of a vendor framer; they only grow (``reset`` keeps them).

    Every rejected unit (a frame, packet, line or message) is counted in exactly one of
    ``truncated``, ``length_errors``, ``oversize``, ``crc_errors`` or ``parse_errors``;
    ``discarded`` counts the bytes dropped while looking for the start of a frame.
    """

    frames: int = 0  # frames delivered
    bytes: int = 0  # bytes fed
    resyncs: int = 0  # times a good frame followed one or more rejected units
    discarded: int = 0  # bytes skipped looking for a frame start (garbage, torn frames)
    truncated: int = 0  # shorter than the format says (a torn frame, a short line)
    length_errors: int = 0  # longer than the format says, or a wrong count of values
    oversize: int = 0  # beyond the format's longest unit: dropped unread, memory bounded
    crc_errors: int = 0  # checksum mismatch (formats with a checksum)
    parse_errors: int = 0  # not what the format allows (non-numeric text, unknown field...)
    ambiguous: int = 0  # FlexiTac: two frame phases fit the stream, waited for the data to tell
    lost: int = 0  # frames missing according to the device's own sequence numbers
    duplicated: int = 0  # frames dropped because they repeat the previous sequence number
    restarts: int = 0  # the device's sequence went backwards (it restarted)

    @property
    def rejected(self) -> int:
        """All units rejected as malformed, of any kind."""
        return (self.truncated + self.length_errors + self.oversize + self.crc_errors
                + self.parse_errors)


class FramerBase:
    """Counters, resync bookkeeping and the generated clock; subclasses implement ``feed``."""

    def __init__(self) -> None:
        self.stats = FramerStats()
        self._buf = bytearray()  # bytes of a unit not complete yet
        self._in_error = False
        self._seq = 0
        self._t0: float | None = None
        self._last_seq: int | None = None

    @property
    def buffered(self) -> int:
        """Bytes of an incomplete unit held between calls."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget partial data and sequence history (the port was reopened); a unit cut short
        by the unplug counts as ``truncated``."""
        if self._buf:
            self.stats.truncated += 1
            self.stats.discarded += len(self._buf)
            self._buf.clear()
        self._in_error = False
        self._last_seq = None

    def _reject(self, kind: str, n: int = 1) -> None:
        setattr(self.stats, kind, getattr(self.stats, kind) + n)
        self._in_error = True

    def _discard(self, n: int) -> None:
        if n > 0:
            self.stats.discarded += n
            self._in_error = True

    def _accept(self, frame: Frame) -> Frame:
        """Count a frame about to be delivered."""
        self.stats.frames += 1
        if self._in_error:
            self.stats.resyncs += 1
            self._in_error = False
        return frame

    def _track_seq(self, seq: int) -> bool:
        """Gaps and repeats of a device's own sequence number; False: a repeat, drop it."""
        last = self._last_seq
        if last is not None:
            step = (seq - last) % SEQ_MOD
            if step == 0:
                self.stats.duplicated += 1
                return False
            if step < SEQ_MOD // 2:
                self.stats.lost += step - 1
            else:
                self.stats.restarts += 1
        self._last_seq = seq
        return True

    def _next_seq(self) -> int:
        """A generated sequence number, for formats that send none."""
        seq = self._seq
        self._seq = (seq + 1) % SEQ_MOD
        return seq

    def _host_clock_us(self, host_time: float) -> int:
        """Device time for formats with no clock: microseconds of host receive time since the
        first frame (the zeroing time constants run on it)."""
        if self._t0 is None:
            self._t0 = host_time
        return max(0, round((host_time - self._t0) * 1e6))


class CoreFramer(Protocol):
    """A vendor framer of the compiled core as its binding shows it (core/framer_binding.hpp's
    ``Vendor``): frames as ``(seq, device_time_us, raw)`` tuples, counters as a list in
    :class:`FramerStats`' field order."""

    @property
    def buffered(self) -> int:
        """Bytes of an incomplete unit held between calls."""

    def feed(self, data: bytes, host_time: float) -> list[tuple[int, int, np.ndarray]]:
        """The frames ``data`` completes."""

    def reset(self) -> None:
        """Forget partial data."""

    def counters(self) -> list[int]:
        """:class:`FramerStats`' counters, in its field order."""


class NativeFramer(NativeFraming):
    """A vendor framer whose work runs in the compiled core (``core``: one of
    ``tactiled._core``'s framers, whose ``feed(bytes, host_time)`` returns ``(seq,
    device_time_us, raw)`` tuples): the same frames and counters as its Python reference for
    the same bytes, one call into the core per ``feed``."""

    STATS = FramerStats

    def __init__(self, core: CoreFramer, shape: tuple[int, int]) -> None:
        super().__init__(core)
        self.shape = shape

    def feed(self, data: bytes, host_time: float | None = None) -> list[Frame]:
        """Consume ``data``; return the frames it completes."""
        if not data:
            return []
        t = now_if_none(host_time)
        return [Frame(seq, t_us, raw, 0, t) for seq, t_us, raw in self._core.feed(data, t)]


def now_if_none(host_time: float | None) -> float:
    """``host_time``, or ``time.monotonic()`` when the caller gave none."""
    return time.monotonic() if host_time is None else host_time

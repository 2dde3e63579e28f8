"""FlexiTac mats: ``flexitac:///dev/ttyUSB0?rows=12&cols=32`` (default 2000000 baud).

Each frame is the marker ``0xAA 0x55`` then ``rows*cols`` bytes (10-bit readings >> 2), with no
length, seq, clock or checksum.  The framer delivers a frame only when the next marker follows
where due (one frame of look-ahead), so a marker inside the data is never taken for a start.
seq is generated; the device time is the host receive time.
"""
# The format (the FlexiTac Python package, repository WT-MM/PyFlexiTac: flexitac/protocol.py
# FrameParser and flexitac/firmware/template.ino): the firmware's loop() writes 0xAA 0x55 and
# then ROW_COUNT * COLUMN_COUNT bytes, row by row, each analogRead(...) >> 2 (a 10-bit reading
# as uint8).  Serial.begin(2000000); the template's array is 12 x 32.
#
# A marker inside the data: 0xAA (170) then 0x55 (85) is an ordinary pair of readings, so the
# marker alone cannot say where a frame starts.  A frame is accepted only when the next marker
# follows at exactly 2 + rows*cols bytes (a frame is delivered one frame period late).  In step,
# the framer jumps from marker to marker and never looks inside the data.  To get in step (at
# start, after garbage or a torn frame) it looks at every marker in one frame's span: exactly one
# that the next marker confirms is taken; none, and the bytes up to the next marker are
# discarded; two or more (a still image holding AA 55 at the same place in every frame confirms
# that phase too), and it counts ambiguous, drops one frame's worth of bytes and looks again, so
# it never guesses: the data's noise tells the phases apart within frames.  A frame whose
# successor's marker is not where due is never delivered: truncated if a marker came earlier,
# length_errors otherwise.  One torn unit is told apart: a lone 0xAA right where the marker is
# due, then a whole marker (reset after the marker's first byte) confirms the frame before it,
# and the lone byte counts as truncated.  So a torn frame costs that frame alone (plus, until in
# step, the one frame needed to get in step).

from __future__ import annotations

from typing import ClassVar

import numpy as np

from tactiled import native
from tactiled.sensors.devices import DeviceArray, device_array
from tactiled.frames import Frame
from tactiled.sources import Framer, SourceURL
from tactiled_drivers.plumbing.framing import FramerBase, NativeFramer, now_if_none
from tactiled_drivers.serial import SerialSource

MARKER = b"\xaa\x55"
DEFAULT_ROWS = 12
DEFAULT_COLS = 32
DEFAULT_BAUD = 2_000_000
MAX_CELLS = 4096  # rows * cols, as the wire format's MAX_TACTELS


class FlexiTacFramer(FramerBase):
    """``AA 55`` + ``rows*cols`` uint8 -> frames of ``uint16`` counts; see the module text."""

    def __init__(self, rows: int = DEFAULT_ROWS, cols: int = DEFAULT_COLS) -> None:
        super().__init__()
        if not (rows >= 1 and cols >= 1 and rows * cols <= MAX_CELLS):
            raise ValueError(f"FlexiTac array {rows}x{cols}: need 1..{MAX_CELLS} cells")
        self.shape = (rows, cols)
        self.period = 2 + rows * cols  # bytes from one marker to the next
        self._synced = False

    def reset(self) -> None:
        super().reset()
        self._synced = False

    def feed(self, data: bytes, host_time: float | None = None) -> list[Frame]:
        """Consume ``data``; return the frames it confirmed (see the module docstring)."""
        if not data:
            return []
        self.stats.bytes += len(data)
        self._buf += data
        t = now_if_none(host_time)
        frames: list[Frame] = []
        buf, period = self._buf, self.period
        while True:
            if self._synced:
                if len(buf) < period + 2:
                    break
                if buf[period:period + 2] == MARKER:
                    frames.append(self._frame(bytes(buf[2:period]), t))
                    del buf[:period]
                    continue
                if buf[period] == MARKER[0] and len(buf) < period + 3:
                    break  # a marker torn after its first byte? one more byte tells
                if self._torn_marker(period):
                    frames.append(self._frame(bytes(buf[2:period]), t))
                    del buf[:period]
                    self._reject("truncated")
                    self._drop(1)
                    continue
                self._synced = False
                early = buf.find(MARKER, 2, period + 1)
                self._reject("truncated" if early >= 0 else "length_errors")
                self._drop(early if early >= 0 else period)
                continue
            if not self._find_phase():
                break
        return frames

    def _find_phase(self) -> bool:
        """Out of step: discard what cannot start a frame, or step in; False to wait for more."""
        buf, period = self._buf, self.period
        first = buf.find(MARKER)
        if first < 0:
            keep = 1 if buf[-1:] == MARKER[:1] else 0
            self._drop(len(buf) - keep)
            return False
        self._drop(first)
        if len(buf) < 2 * period + 1:  # every phase of one span checked against its successor
            return False
        phases = []
        at = 0
        while 0 <= at < period:
            if buf[at + period:at + period + 2] == MARKER or self._torn_marker(at + period):
                phases.append(at)
            at = buf.find(MARKER, at + 1, period + 1)
        if len(phases) == 1:
            self._drop(phases[0])
            self._synced = True
        elif not phases:
            nxt = buf.find(MARKER, 1)
            self._drop(nxt if nxt > 0 else len(buf) - 1)
        else:
            self.stats.ambiguous += 1
            self._drop(period)
        return True

    def _torn_marker(self, i: int) -> bool:
        """``0xAA`` at ``i`` then a whole marker: the device reset right after the first byte
        of a marker, so the frame before ``i`` is whole (the lone ``0xAA`` is the torn unit)."""
        return self._buf[i:i + 1] == MARKER[:1] and self._buf[i + 1:i + 3] == MARKER

    def _drop(self, n: int) -> None:
        if n > 0:
            del self._buf[:n]
            self._discard(n)

    def _frame(self, payload: bytes, host_time: float) -> Frame:
        raw = np.frombuffer(payload, dtype=np.uint8).reshape(self.shape).astype(np.uint16)
        return self._accept(Frame(seq=self._next_seq(), device_time_us=self._host_clock_us(host_time),
                                  raw=raw, host_time=host_time, clocked=False))


class NativeFlexiTacFramer(NativeFramer):
    """:class:`FlexiTacFramer` with its work in the compiled core (core/flexitac.cpp); the Python
    class is the reference (tests/drivers/test_vendor_framers.py holds the two equal)."""

    def __init__(self, rows: int = DEFAULT_ROWS, cols: int = DEFAULT_COLS) -> None:
        from tactiled import _core  # (built by the install, whichever path is selected)

        ref = FlexiTacFramer(rows, cols)  # (checks the arguments)
        super().__init__(_core.FlexiTacFramer(rows, cols), ref.shape)
        self.period = ref.period  # bytes from one marker to the next


def encode(raw: np.ndarray) -> bytes:
    """One frame as the firmware sends it: the marker, then the counts row by row as uint8.
    ``ValueError`` for counts outside 0..255."""
    a = np.asarray(raw)
    if a.ndim != 2 or a.size == 0 or a.min() < 0 or a.max() > 255:
        raise ValueError(f"FlexiTac counts must be a 2-D array of 0..255, got {a.shape}")
    return MARKER + a.astype(np.uint8).tobytes()


class FlexiTacSource(SerialSource):
    """A FlexiTac mat on a serial port (the serial driver's reader thread and reconnection)."""

    PARAMS: ClassVar[frozenset[str]] = SerialSource.PARAMS | {"rows", "cols"}
    DEFAULT_BAUD: ClassVar[int] = DEFAULT_BAUD

    def __init__(self, url: str | SourceURL, *, decoder: Framer | None = None) -> None:
        super().__init__(url, decoder=decoder)  # type: ignore[arg-type]

    def _new_decoder(self) -> FlexiTacFramer | NativeFlexiTacFramer:
        self.rows = self.url.get_int("rows", DEFAULT_ROWS, minimum=1, maximum=255)
        self.cols = self.url.get_int("cols", DEFAULT_COLS, minimum=1, maximum=255)
        framer = FlexiTacFramer if native.core is None else NativeFlexiTacFramer
        try:
            return framer(self.rows, self.cols)
        except ValueError as err:
            raise ValueError(f"{self.url.url!r}: {err}") from None

    def sent_id(self) -> int:
        return 0  # a FlexiTac frame carries no id

    def device_array(self) -> DeviceArray:
        return device_array("flexitac", self.url.get_int("rows", DEFAULT_ROWS),
                            self.url.get_int("cols", DEFAULT_COLS))

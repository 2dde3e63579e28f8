"""Text lines of integers: ``lines:///dev/ttyACM0?baud=115200&rows=8&cols=8&sep=,``.

One frame per line of ``rows*cols`` integers, row by row, separated by ``sep`` (``,``,
``space`` or ``tab``), as a firmware printing its matrix with ``Serial.print`` sends.
``time_col=0`` says the line starts with the device's clock (``time_unit`` ``ms``, ``us`` or
``s``); else the device time is the host receive time.  Bad lines are counted and skipped.
:class:`NativeLinesFramer` does the same in the compiled core.
"""
# ``\r\n`` or ``\n`` ends a line; ``space`` means any run of spaces; the default time_unit, ms,
# matches Arduino's millis().  The seq is generated.
# Bad lines: fewer values than rows*cols (truncated), more (length_errors), a value that is not
# an integer or a negative time (parse_errors), a line longer than MAX_LINE bytes (oversize: its
# bytes are dropped as they arrive, up to the next newline, so a device that never sends one
# costs no memory).  Blank lines are ignored; a trailing separator is allowed.  Counts are the
# device's integers as they are (int64), and a clock must fit int64 in microseconds (else
# parse_errors).  The calibration's counts domain is 0..65535, and a recording stores 0..65535
# only.

from __future__ import annotations

from typing import ClassVar

import numpy as np

from tactiled import native
from tactiled.sensors.devices import DeviceArray, device_array
from tactiled.frames import Frame
from tactiled.sources import Framer, SourceURL
from tactiled_drivers.plumbing.framing import FramerBase, NativeFramer, now_if_none
from tactiled_drivers.serial import SerialSource

DEFAULT_BAUD = 115_200
MAX_CELLS = 4096
#: Longest line accepted, bytes: 4096 values of up to 20 characters and a separator each.
MAX_LINE = 21 * (MAX_CELLS + 1)
SEPARATORS = {",": b",", "space": None, " ": None, "tab": b"\t", "\t": b"\t"}
TIME_UNITS_US = {"ms": 1000, "us": 1, "s": 1_000_000}


class LinesFramer(FramerBase):
    """Lines of ``rows*cols`` integers -> frames of ``int64`` counts; see the module text."""

    def __init__(self, rows: int, cols: int, sep: str = ",", time_col: bool = False,
                 time_unit: str = "ms") -> None:
        super().__init__()
        if not (rows >= 1 and cols >= 1 and rows * cols <= MAX_CELLS):
            raise ValueError(f"array {rows}x{cols}: need 1..{MAX_CELLS} cells")
        if sep not in SEPARATORS:
            raise ValueError(f"sep {sep!r} is not one of ',', 'space', 'tab'")
        if time_unit not in TIME_UNITS_US:
            raise ValueError(f"time_unit {time_unit!r} is not one of {', '.join(TIME_UNITS_US)}")
        self.shape = (rows, cols)
        self.sep = SEPARATORS[sep]
        self.time_col = time_col
        self.time_scale = TIME_UNITS_US[time_unit]
        self._skipping = False  # inside an oversize line: drop up to the next newline

    def reset(self) -> None:
        super().reset()
        self._skipping = False

    def feed(self, data: bytes, host_time: float | None = None) -> list[Frame]:
        """Consume ``data``; return a frame per complete good line."""
        if not data:
            return []
        data = bytes(data)
        self.stats.bytes += len(data)
        if self._skipping:
            end = data.find(b"\n")
            if end < 0:
                return []
            data = data[end + 1:]
            self._skipping = False
        if b"\n" not in data:
            self._buf += data
            self._check_bound()
            return []
        lines = data.split(b"\n")
        lines[0] = bytes(self._buf) + lines[0]
        self._buf = bytearray(lines.pop())
        t = now_if_none(host_time)
        frames = []
        for line in lines:
            if len(line) > MAX_LINE:
                self._reject("oversize")
                continue
            frame = self._parse(line.strip(), t)
            if frame is not None:
                frames.append(self._accept(frame))
        self._check_bound()
        return frames

    def _check_bound(self) -> None:
        if len(self._buf) > MAX_LINE:
            self._buf.clear()
            self._skipping = True
            self._reject("oversize")

    def _parse(self, line: bytes, host_time: float) -> Frame | None:
        if not line:
            return None
        if self.sep is not None and line.endswith(self.sep):  # "1,2,3," as print loops leave it
            line = line[:-1]
        fields = line.split(self.sep)
        want = self.shape[0] * self.shape[1] + int(self.time_col)
        if len(fields) != want:
            self._reject("truncated" if len(fields) < want else "length_errors")
            return None
        try:
            values = [int(f, 10) for f in fields]
        except ValueError:
            self._reject("parse_errors")
            return None
        if self.time_col:
            stamp = values.pop(0) * self.time_scale
            if not 0 <= stamp < 1 << 63:
                self._reject("parse_errors")
                return None
        else:
            stamp = self._host_clock_us(host_time)
        try:
            raw = np.array(values, dtype=np.int64).reshape(self.shape)
        except OverflowError:
            self._reject("parse_errors")
            return None
        return Frame(seq=self._next_seq(), device_time_us=stamp, raw=raw, host_time=host_time,
                     clocked=self.time_col)


class NativeLinesFramer(NativeFramer):
    """:class:`LinesFramer` with its work in the compiled core (core/lines.cpp); the Python class
    is the reference (tests/drivers/test_lines_core.py holds the two equal)."""

    def __init__(self, rows: int, cols: int, sep: str = ",", time_col: bool = False,
                 time_unit: str = "ms") -> None:
        from tactiled import _core  # (built by the install, whichever path is selected)

        ref = LinesFramer(rows, cols, sep, time_col, time_unit)  # (checks the arguments)
        super().__init__(_core.LinesFramer(rows, cols, " " if ref.sep is None else ref.sep.decode(),
                                           time_col, ref.time_scale), ref.shape)


def encode(raw: np.ndarray, sep: str = ",", time_ms: int | None = None) -> bytes:
    """One frame as a firmware prints it: the counts row by row, ``sep``-separated, ``\\r\\n``
    (``time_ms``: a leading clock column)."""
    joiner = {",": ",", "space": " ", "tab": "\t"}[sep]
    values = [str(int(v)) for v in np.asarray(raw).ravel()]
    if time_ms is not None:
        values.insert(0, str(int(time_ms)))
    return (joiner.join(values) + "\r\n").encode("ascii")


class LinesSource(SerialSource):
    """Text lines on a serial port (the serial driver's reader thread and reconnection)."""

    PARAMS: ClassVar[frozenset[str]] = SerialSource.PARAMS | {
        "rows", "cols", "sep", "time_col", "time_unit"}
    DEFAULT_BAUD: ClassVar[int] = DEFAULT_BAUD

    def __init__(self, url: str | SourceURL, *, decoder: Framer | None = None) -> None:
        super().__init__(url, decoder=decoder)  # type: ignore[arg-type]

    def _new_decoder(self) -> LinesFramer | NativeLinesFramer:
        u = self.url
        for name in ("rows", "cols"):
            if name not in u.params:
                raise ValueError(f"{u.url!r}: lines:// needs rows= and cols= (the array's shape)")
        self.rows = u.get_int("rows", 0, minimum=1, maximum=MAX_CELLS)
        self.cols = u.get_int("cols", 0, minimum=1, maximum=MAX_CELLS)
        time_col = u.get_int("time_col", -1, minimum=0, maximum=0) == 0
        framer = LinesFramer if native.core is None else NativeLinesFramer
        try:
            return framer(self.rows, self.cols, sep=u.get_str("sep", ","),
                          time_col=time_col, time_unit=u.get_str("time_unit", "ms"))
        except ValueError as err:
            raise ValueError(f"{u.url!r}: {err}") from None

    def device_array(self) -> DeviceArray:
        return device_array("lines", self.rows, self.cols)

    def sent_id(self) -> int:
        return 0  # a line carries no id

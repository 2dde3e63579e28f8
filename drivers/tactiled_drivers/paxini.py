"""PaXini PX-6AX 3-axis tactile modules on a serial port:
``paxini:///dev/ttyACM0?module=0&rows=10&cols=12&checksum=1`` (921600 baud by default).

The module answers requests and sends nothing unasked.  A frame is one answer to the
distributed-force request: ``Frame.taxels`` ``(rows, cols, 3)`` (x, y, z per point, 0.1 N
counts offset by :data:`ZERO_COUNTS`), checked prefix and LRC; seq and device time are made on
the host.
"""
# The request, as PaXini's reference tool writes it (adnan-saood/paxini_ros2,
# helper_scripts/UI_sensor.py, get_commands; the same bytes in that repository's
# paxini_hardware/src/tactile_sensor.cpp, distributed_command):
#
#     55 AA | 09 00 | ADDR | 00 | FB | 0E 04 00 00 | LEN_lo LEN_hi | LRC
#
# ADDR the module number + 1, FB a read, 0x040E (1038) the register of the points
# (Gabriel-Ning/paxini_driver, paxini_driver.py, reads the same address), LEN the payload's
# length in bytes, 3 per point, little-endian; LRC the two's complement of the sum of every byte
# before it.  The answer is a 14-byte prefix, the payload, and its LRC:
#
#     AA 55 | N_lo N_hi | ADDR | 00 | FB | 0E 04 00 00 | LEN_lo LEN_hi | STATUS | payload | LRC
#
# The public drivers take the payload at offset 14 behind AA 55 and read no further
# (tactile_sensor.cpp, read_response: 14 + LEN bytes); this driver also checks what the request
# implies of the prefix (N counts the bytes from ADDR to the payload's end, 10 + LEN; address,
# function, register and length echo the request's; status 0) and, unless ``checksum=0``, the
# LRC byte after the payload, so a torn or corrupt answer is counted and dropped, never read as
# a frame.  The payload is x, y, z
# per point: x and y signed 8-bit, z unsigned 8-bit, in 0.1 N (UI_sensor.py,
# parse_distributed_force).  Points are in order, row-major (rows x cols = points), as signed
# counts offset by ZERO_COUNTS to fit the wire's unsigned 16 bits (raw, the z counts the 1-axis
# path reads, likewise).
# Counters: prefix mismatch (parse_errors), LRC mismatch (crc_errors), cut short by a newer
# header (truncated), length not the request's (length_errors); bytes before a header are
# discarded.

from __future__ import annotations

import asyncio
import logging
from typing import ClassVar

import numpy as np
import serial

from tactiled.sensors.devices import DeviceArray, device_array
from tactiled.frames import Frame
from tactiled.sources import SourceURL
from tactiled_drivers.plumbing.framing import FramerBase, now_if_none
from tactiled_drivers.serial import SerialSource

log = logging.getLogger(__name__)

DEFAULT_BAUD = 921600
REQUEST_HEAD = b"\x55\xaa"
RESPONSE_HEAD = b"\xaa\x55"
READ = 0xFB
REGISTER = 0x040E  # the points' register, little-endian on the wire
PREFIX = 14
#: Signed readings are sent offset by this, so that they are unsigned 16-bit counts.
ZERO_COUNTS = 0x8000
DEFAULT_POINTS = 120
#: An answer not complete after this long is asked for again (s).
ANSWER_TIMEOUT_S = 0.05


def lrc(data: bytes) -> int:
    """The two's complement of the byte sum: ``(sum(data) + lrc) % 256 == 0``."""
    return (-sum(data)) & 0xFF


def request(module: int, points: int) -> bytes:
    """The distributed-force request to module ``module`` (0-based) for ``points`` points."""
    n = 3 * points
    body = (REQUEST_HEAD + bytes((0x09, 0x00, module + 1, 0x00, READ))
            + REGISTER.to_bytes(4, "little") + n.to_bytes(2, "little"))
    return body + bytes((lrc(body),))


def response(module: int, xyz: np.ndarray, status: int = 0, checksum: bool = True) -> bytes:
    """A module's answer carrying ``xyz`` ``(points, 3)``: x, y in [-128, 127], z in [0, 255];
    ``checksum=False``: without the LRC byte after the payload."""
    a = np.asarray(xyz, dtype=np.int64).reshape(-1, 3)
    payload = np.empty(a.shape, dtype=np.uint8)
    payload[:, :2] = (a[:, :2] & 0xFF).astype(np.uint8)
    payload[:, 2] = a[:, 2].astype(np.uint8)
    data = payload.tobytes()
    body = (RESPONSE_HEAD + (10 + len(data)).to_bytes(2, "little")
            + bytes((module + 1, 0x00, READ)) + REGISTER.to_bytes(4, "little")
            + len(data).to_bytes(2, "little") + bytes((status,)) + data)
    return body + bytes((lrc(body),)) if checksum else body


class PaxiniFramer(FramerBase):
    """Answers of one module -> frames ``(rows, cols, 3)``; never raises.  ``checksum``: the
    answers end with an LRC byte (False: with their payload)."""

    def __init__(self, module: int = 0, rows: int = 10, cols: int = 12,
                 checksum: bool = True) -> None:
        super().__init__()
        if not 0 <= module < 255:
            raise ValueError(f"module must be 0..254, got {module}")
        if rows < 1 or cols < 1 or 3 * rows * cols > 0xFFFF - 10:
            raise ValueError(f"rows x cols must be 1..21841 points, got {rows}x{cols}")
        self.module = module
        self.shape = (rows, cols)
        self.length = 3 * rows * cols
        self.checksum = checksum
        self.size = PREFIX + self.length + (1 if checksum else 0)
        self._expect = response(module, np.zeros((rows * cols, 3)))[2:PREFIX - 1]
        self.answers = 0  # whole answers seen, good or bad: the source asks again after each

    def feed(self, data: bytes, host_time: float | None = None) -> list[Frame]:
        self.stats.bytes += len(data)
        self._buf += data
        out: list[Frame] = []
        buf = self._buf
        while True:
            start = buf.find(RESPONSE_HEAD)
            if start < 0:
                keep = 1 if buf[-1:] == RESPONSE_HEAD[:1] else 0
                self._discard(len(buf) - keep)
                del buf[:len(buf) - keep]
                break
            if start:
                self._discard(start)
                del buf[:start]
            later = self._later(buf)
            if later is None:
                break  # a header inside it may begin the next answer: its prefix will tell
            if later:  # the next answer began before this one ended: this one is torn
                self._drop_unit("truncated", later)
                continue
            if len(buf) < self.size:
                break
            unit = bytes(buf[:self.size])
            kind = self._check(unit)
            if kind is None:
                del buf[:self.size]
                self.answers += 1
                out.append(self._accept(self._frame(unit, now_if_none(host_time))))
            else:
                self._drop_unit(kind, len(RESPONSE_HEAD))
        return out

    def _later(self, buf: bytearray) -> int | None:
        """Where an answer with this module's prefix begins inside the one at 0 (0: nowhere;
        None: a header whose prefix has not all arrived yet)."""
        end = min(len(buf), self.size)
        i = buf.find(RESPONSE_HEAD, 2, end)
        while i > 0:
            seen = bytes(buf[i + 2:i + PREFIX - 1])
            if seen == self._expect[:len(seen)]:
                return i if len(seen) == len(self._expect) else None
            i = buf.find(RESPONSE_HEAD, i + 1, end)
        return 0

    def _drop_unit(self, kind: str, n: int) -> None:
        self._reject(kind)
        self.answers += 1
        self.stats.discarded += n
        del self._buf[:n]

    def _check(self, unit: bytes) -> str | None:
        if unit[2:PREFIX - 1] != self._expect:
            n = int.from_bytes(unit[2:4], "little")
            return "length_errors" if n != 10 + self.length else "parse_errors"
        if unit[PREFIX - 1] != 0:
            return "parse_errors"
        if self.checksum and lrc(unit[:-1]) != unit[-1]:
            return "crc_errors"
        return None

    def _frame(self, unit: bytes, host_time: float) -> Frame:
        p = np.frombuffer(unit, dtype=np.uint8, count=self.length, offset=PREFIX).reshape(-1, 3)
        xyz = np.empty(p.shape, dtype=np.int32)
        xyz[:, :2] = p[:, :2].astype(np.int8)
        xyz[:, 2] = p[:, 2]
        counts = (xyz + ZERO_COUNTS).astype(np.uint16).reshape(*self.shape, 3)
        return Frame(seq=self._next_seq(), device_time_us=self._host_clock_us(host_time),
                     raw=counts[..., 2].copy(), sensor_id=self.module, host_time=host_time,
                     taxels=counts)


class PaxiniSource(SerialSource):
    """A PX-6AX module on a serial port: asks for the points, reads the answer, asks again."""

    PARAMS: ClassVar[frozenset[str]] = SerialSource.PARAMS | {"module", "rows", "cols",
                                                               "checksum"}
    DEFAULT_BAUD: ClassVar[int] = DEFAULT_BAUD

    def __init__(self, url: str | SourceURL, *, decoder: PaxiniFramer | None = None) -> None:
        super().__init__(url, decoder=decoder)  # type: ignore[arg-type]
        self._asked_for = -1  # the framer's answer count when the last request went out
        self._asked_at = 0.0
        self.requests = 0

    def _new_decoder(self) -> PaxiniFramer:
        u = self.url
        self.module = u.get_int("module", 0, minimum=0, maximum=254)
        self.rows = u.get_int("rows", 10, minimum=1, maximum=255)
        self.cols = u.get_int("cols", 12, minimum=1, maximum=255)
        try:
            return PaxiniFramer(self.module, self.rows, self.cols,
                                checksum=u.get_bool("checksum", True))
        except ValueError as err:
            raise ValueError(f"{u.url!r}: {err}") from None

    def device_array(self) -> DeviceArray:
        return device_array("paxini", self.url.get_int("rows", 10), self.url.get_int("cols", 12))

    def _ask(self, port: serial.Serial) -> None:
        port.write(request(self.module, self.rows * self.cols))
        self.requests += 1
        self._asked_for = self.decoder.answers  # type: ignore[attr-defined]
        self._asked_at = asyncio.get_running_loop().time()

    async def _read_internal(self) -> bytes:
        while self.is_open:
            port, reader = self._port, self._reader
            if port is None or reader is None:
                return await super()._read_internal()  # reconnects, then returns bytes
            loop = asyncio.get_running_loop()
            answered = self.decoder.answers != self._asked_for  # type: ignore[attr-defined]
            if answered or loop.time() - self._asked_at > ANSWER_TIMEOUT_S:
                try:
                    self._ask(port)
                except (OSError, serial.SerialException) as err:
                    self._lost(err)
                    continue
            try:
                return await asyncio.wait_for(super()._read_internal(), ANSWER_TIMEOUT_S)
            except TimeoutError:
                continue  # no answer: ask again
        return b""

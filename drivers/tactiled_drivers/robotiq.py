"""Robotiq TSF-85 fingertip sensors: ``robotiq:///dev/rq_tsf85_0?finger=0`` (115200 baud).

A frame is the 7x4 static array of the URL's finger, with the finger's other fields (dynamic,
accelerometer, gyroscope, magnetometer, temperature, timestamp) as ``extras``; device time is
the finger's timestamp in ms (unwrapped) once one has come, else the host time; ``sensor_id`` is
the finger number.  Both fingers share one port through :class:`_SharedPort`.
"""
# The format, from Robotiq's ``tactile_sensors`` repository (``tactile_sensor_ui/src/
# communicator.cpp``, ``sdk_cpp/RobotiqTactileSensor.cpp``, ``sdk_cpp/finger_data.h``,
# ``sensor_quickstart/protocol.py``) and the ``pyrobotiqtactile`` package (``protocol.py``):
# - a packet is 0x9A, a CRC byte, a command byte, a data length, then that many data bytes
#   (at most 60: ``uint8_t data[60]`` of ``struct UsbPacket``);
# - the data is a run of fields: a type byte (high nibble the sensor type, bits 2-3 the finger,
#   bits 0-1 an index) and its big-endian payload: static tactile 0x10, 28 uint16 (7 rows x 4
#   columns, row by row); dynamic tactile 0x20, 1 int16; accelerometer 0x30 and gyroscope 0x40,
#   3 int16; magnetometer 0x50, 3 int16 (the Python sources); temperature 0x60, 1 int16;
#   timestamp 0x70, 1 uint16 in Robotiq's code, 1 uint64 in ``pyrobotiqtactile``;
# - the host starts streaming with command 0x58 (auto-send) and one data byte, the period in ms,
#   and stops it with period 0.
#
# The CRC byte is not checked, as in every source: Robotiq's ``calcCrc8`` is a placeholder that
# returns the packet's own CRC byte ("TODO: calculate CRC8"; the SDK: "the autosend command
# currently works without a valid CRC"), and ``pyrobotiqtactile`` sends 0.  So ``crc_errors``
# stays 0 and commands go out with CRC 0.  The structure stands in for a checksum: a packet is
# accepted only when its length is at most 60, its fields, each of a known type, end exactly at
# its end (a timestamp is tried as uint16, then uint64, so both firmware readings parse), and
# what follows it is the start of another packet (0x9A, length <= 60 and, with data, a known
# field type) or a pause (the packet ends where the bytes read so far end and all of it came in
# that one read) or garbage (bytes that start no packet, with no packet start inside the packet
# either).  A packet whose bytes span reads and end exactly at the last read's end waits for the
# next byte.  Anything else is rejected (``length_errors`` for a length over 60, ``parse_errors``
# for fields that do not fit, ``truncated`` for a packet not followed by a start) and the search
# resumes at the byte after its 0x9A.  So a torn packet (device reset mid-packet) whose declared
# length runs into the next packet is never delivered as a frame of two packets' bytes.  Where
# the missing bytes are exactly one whole next packet, a packet whose data ends with a run of
# whole, parsing packets is rejected as torn too (a good packet holds such a run by chance about
# once in 10^5 packets; it is then lost, never misread).  A 0x9A inside the data after a packet
# reads as a start only while that packet's bytes have not all arrived.  Torn packets still slip
# through when their declared length ends on such a start before the rest has come: 3 in 20,000
# tears of ``tests/drivers/test_torn_units.py``'s hostile stream, one delivered as a frame.
# Garbage holding 0x9A costs no good packet behind it.
#
# :class:`RobotiqFramer` is the reference; :class:`NativeRobotiqFramer` does the same in the
# compiled core (core/robotiq.cpp), the source's framer unless ``TACTILED_CORE=python``.
#
# Two fingers, one port: every ``robotiq://`` source on one device path shares one
# :class:`_SharedPort` (one serial connection, reader thread and reconnection loop); the source
# that reads copies the bytes to the others, each framing its own finger.  The first source to
# open starts the auto-send, the last to close stops it.  seq is generated.

from __future__ import annotations

import asyncio
import logging
from typing import Any, ClassVar

import numpy as np
import serial

from tactiled import native
from tactiled.sensors.devices import DeviceArray, device_array
from tactiled.frames import Frame
from tactiled.sources import FrameSource, SourceURL, parse_source_url
from tactiled_drivers.plumbing.framing import FramerBase, FramerStats, NativeFramer, now_if_none
from tactiled_drivers.serial import SerialSource

log = logging.getLogger(__name__)

START = 0x9A
HEADER = 4
MAX_DATA = 60
COMMAND_AUTOSEND = 0x58
DEFAULT_BAUD = 115_200
ROWS, COLS = 7, 4
STATIC, DYNAMIC, ACCEL, GYRO, MAGNET, TEMPERATURE, TIMESTAMP = (
    0x10, 0x20, 0x30, 0x40, 0x50, 0x60, 0x70)
#: payload bytes of each field type (the timestamp's width is tried as 2, then 8)
FIELD_BYTES = {STATIC: 2 * ROWS * COLS, DYNAMIC: 2, ACCEL: 6, GYRO: 6, MAGNET: 6,
               TEMPERATURE: 2, TIMESTAMP: 2}
_EXTRA_NAMES = {DYNAMIC: "dynamic", ACCEL: "accelerometer", GYRO: "gyroscope",
                MAGNET: "magnetometer", TEMPERATURE: "temperature"}
PENDING_LIMIT = 4 << 20  # bytes a sharing source may hold unread before they are dropped


def command(cmd: int, data: bytes = b"") -> bytes:
    """A host command packet (CRC byte 0, as ``pyrobotiqtactile`` sends it)."""
    if len(data) > MAX_DATA:
        raise ValueError(f"command data of {len(data)} bytes > {MAX_DATA}")
    return bytes([START, 0, cmd, len(data)]) + data


def autosend(period_ms: int) -> bytes:
    """Start streaming every ``period_ms`` ms (1..255), or stop it (0)."""
    if not 0 <= period_ms <= 255:
        raise ValueError(f"auto-send period must be 0..255 ms, got {period_ms}")
    return command(COMMAND_AUTOSEND, bytes([period_ms]))


def _fields(data: bytes, i: int = 0) -> list[tuple[int, int, bytes]] | None:
    """The fields ``(type, finger, payload)`` from ``data[i:]``, or None if they do not end
    exactly at its end (a timestamp is tried as 2 bytes, then as 8)."""
    out: list[tuple[int, int, bytes]] = []
    n = len(data)
    while i < n:
        kind, finger = data[i] & 0xF0, (data[i] >> 2) & 0x03
        size = FIELD_BYTES.get(kind)
        if size is None or i + 1 + size > n:
            return None
        if kind == TIMESTAMP and i + 9 <= n:
            rest = _fields(data, i + 3)
            if rest is None:
                rest = _fields(data, i + 9)
                if rest is None:
                    return None
                return [*out, (kind, finger, data[i + 1:i + 9]), *rest]
            return [*out, (kind, finger, data[i + 1:i + 3]), *rest]
        out.append((kind, finger, data[i + 1:i + 1 + size]))
        i += 1 + size
    return out


def _starts_packet(buf: bytearray, i: int) -> bool:
    """Whether ``buf[i:]`` can be the start of a packet, as far as it has arrived: ``0x9A``,
    then a data length of at most 60, then (when there is data) a known field type."""
    if buf[i] != START:
        return False
    if len(buf) > i + 3 and buf[i + 3] > MAX_DATA:
        return False
    if len(buf) > i + HEADER and buf[i + 3] > 0:
        return (buf[i + HEADER] & 0xF0) in FIELD_BYTES
    return True


def _packet_at(buf: bytearray, i: int) -> bool | None:
    """Whether a whole packet whose fields parse starts at ``buf[i]`` (None: it may, its bytes
    have not all arrived).  A ``0x9A`` with a plausible header inside another packet's data
    (about one byte in 2,400 of random data) is told from a start once that packet's bytes are
    there: they do not parse."""
    if not _starts_packet(buf, i):
        return False
    if len(buf) < i + HEADER:
        return None
    stop = i + HEADER + buf[i + 3]
    if len(buf) < stop:
        return None
    return _fields(bytes(buf[i + HEADER:stop])) is not None


def _start_inside(buf: bytearray, end: int) -> bool | None:
    """Whether a whole packet with data, its fields parsing, starts inside ``buf[1:end]``
    (None: one may, its bytes have not all arrived).  Where a packet is followed by no start,
    this tells a torn packet that ran into the next one (whose start is inside it) from a good
    packet followed by garbage (no start inside)."""
    i = buf.find(START, 1, end)
    while i >= 0:
        if len(buf) < i + HEADER:
            return None
        if buf[i + 3] > 0 and _starts_packet(buf, i):
            stop = i + HEADER + buf[i + 3]
            if len(buf) < stop:
                return None
            if _fields(bytes(buf[i + HEADER:stop])) is not None:
                return True
        i = buf.find(START, i + 1, end)
    return False


def _holds_packets(buf: bytearray, end: int) -> bool:
    """Whether the data of the packet ``buf[:end]`` ends with whole packets: a ``0x9A`` inside
    it starts a run of packets whose fields parse and which ends exactly at ``end``.  That is
    a torn packet whose missing bytes were exactly the next packet(s) (the torn one's declared
    length reaches just to the end of a following packet, so a start byte follows it)."""
    i = buf.find(START, HEADER, end)
    while i >= 0:
        j = i
        while j + HEADER <= end and buf[j] == START and buf[j + 3] <= MAX_DATA:
            k = j + HEADER + buf[j + 3]
            if k > end or _fields(bytes(buf[j + HEADER:k])) is None:
                break
            j = k
        if j == end:
            return True
        i = buf.find(START, i + 1, end)
    return False


def _int16s(payload: bytes) -> tuple[int, ...]:
    return tuple(int(v) for v in np.frombuffer(payload, dtype=">i2"))


class RobotiqFramer(FramerBase):
    """Packets -> frames of one finger's 7x4 static array (``uint16``); see the module text."""

    def __init__(self, finger: int = 0) -> None:
        super().__init__()
        if finger not in (0, 1, 2, 3):
            raise ValueError(f"finger must be 0..3, got {finger!r}")
        self.finger = finger
        self._extras: dict[str, Any] = {}
        self._stamp_ms: int | None = None  # latest timestamp, unwrapped
        self.packets = 0  # packets accepted (any finger)

    def reset(self) -> None:
        super().reset()
        self._stamp_ms = None

    def feed(self, data: bytes, host_time: float | None = None) -> list[Frame]:
        """Consume ``data``; return this finger's frames from the packets it completed (and
        confirmed: see the module text)."""
        if not data:
            return []
        self.stats.bytes += len(data)
        buf = self._buf
        carried = len(buf)  # bytes at the front of buf that came in earlier reads
        buf += data
        t = now_if_none(host_time)
        frames: list[Frame] = []
        while True:
            start = buf.find(START)
            if start < 0:
                self._drop(len(buf))
                break
            self._drop(start)
            carried = max(0, carried - start)
            if len(buf) < HEADER:
                break
            length = buf[3]
            if length > MAX_DATA:
                self._reject("length_errors")
                self._drop(1)
                carried = max(0, carried - 1)
                continue
            end = HEADER + length
            if len(buf) < end:
                break
            fields = _fields(bytes(buf[HEADER:end]))
            if fields is None:
                self._reject("parse_errors")
                self._drop(1)
                carried = max(0, carried - 1)
                continue
            if len(buf) == end and carried:  # spans reads: the next byte must confirm it
                break
            # what follows: a start whose packet has not all arrived confirms it as before; a
            # start whose whole packet does not parse is garbage
            follows = _packet_at(buf, end) is not False if len(buf) > end else True
            inside = not follows and _start_inside(buf, end)
            if inside is None:  # a packet may start inside it: wait for its bytes to tell
                break
            if inside or _holds_packets(buf, end):
                self._reject("truncated")  # a torn packet run into the next one(s)
                self._drop(1)
                carried = max(0, carried - 1)
                continue
            del buf[:end]
            carried = max(0, carried - end)
            self.packets += 1
            frame = self._packet(fields, t)
            if frame is not None:
                frames.append(self._accept(frame))
        return frames

    def _drop(self, n: int) -> None:
        if n > 0:
            del self._buf[:n]
            self._discard(n)

    def _packet(self, fields: list[tuple[int, int, bytes]], host_time: float) -> Frame | None:
        static = None
        for kind, finger, payload in fields:
            if finger != self.finger:
                continue
            if kind == STATIC:
                static = payload
            elif kind == TIMESTAMP:
                self._stamp(int.from_bytes(payload, "big"), len(payload))
            else:
                values = _int16s(payload)
                self._extras[_EXTRA_NAMES[kind]] = values[0] if len(values) == 1 else values
        if static is None:
            return None
        raw = np.frombuffer(static, dtype=">u2").reshape(ROWS, COLS).astype(np.uint16)
        extras = dict(self._extras)
        if self._stamp_ms is not None:
            extras["timestamp"] = self._stamp_ms
            t_us = self._stamp_ms * 1000
        else:
            t_us = self._host_clock_us(host_time)
        return Frame(seq=self._next_seq(), device_time_us=t_us, raw=raw, sensor_id=self.finger,
                     host_time=host_time, extras=extras, clocked=self._stamp_ms is not None)

    def _stamp(self, value: int, width: int) -> None:
        """A timestamp field: uint16 ms is unwrapped (it wraps every 65.536 s)."""
        last = self._stamp_ms
        if width != 2 or last is None:
            self._stamp_ms = value
            return
        base = last - (last & 0xFFFF)
        stamp = base + value
        if stamp < last:
            stamp += 0x10000
        self._stamp_ms = stamp


class NativeRobotiqFramer(NativeFramer):
    """:class:`RobotiqFramer` with its work in the compiled core (core/robotiq.cpp); the Python
    class is the reference (tests/drivers/test_vendor_framers.py holds the two equal)."""

    def __init__(self, finger: int = 0) -> None:
        from tactiled import _core  # (built by the install, whichever path is selected)

        self.finger = RobotiqFramer(finger).finger  # (checks the argument)
        super().__init__(_core.RobotiqFramer(finger), (ROWS, COLS))

    @property
    def packets(self) -> int:
        """Packets accepted (any finger)."""
        return self._core.packets

    def feed(self, data: bytes, host_time: float | None = None) -> list[Frame]:
        """Consume ``data``; return this finger's frames from the packets it completed."""
        if not data:
            return []
        t = now_if_none(host_time)
        return [Frame(seq, t_us, raw, self.finger, t, extras=extras, clocked=clocked)
                for seq, t_us, raw, clocked, extras in self._core.feed(data, t)]


def encode_finger(finger: int, raw: np.ndarray, *, dynamic: int = 0,
                  accelerometer: tuple[int, int, int] = (0, 0, 0),
                  gyroscope: tuple[int, int, int] = (0, 0, 0), timestamp_ms: int = 0) -> bytes:
    """One finger's reading as two packets (its IMU, dynamic and timestamp fields, then its
    static array), as the sources lay them out; CRC byte 0."""
    if raw.shape != (ROWS, COLS):
        raise ValueError(f"Robotiq static array must be {ROWS}x{COLS}, got {raw.shape}")
    f = (finger & 0x03) << 2
    be = ">i2"
    side = (bytes([DYNAMIC | f]) + np.array([dynamic], be).tobytes()
            + bytes([ACCEL | f]) + np.array(accelerometer, be).tobytes()
            + bytes([GYRO | f]) + np.array(gyroscope, be).tobytes()
            + bytes([TIMESTAMP | f]) + (timestamp_ms & 0xFFFF).to_bytes(2, "big"))
    static = bytes([STATIC | f]) + np.asarray(raw, dtype=">u2").tobytes()
    return (bytes([START, 0, COMMAND_AUTOSEND, len(side)]) + side
            + bytes([START, 0, COMMAND_AUTOSEND, len(static)]) + static)


# --------------------------------------------------------------------------------------------
# The port, shared by the fingers of one device


class _RobotiqPort(SerialSource):
    """The serial connection to one TSF-85 device: starts auto-send on every (re)open."""

    PARAMS: ClassVar[frozenset[str]] = frozenset({"baud", "exclusive", "period_ms"})
    DEFAULT_BAUD: ClassVar[int] = DEFAULT_BAUD

    def __init__(self, url: SourceURL, period_ms: int) -> None:
        super().__init__(url)
        self.period_ms = period_ms

    def _port_opened(self, port: serial.Serial) -> None:
        try:
            port.write(autosend(self.period_ms))
        except (OSError, serial.SerialException) as err:  # the reader will see it gone too
            log.warning("%s: cannot start auto-send: %s", self.path, err)

    def _port_closing(self, port: serial.Serial) -> None:
        port.write(autosend(0))
        port.flush()


class _SharedPort:
    """One device's connection and the sources reading it (see the module docstring)."""

    def __init__(self, key: str, url: SourceURL, period_ms: int) -> None:
        self.key = key
        self.port = _RobotiqPort(url, period_ms)
        # The port calls decoder.reset() when it reconnects: each source's framer must drop
        # the packet the unplug cut, at that point of its own stream.
        self.port.decoder = self  # type: ignore[assignment]
        self.stats = FramerStats()
        self.users: list[RobotiqSource] = []
        self._reading: RobotiqSource | None = None

    def reset(self) -> None:
        """The port reconnected: the reading source's framer resets now (it has framed every
        byte before this read); the others' after the bytes they hold from before."""
        for user in self.users:
            if user is self._reading:
                user.decoder.reset()
            else:
                user.reset_at = len(user.pending)

    async def attach(self, user: RobotiqSource) -> None:
        if not self.users:
            await self.port.open()
        self.users.append(user)

    async def detach(self, user: RobotiqSource) -> None:
        if user in self.users:
            self.users.remove(user)
        user.wake.set()  # its read waiting for another's round returns b""
        if not self.users:
            _PORTS.pop(self.key, None)
            await self.port.close()

    async def read_for(self, user: RobotiqSource) -> bytes:
        """The next bytes for ``user``: what another source read for it, or a read of its own."""
        while user.is_open:
            if user.reset_at == 0:
                user.decoder.reset()
                user.reset_at = None
            if user.pending:
                cut = len(user.pending) if user.reset_at is None else user.reset_at
                data = bytes(user.pending[:cut])
                del user.pending[:cut]
                if user.reset_at is not None:
                    user.reset_at -= cut
                return data
            if self._reading is not None:  # another source is reading: wait for its round
                user.wake.clear()
                await user.wake.wait()
                continue
            self._reading = user
            try:
                data = await self.port.read()
            finally:
                self._reading = None
                for other in self.users:
                    other.wake.set()
            if not data:
                return b""
            for other in self.users:
                if other is not user:
                    other.give(data)
            return data
        return b""


_PORTS: dict[str, _SharedPort] = {}


class RobotiqSource(FrameSource):
    """One finger of a TSF-85 device (``finger=0`` or ``1``); fingers of one device share its
    port.  URL parameters: ``finger`` (default 0), ``period_ms`` (auto-send period, 1..255,
    default 10), ``baud`` (default 115200), ``exclusive`` (default 1)."""

    PARAMS: ClassVar[frozenset[str]] = frozenset({"finger", "period_ms", "baud", "exclusive"})

    def __init__(self, url: str | SourceURL, *,
                 decoder: RobotiqFramer | NativeRobotiqFramer | None = None) -> None:
        super().__init__(url, decoder=decoder)  # type: ignore[arg-type]
        if not self.url.location:
            raise ValueError(f"{self.url.url!r}: no device path; write e.g. "
                             "robotiq:///dev/ttyACM0?finger=0")
        self.path = self.url.location
        self.period_ms = self.url.get_int("period_ms", 10, minimum=1, maximum=255)
        # the shared port's URL: the device and its serial settings, not the finger
        query = "&".join(f"{k}={v}" for k, v in sorted(self.url.params.items())
                         if k in ("baud", "exclusive"))
        self._port_url = f"serial://{self.url.url.split('://', 1)[1].split('?', 1)[0]}" + (
            f"?{query}" if query else "")
        self.pending = bytearray()
        self.pending_dropped = 0
        #: bytes of ``pending`` to frame before the framer resets (the port reconnected)
        self.reset_at: int | None = None
        self.wake = asyncio.Event()
        self._shared: _SharedPort | None = None

    def _new_decoder(self) -> RobotiqFramer | NativeRobotiqFramer:
        self.finger = self.url.get_int("finger", 0, minimum=0, maximum=3)
        return (RobotiqFramer if native.core is None else NativeRobotiqFramer)(self.finger)

    def device_array(self) -> DeviceArray:
        return device_array("robotiq")

    def sent_id(self) -> int:
        return self.finger

    def give(self, data: bytes) -> None:
        """Bytes another source read from the shared port (dropped beyond PENDING_LIMIT: the
        framer then resynchronises and counts the torn packet)."""
        if len(self.pending) + len(data) > PENDING_LIMIT:
            self.pending_dropped += len(self.pending)
            self.pending.clear()
            self.reset_at = 0 if self.reset_at is not None else None
        self.pending += data

    async def _open_internal(self) -> None:
        shared = _PORTS.get(self.path)
        if shared is None:
            shared = _PORTS[self.path] = _SharedPort(
                self.path, parse_source_url(self._port_url), self.period_ms)
        try:
            await shared.attach(self)
        except BaseException:
            if not shared.users:
                _PORTS.pop(self.path, None)
            raise
        self._shared = shared
        self.pending.clear()
        self.reset_at = None

    async def _close_internal(self) -> None:
        shared, self._shared = self._shared, None
        if shared is not None:
            await shared.detach(self)

    async def _read_internal(self) -> bytes:
        shared = self._shared
        return b"" if shared is None else await shared.read_for(self)

    def _timestamp(self) -> float:
        shared = self._shared
        return shared.port._timestamp() if shared is not None else super()._timestamp()

    # the connection's state is the shared port's
    def _port_attr(self, name: str, default: Any) -> Any:
        shared = self.__dict__.get("_shared")
        return getattr(shared.port, name) if shared is not None else default

    connected = property(lambda self: self._is_open and bool(self._port_attr("connected", False)),
                         lambda self, value: None)
    reconnects = property(lambda self: self._port_attr("reconnects", 0), lambda self, v: None)
    disconnects = property(lambda self: self._port_attr("disconnects", 0), lambda self, v: None)
    last_error = property(lambda self: self._port_attr("last_error", ""), lambda self, v: None)

    @property
    def read_backlog_now(self) -> int:
        return int(self._port_attr("read_backlog_now", 0)) + len(self.pending)

    @property
    def read_backlog(self) -> int:
        return int(self._port_attr("read_backlog", 0))

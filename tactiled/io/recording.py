"""Recording files: raw wire frames with host timestamps, for replay and regression tests."""

# A recording keeps the *wire bytes* of each frame (not decoded arrays), so replaying it runs
# the very decoder the hardware's bytes went through, the way gpsd's ``gpsfake`` replays device
# logs.  Format (version 1, all integers and floats little-endian)::
#
#     header, 32 bytes
#       offset size  type     field
#       0      8     bytes    magic b"TACTREC\\x00"
#       8      2     uint16   version (1)
#       10     2     uint16   header_size: bytes from file start to the first record (32)
#       12     4     uint32   sensor_id
#       16     8     float64  created: wall-clock time.time() seconds (Unix epoch) at creation
#       24     8     bytes    device: the vendor driver's kind the frames came from, ASCII,
#                             NUL-padded ("paxini"); all zero: the wire format's own counts
#     then records until end of file, each
#       0      8     float64  host_time: time.monotonic() seconds when the frame was received
#       8      4     uint32   length: number of wire bytes that follow (1 .. 1 MiB)
#       12     length bytes   one encoded frame, trailing 0x00 delimiter included
#
# ``host_time`` is monotonic, so only differences within one file mean anything (replay paces
# frames by them); ``created`` anchors the file in wall-clock time; ``device`` lets a replay
# read a vendor device's counts through that device's nominal table, as the live run did
# (files written before it have zeros there, read as the wire format's own counts).  A reader skips
# ``header_size`` bytes, so a later version may grow the header.  A trailing record cut short
# (a crash, a full disk) is reported through :attr:`RecordingReader.truncated`, never raised.

from __future__ import annotations

import logging
import math
import os
import struct
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import BinaryIO

from tactiled.errors import FrameError
from tactiled.frames import Frame, encode_frame

log = logging.getLogger(__name__)

MAGIC = b"TACTREC\x00"
VERSION = 1
_HEADER = struct.Struct("<8sHHId8s")  # magic, version, header_size, sensor_id, created, device
_RECORD = struct.Struct("<dI")  # host_time, length
HEADER_SIZE = _HEADER.size  # 32 bytes
RECORD_HEADER_SIZE = _RECORD.size  # 12 bytes
MAX_RECORD_BYTES = 1 << 20  # far above any frame; a larger length means a corrupt file
DEVICE_LEN = 8  # bytes of the header's device name


@dataclass(frozen=True)
class RecordingHeader:
    """What the file header says: format version, sensor id, creation time (Unix seconds) and
    the vendor device the frames came from (``None``: the wire format's own counts)."""

    version: int
    sensor_id: int
    created: float
    header_size: int = HEADER_SIZE
    device: str | None = None


def _device_field(device: str | None) -> bytes:
    """The header's device bytes (ValueError for a name that does not fit)."""
    if device is None:
        return bytes(DEVICE_LEN)
    if not (0 < len(device) <= DEVICE_LEN and all(0x20 < ord(c) < 0x7F for c in device)):
        raise ValueError(f"device must be 1..{DEVICE_LEN} printable ASCII characters, no "
                         f"blank, got {device!r}")
    return device.encode("ascii").ljust(DEVICE_LEN, b"\0")


def _device_name(raw: bytes) -> str | None:
    """The device named by the header's bytes (None: zeros, or bytes that name nothing)."""
    name = raw.rstrip(b"\0")
    if not name or b"\0" in name or not all(0x20 < b < 0x7F for b in name):
        return None
    return name.decode("ascii")


def _read_header(stream: BinaryIO, path: Path) -> RecordingHeader:
    data = stream.read(HEADER_SIZE)
    if len(data) < HEADER_SIZE:
        if data[: len(MAGIC)] != MAGIC[: len(data)]:
            raise FrameError(f"{path}: not a tactiled recording (bad magic)")
        raise FrameError(f"{path}: recording header truncated ({len(data)} of "
                         f"{HEADER_SIZE} bytes)")
    magic, version, header_size, sensor_id, created, device = _HEADER.unpack(data)
    if magic.startswith(b"PK\x03\x04"):
        raise FrameError(f"{path}: not a tactiled recording but an .npz file (tactiled fit "
                         "reads frame files)")
    if magic != MAGIC:
        raise FrameError(f"{path}: not a tactiled recording (bad magic {magic!r})")
    if version != VERSION:
        raise FrameError(f"{path}: recording version {version} is not supported "
                         f"(this tactiled reads version {VERSION})")
    if header_size < HEADER_SIZE:
        raise FrameError(f"{path}: recording header size {header_size} < {HEADER_SIZE}")
    stream.seek(header_size)
    return RecordingHeader(version, sensor_id, created, header_size, _device_name(device))


class RecordingReader:
    """Iterate the ``(host_time, wire_bytes)`` records of a recording.

    The header is read (and checked: :class:`FrameError` if it is not a recording) on
    construction.  Iteration stops at the end of file; if the last record is cut short it
    stops before it and sets ``truncated`` (with ``truncated_bytes`` dangling bytes and
    ``truncated_offset`` where the broken record starts), logging one warning.  A record
    length beyond 1 MiB means the file is corrupt mid-way and raises :class:`FrameError`.
    Each iteration re-reads the file from the first record.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._stream: BinaryIO = open(self.path, "rb")  # noqa: SIM115 - closed in close()
        try:
            self.header = _read_header(self._stream, self.path)
        except BaseException:
            self._stream.close()
            raise
        self.records = 0
        self.truncated = False
        self.truncated_bytes = 0
        self.truncated_offset: int | None = None

    def __iter__(self) -> Iterator[tuple[float, bytes]]:
        for host_time, data in self._walk(read_data=True):
            assert data is not None
            yield host_time, data

    def scan(self) -> int:
        """Check every record's framing without reading the payloads (seeking over them):
        the number of complete records; raises :class:`FrameError` where a record is corrupt
        (as iterating would, later).  Sets ``truncated`` as iterating does."""
        for _ in self._walk(read_data=False, warn=False):
            pass
        return self.records

    def _walk(self, *, read_data: bool,
              warn: bool = True) -> Iterator[tuple[float, bytes | None]]:
        stream = self._stream
        stream.seek(0, os.SEEK_END)
        size = stream.tell()
        stream.seek(self.header.header_size)
        self.records = 0
        self.truncated, self.truncated_bytes, self.truncated_offset = False, 0, None
        while True:
            offset = stream.tell()
            head = stream.read(RECORD_HEADER_SIZE)
            if not head:
                return
            if len(head) < RECORD_HEADER_SIZE:
                self._truncate(offset, len(head), warn)
                return
            host_time, length = _RECORD.unpack(head)
            if length == 0 or length > MAX_RECORD_BYTES or not math.isfinite(host_time):
                raise FrameError(f"{self.path}: corrupt record at byte {offset} "
                                 f"(length {length}, host_time {host_time!r})")
            if read_data:
                data: bytes | None = stream.read(length)
                have = len(data)
            else:
                data, have = None, min(length, size - offset - RECORD_HEADER_SIZE)
                stream.seek(offset + RECORD_HEADER_SIZE + have)
            if have < length:
                self._truncate(offset, RECORD_HEADER_SIZE + have, warn)
                return
            self.records += 1
            yield host_time, data

    def _truncate(self, offset: int, dangling: int, warn: bool) -> None:
        self.truncated, self.truncated_bytes, self.truncated_offset = True, dangling, offset
        if warn:
            log.warning("%s: truncated last record at byte %d (%d dangling bytes ignored) "
                        "after %d complete records", self.path, offset, dangling, self.records)

    def close(self) -> None:
        """Close the file."""
        self._stream.close()

    def __enter__(self) -> RecordingReader:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def read_recording(path: str | os.PathLike[str]) -> list[tuple[float, bytes]]:
    """All complete records of a file (a truncated tail is dropped and logged)."""
    with RecordingReader(path) as reader:
        return list(reader)


def _complete_length(path: Path) -> tuple[RecordingHeader, int]:
    """The header of an existing recording and the byte length of its complete records."""
    with RecordingReader(path) as reader:
        for _ in reader:
            pass
        end = reader.truncated_offset
        if end is None:
            end = reader._stream.tell()
        return reader.header, end


class RecordingWriter:
    """Append ``(host_time, wire_bytes)`` records to a recording file.

    A new file gets a header (``device``: the vendor driver's kind the frames came from, e.g.
    ``"paxini"``, so that a replay reads its counts as the live run did); with ``append=True``
    an existing recording is continued (its sensor id must match, and its device when it names
    one; a truncated last record is cut off first so the file stays readable).  Without ``append`` an existing file is an error (``FileExistsError``):
    recordings are evidence and are not overwritten silently.  Writes are buffered;
    :meth:`flush` hands them to the OS, :meth:`close` also ``fsync``\\ s them to the disk.
    """

    def __init__(self, path: str | os.PathLike[str], *, sensor_id: int = 0,
                 append: bool = False, created: float | None = None,
                 device: str | None = None) -> None:
        if not 0 <= sensor_id <= 0xFFFFFFFF:
            raise ValueError(f"sensor_id must fit in uint32, got {sensor_id!r}")
        device_bytes = _device_field(device)
        self.path = Path(path)
        self.records = 0
        self.bytes_written = 0
        if append and self.path.exists() and self.path.stat().st_size > 0:
            header, end = _complete_length(self.path)
            if header.sensor_id != sensor_id:
                raise FrameError(f"{self.path}: recording is of sensor {header.sensor_id}, "
                                 f"cannot append frames of sensor {sensor_id}")
            # (a file that names no device, as every file written before the field, takes
            # any frames: its replay reads them as it always did)
            if header.device is not None and header.device != device:
                raise FrameError(f"{self.path}: recording is of device {header.device}, cannot "
                                 f"append frames of {device or 'the wire format'}")
            self.header = header
            self._stream: BinaryIO = open(self.path, "r+b")  # noqa: SIM115
            if end < self.path.stat().st_size:
                log.warning("%s: cutting a truncated last record at byte %d before appending",
                            self.path, end)
                self._stream.truncate(end)
            self._stream.seek(end)
        else:
            self.header = RecordingHeader(
                VERSION, sensor_id, time.time() if created is None else created, device=device
            )
            self._stream = open(self.path, "ab" if append else "xb")  # noqa: SIM115
            self._stream.write(_HEADER.pack(MAGIC, VERSION, HEADER_SIZE, sensor_id,
                                            self.header.created, device_bytes))

    @property
    def closed(self) -> bool:
        return self._stream.closed

    def write(self, host_time: float, data: bytes) -> None:
        """Append one record: ``data`` must be the wire bytes of one encoded frame."""
        if not math.isfinite(host_time):
            raise ValueError(f"host_time must be finite seconds, got {host_time!r}")
        if not 0 < len(data) <= MAX_RECORD_BYTES:
            raise ValueError(f"record must hold 1..{MAX_RECORD_BYTES} bytes, got {len(data)}")
        self._stream.write(_RECORD.pack(host_time, len(data)))
        self._stream.write(data)
        self.records += 1
        self.bytes_written += RECORD_HEADER_SIZE + len(data)

    def flush(self) -> None:
        """Hand buffered records to the operating system (not yet forced to disk)."""
        self._stream.flush()

    def close(self) -> None:
        """Flush, ``fsync`` and close; idempotent."""
        if self._stream.closed:
            return
        try:
            self._stream.flush()
            os.fsync(self._stream.fileno())
        finally:
            self._stream.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


class Recorder:
    """Record decoded frames: each is re-encoded with the wire codec and appended.

    For the pipeline: ``record(frame)`` is cheap (a buffered write); buffered records are
    flushed to the OS at most every ``flush_interval`` seconds so a crash loses little, and
    :meth:`close` forces them to disk.
    """

    def __init__(self, path: str | os.PathLike[str], *, sensor_id: int = 0,
                 append: bool = False, flush_interval: float = 0.5,
                 device: str | None = None) -> None:
        if not (math.isfinite(flush_interval) and flush_interval >= 0):
            raise ValueError(f"flush_interval must be >= 0 seconds, got {flush_interval!r}")
        self.writer = RecordingWriter(path, sensor_id=sensor_id, append=append, device=device)
        self.flush_interval = flush_interval
        self._last_flush = time.monotonic()

    @property
    def path(self) -> Path:
        return self.writer.path

    @property
    def frames_written(self) -> int:
        return self.writer.records

    def record(self, frame: Frame, host_time: float | None = None) -> None:
        """Append ``frame``; ``host_time`` (monotonic seconds) defaults to the frame's own
        ``host_time``, or to now when the frame was never stamped (``host_time == 0``)."""
        if host_time is None:
            host_time = frame.host_time or time.monotonic()
        self.writer.write(host_time, encode_frame(frame))
        now = time.monotonic()
        if now - self._last_flush >= self.flush_interval:
            self.writer.flush()
            self._last_flush = now

    def close(self) -> None:
        """Flush, fsync and close the file; idempotent."""
        self.writer.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

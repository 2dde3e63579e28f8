"""Frames: one reading of the tactel array, and (below) the wire-format codec.

No I/O here: the decoder is fed bytes and returns frames, so it is trivially testable and
fuzzable.  The wire format is documented in ``docs/reference/protocol.md``.  Public codec API:
:func:`encode_frame`, :class:`FrameDecoder` (with :class:`DecoderStats`), :func:`decode_frame`
for a single frame, and the :func:`cobs_encode` / :func:`cobs_decode` helpers.
"""

from __future__ import annotations

import operator
import struct
import time
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactiled.errors import FrameError


@dataclass
class Frame:
    """One reading of the array.

    ``raw`` holds the tactel counts as ``uint16`` of shape ``(rows, cols)``; ``strain`` is filled
    in by calibration (linearised, zeroed, positive under compression) and is ``None`` before.
    ``device_time_us`` is the sensor's own clock in microseconds; ``host_time`` is
    ``time.monotonic()`` seconds when the host finished receiving the frame.  ``extras``: what a
    vendor format sends beside the array (a Robotiq finger's accelerometer, a XELA taxel's shear
    components...), by name; ``None`` for formats with nothing more (not sent on the wire).
    ``clocked``: ``device_time_us`` is the device's own clock (False: the format sends none and
    the framer made it from arrival times).  ``time``: when the device measured the frame, Unix
    seconds, set by :class:`tactiled.clock.FrameClock` (None until then; host-side only).
    ``taxels``: a 3-axis array's readings, shape ``(rows, cols, 3)`` (x, y, z per taxel, as the
    device counts them; docs/concepts/shear.md), ``raw`` then holds the z counts, which the
    1-axis path reads (the wire's version-2 frames carry them); ``None`` for a 1-axis array.
    """

    seq: int
    device_time_us: int
    raw: np.ndarray
    sensor_id: int = 0
    host_time: float = 0.0
    strain: np.ndarray | None = field(default=None, repr=False)
    extras: dict[str, Any] | None = field(default=None, repr=False)
    clocked: bool = field(default=True, repr=False)
    time: float | None = field(default=None, repr=False)
    taxels: np.ndarray | None = field(default=None, repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.raw.shape[0]), int(self.raw.shape[1]))

    @property
    def axes(self) -> int:
        """Readings per taxel: 3 for a frame carrying :attr:`taxels`, else 1."""
        return 1 if self.taxels is None else int(self.taxels.shape[-1])


# --------------------------------------------------------------------------------------------
# Wire format (docs/reference/protocol.md): COBS( header | uint16 LE counts, row-major | CRC-32 LE ) 0x00
# --------------------------------------------------------------------------------------------

VERSION = 1  # a 1-axis frame: one count per tactel
VERSION_AXES = 2  # a frame whose header's byte 1 says the readings per taxel (``axes``)
#: The readings per taxel a version-2 frame may carry: 3 (x, y, z), or 1.
WIRE_AXES = (1, 3)
# version, flags (version 2: axes), sensor_id, seq, device_time_us, rows, cols
HEADER = struct.Struct("<BBHIQBB")
HEADER_LEN = HEADER.size  # 18 bytes, both versions
CRC_LEN = 4
MAX_TACTELS = 4096  # counts per frame (rows * cols * axes); a 64x64 array, far above 8x8
MAX_DECODED_LEN = HEADER_LEN + 2 * MAX_TACTELS + CRC_LEN  # 8214 bytes
# COBS adds one code byte per started run of 254 bytes: the longest legal encoded frame,
# not counting its 0x00 delimiter.  Anything longer is garbage and is dropped unread.
MAX_ENCODED_LEN = MAX_DECODED_LEN + -(-MAX_DECODED_LEN // 254)  # 8247 bytes
_SEQ_MOD = 1 << 32
_COUNTS = np.dtype("<u2")  # the wire's counts: uint16, little-endian


def cobs_encode(data: bytes) -> bytes:
    """COBS-encode ``data`` (Cheshire & Baker); the result has no 0x00 and no delimiter."""
    out = bytearray()
    segments = bytes(data).split(b"\x00")
    last = len(segments) - 1
    for k, seg in enumerate(segments):
        i = 0
        while len(seg) - i >= 254:  # a full run: code 0xFF, no implied zero
            out.append(0xFF)
            out += seg[i : i + 254]
            i += 254
        rest = seg[i:]
        # A run ending exactly at the end of the data needs no empty closing group.
        if rest or k < last or i == 0:
            out.append(len(rest) + 1)
            out += rest
    return bytes(out)


def _cobs_decode(chunk: bytes) -> tuple[bytearray, bool]:
    """Decode one delimiter-free COBS chunk; ``ok`` is False if it is not valid COBS.

    The bytes decoded so far are returned either way, so a cut-off frame can still be
    recognised as truncated by its header.  Speed: the decoded data is the chunk with each
    code byte zeroed in place (code 0xFF implies no zero, so the byte after its run is
    deleted instead), so the Python loop does one store per group and copies nothing.
    """
    buf = bytearray(chunk)
    n = len(buf)
    if n == 0:
        return buf, False
    drop = [0]  # code bytes that stand for no data byte: the first, and those after 0xFF runs
    i, code = 0, buf[0]
    while code:
        j = i + code
        if j >= n:
            break
        following = buf[j]
        if code == 0xFF:
            drop.append(j)
        else:
            buf[j] = 0
        i, code = j, following
    for k in reversed(drop):  # at most one per 254 bytes, so the O(n) deletes stay cheap
        del buf[k]
    return buf, code != 0 and i + code == n


def cobs_decode(chunk: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`: decode one chunk without its 0x00 delimiter.

    Raises :class:`~tactiled.errors.FrameError` if the chunk is not valid COBS.
    """
    out, ok = _cobs_decode(bytes(chunk))
    if not ok:
        raise FrameError(f"invalid COBS data ({len(chunk)} bytes)")
    return bytes(out)


def _check_uint(name: str, value: int, bits: int) -> int:
    try:
        number = operator.index(value)  # ints and numpy ints; a float seq is a caller's bug
    except TypeError:
        raise ValueError(f"{name} must be an integer, got {value!r}") from None
    if not 0 <= number < (1 << bits):
        raise ValueError(f"{name} must be an unsigned {bits}-bit integer, got {value!r}")
    return number


def encode_frame(frame: Frame) -> bytes:
    """Encode ``frame`` for the wire: COBS bytes including the trailing 0x00 delimiter.

    Only ``seq``, ``device_time_us``, ``sensor_id`` and the counts travel; ``host_time`` and
    ``strain`` are host-side.  A frame with ``taxels`` (a 3-axis array's ``(rows, cols, 3)``
    counts) is sent as a version-2 frame carrying them (its ``raw`` is not sent: the receiver's
    is the z counts); any other frame as version 1, its bytes those of a 1-axis array.
    ``seq`` must already be wrapped to uint32 by the sender.  Raises ``ValueError`` naming the
    value if the frame cannot be represented.
    """
    seq = _check_uint("seq", frame.seq, 32)
    device_time_us = _check_uint("device_time_us", frame.device_time_us, 64)
    sensor_id = _check_uint("sensor_id", frame.sensor_id, 16)
    if frame.taxels is None:
        counts, name, version, axes = np.asarray(frame.raw), "raw", VERSION, 0
        if counts.ndim != 2:
            raise ValueError(f"raw must be 2-D with 1..255 rows and cols, got shape {counts.shape}")
    else:
        counts, name, version = np.asarray(frame.taxels), "taxels", VERSION_AXES
        if counts.ndim != 3 or counts.shape[2] not in WIRE_AXES:
            raise ValueError(f"taxels must have shape (rows, cols, 3), got {counts.shape}")
        axes = counts.shape[2]
    rows, cols = counts.shape[:2]
    if not (1 <= rows <= 255 and 1 <= cols <= 255):
        raise ValueError(f"{name} must have 1..255 rows and cols, got shape {counts.shape}")
    if counts.size > MAX_TACTELS:
        raise ValueError(f"{name} shape {counts.shape} has {counts.size} counts > {MAX_TACTELS}")
    if counts.dtype != np.uint16:
        if counts.dtype.kind not in "iuf":
            raise ValueError(f"{name} must hold integer counts, got dtype {counts.dtype}")
        bad = ~np.isfinite(counts) | (counts < 0) | (counts > 0xFFFF) | (counts != np.round(counts))
        if bad.any():
            idx = tuple(int(k) for k in np.argwhere(bad)[0])
            raise ValueError(f"{name}{list(idx)} = {counts[idx]!r} is not a uint16 count")
    header = HEADER.pack(version, axes, sensor_id, seq, device_time_us, rows, cols)
    body = header + counts.astype("<u2").tobytes()  # C order: row-major, x y z per taxel
    body += zlib.crc32(body).to_bytes(CRC_LEN, "little")
    return cobs_encode(body) + b"\x00"


@dataclass
class DecoderStats:
    """Counters of a :class:`FrameDecoder`; they only ever grow (``reset`` keeps them).

    Every rejected chunk (the bytes between two 0x00) is counted in exactly one of
    ``crc_errors``, ``length_errors``, ``version_errors``, ``cobs_errors``, ``truncated`` or
    ``oversize``; see docs/reference/protocol.md for how the kind is chosen.
    """

    frames: int = 0  # frames delivered
    bytes: int = 0  # bytes fed
    crc_errors: int = 0  # CRC mismatch (corruption in transit)
    length_errors: int = 0  # CRC good but rows*cols disagrees with the payload or the maximum
    version_errors: int = 0  # CRC good but an unknown format version
    cobs_errors: int = 0  # COBS structure broken (a group runs past the delimiter)
    truncated: int = 0  # shorter than a header, or than the frame its header declares
    oversize: int = 0  # no delimiter within MAX_ENCODED_LEN bytes: discarded unread
    lost: int = 0  # frames missing according to forward gaps in seq
    duplicated: int = 0  # frames dropped because they repeat the previous seq
    restarts: int = 0  # seq went backwards: the device restarted (no frames counted lost)
    resyncs: int = 0  # times a good frame followed one or more rejected chunks

    @property
    def rejected(self) -> int:
        """All chunks rejected as corrupt, of any kind."""
        return (self.crc_errors + self.length_errors + self.version_errors
                + self.cobs_errors + self.truncated + self.oversize)


class FrameDecoder:
    """Stream decoder: ``feed(bytes) -> frames``, no I/O; never raises on any input bytes.

    Bytes may arrive in chunks of any size.  Memory is bounded: at most ``MAX_ENCODED_LEN``
    bytes are held between calls.  Sequence numbers are tracked per ``sensor_id``.
    """

    def __init__(self) -> None:
        self.stats = DecoderStats()
        self._buf = bytearray()
        self._discarding = False  # inside an oversize run: drop everything up to the next 0x00
        self._in_error = False  # a chunk was rejected since the last good frame
        self._last_seq: dict[int, int] = {}

    @property
    def buffered(self) -> int:
        """Bytes of an incomplete frame held until its delimiter arrives."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget partial data and sequence history (e.g. after reopening the port)."""
        self._buf.clear()
        self._discarding = False
        self._in_error = False
        self._last_seq.clear()

    def feed(self, data: bytes, host_time: float | None = None) -> list[Frame]:
        """Consume ``data`` and return the frames completed by it, in order.

        ``host_time`` (``time.monotonic()`` seconds, default: now) is stamped on every frame
        returned by this call.
        """
        if not data:
            return []
        data = bytes(data)  # no copy for bytes; accepts bytearray and memoryview too
        self.stats.bytes += len(data)
        if self._discarding:
            start = data.find(b"\x00")
            if start < 0:
                return []
            data = data[start + 1 :]
            self._discarding = False
        if data.find(b"\x00") < 0:  # the common byte-at-a-time case: no copy of the buffer
            self._buf += data
            self._check_bound()
            return []
        chunks = data.split(b"\x00")
        chunks[0] = bytes(self._buf) + chunks[0]
        self._buf = bytearray(chunks.pop())
        if host_time is None:
            host_time = time.monotonic()
        frames: list[Frame] = []
        for chunk in chunks:
            if not chunk:  # leading, doubled or idle 0x00: not an error
                continue
            if len(chunk) > MAX_ENCODED_LEN:
                self._reject("oversize")
                continue
            result = _parse(chunk)
            if isinstance(result, str):
                self._reject(result)
            elif self._accept(result):
                result.host_time = host_time
                frames.append(result)
        # The unterminated tail comes after every complete chunk in the stream: an oversize
        # tail is rejected only now, or a good frame before it would count as a resync.
        self._check_bound()
        return frames

    def _check_bound(self) -> None:
        if len(self._buf) > MAX_ENCODED_LEN:
            self._buf.clear()
            self._discarding = True
            self._reject("oversize")

    def _reject(self, kind: str) -> None:
        setattr(self.stats, kind, getattr(self.stats, kind) + 1)
        self._in_error = True

    def _accept(self, frame: Frame) -> bool:
        """Sequence bookkeeping for a CRC-good frame; False if it is a duplicate to drop."""
        last = self._last_seq.get(frame.sensor_id)
        if last is not None:
            step = (frame.seq - last) % _SEQ_MOD  # uint32 wrap-around: 0xFFFFFFFF -> 0 is +1
            if step == 0:
                self.stats.duplicated += 1
                return False
            if step < _SEQ_MOD // 2:
                self.stats.lost += step - 1
            else:  # backwards: a reset device restarts its count, it did not lose 4e9 frames
                self.stats.restarts += 1
        self._last_seq[frame.sensor_id] = frame.seq
        self.stats.frames += 1
        if self._in_error:
            self.stats.resyncs += 1
            self._in_error = False
        return True


def _values(version: int, axes: int, rows: int, cols: int) -> int:
    """The counts a header declares, or 0 where the header is not one this format carries
    (an unknown version, or a version-2 ``axes`` not in :data:`WIRE_AXES`)."""
    if version == VERSION:
        return rows * cols
    if version == VERSION_AXES and axes in WIRE_AXES:
        return rows * cols * axes
    return 0


def _parse(chunk: bytes) -> Frame | str:
    """Decode one delimiter-free chunk to a Frame, or name the DecoderStats counter to bump."""
    data, cobs_ok = _cobs_decode(chunk)
    n = len(data)
    if n < HEADER_LEN + CRC_LEN:
        return "truncated"
    version, axes, sensor_id, seq, t_us, rows, cols = HEADER.unpack_from(data)
    values = _values(version, axes, rows, cols)
    expected = HEADER_LEN + 2 * values + CRC_LEN
    plausible = 0 < values <= MAX_TACTELS
    crc = int.from_bytes(data[-CRC_LEN:], "little")
    if cobs_ok and zlib.crc32(memoryview(data)[:-CRC_LEN]) == crc:
        # The bytes are what the sender sent, so a bad header is the sender's own error.
        if version not in (VERSION, VERSION_AXES):
            return "version_errors"
        if not plausible or n != expected:
            return "length_errors"
        # a view of ``data``, which nothing else holds (a copy on a big-endian host only)
        counts = np.frombuffer(data, dtype=_COUNTS, count=values, offset=HEADER_LEN)
        if _COUNTS != np.uint16:
            counts = counts.astype(np.uint16)
        if version == VERSION or axes == 1:
            return Frame(seq=seq, device_time_us=t_us, raw=counts.reshape(rows, cols),
                         sensor_id=sensor_id)
        taxels = counts.reshape(rows, cols, axes)
        return Frame(seq=seq, device_time_us=t_us, raw=taxels[..., 2].copy(),
                     sensor_id=sensor_id, taxels=taxels)
    # Damaged in transit.  A plausible header promising more bytes than arrived means the
    # frame was cut off (e.g. the device reset mid-frame and sent its start-up 0x00).
    if plausible and n < expected:
        return "truncated"
    return "crc_errors" if cobs_ok else "cobs_errors"


def decode_frame(encoded: bytes, host_time: float = 0.0) -> Frame:
    """Decode exactly one frame (with or without its 0x00 delimiters), e.g. from a file.

    Raises :class:`~tactiled.errors.FrameError` naming the kind of damage.
    """
    chunk = bytes(encoded).strip(b"\x00")
    if b"\x00" in chunk:
        raise FrameError(f"expected one frame, got several in {len(encoded)} bytes")
    result = "oversize" if len(chunk) > MAX_ENCODED_LEN else _parse(chunk)
    if isinstance(result, str):
        raise FrameError(f"corrupt frame: {result.removesuffix('_errors')}")
    result.host_time = host_time
    return result


class NativeFraming:
    """What a framer whose work runs in the compiled core shares with the others: its core
    object (one of ``tactiled._core``'s framers) and its counters, read from the core as a
    ``STATS`` dataclass (whose fields the core's ``counters()`` gives in order)."""

    STATS: type

    def __init__(self, core: Any) -> None:
        self._core = core

    @property
    def stats(self) -> Any:
        """A snapshot of the counters (a new ``STATS`` on each access)."""
        return self.STATS(*self._core.counters())

    @property
    def buffered(self) -> int:
        """Bytes of an incomplete unit held between calls."""
        return self._core.buffered

    def reset(self) -> None:
        """Forget partial data (the port was reopened), as the Python framer does."""
        self._core.reset()


class NativeFrameDecoder(NativeFraming):
    """:class:`FrameDecoder` with its work in the compiled core (``tactiled._core``,
    core/wire.cpp): the same frames and the same counters for the same bytes (the Python class
    is the reference, tests/reliability/test_decoder_fuzz.py holds the two equal); one call
    into the core per ``feed``, however many frames the bytes hold."""

    STATS = DecoderStats

    def __init__(self) -> None:
        from tactiled import _core  # (built by the install, whichever path is selected)

        super().__init__(_core.WireDecoder())

    def feed(self, data: bytes, host_time: float | None = None) -> list[Frame]:
        """Consume ``data`` and return the frames completed by it, in order (as
        :meth:`FrameDecoder.feed`)."""
        if not data:
            return []
        decoded = self._core.feed(data)
        if not decoded:
            return []
        if host_time is None:
            host_time = time.monotonic()
        return [Frame(seq, t_us, raw, sensor_id, host_time) if raw.ndim == 2
                else Frame(seq, t_us, raw[..., 2].copy(), sensor_id, host_time, taxels=raw)
                for seq, t_us, sensor_id, raw in decoded]


def new_decoder() -> FrameDecoder | NativeFrameDecoder:
    """The wire format's decoder this process runs: the compiled core's, or the Python
    reference where ``TACTILED_CORE=python`` (:mod:`tactiled.native`)."""
    from tactiled import native

    return FrameDecoder() if native.core is None else NativeFrameDecoder()

"""FrameDecoder: round trips, chunking, resynchronisation, rejection, sequence bookkeeping."""

from __future__ import annotations

import time
import zlib
from dataclasses import asdict

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactiled.frames import (
    HEADER,
    MAX_ENCODED_LEN,
    DecoderStats,
    Frame,
    FrameDecoder,
    cobs_decode,
    cobs_encode,
    encode_frame,
)

U32 = 1 << 32
ERROR_KINDS = ("crc_errors", "length_errors", "version_errors", "cobs_errors", "truncated",
               "oversize")


@st.composite
def frames(draw: st.DrawFn, max_side: int = 12) -> Frame:
    rows = draw(st.integers(1, max_side))
    cols = draw(st.integers(1, max_side))
    # Small counts put zeros in the high bytes (many COBS groups), large ones give none.
    top = draw(st.sampled_from([255, 4095, 0xFFFF]))
    seed = draw(st.integers(0, 2**32 - 1))
    raw = np.random.default_rng(seed).integers(0, top + 1, (rows, cols)).astype(np.uint16)
    return Frame(seq=draw(st.integers(0, U32 - 1)),
                 device_time_us=draw(st.integers(0, 2**64 - 1)),
                 sensor_id=draw(st.integers(0, 0xFFFF)), raw=raw)


def make_frames(n: int, start: int = 0, shape: tuple[int, int] = (8, 8),
                seed: int = 0) -> list[Frame]:
    """Consecutive frames, seq from ``start`` (wrapping), 1 ms apart."""
    rng = np.random.default_rng(seed)
    return [Frame(seq=(start + k) % U32, device_time_us=1000 * k, sensor_id=1,
                  raw=rng.integers(0, 4096, shape).astype(np.uint16)) for k in range(n)]


def key(frame: Frame) -> tuple:
    """What travels on the wire, comparable."""
    return (frame.seq, frame.device_time_us, frame.sensor_id, frame.raw.shape,
            frame.raw.tobytes())


def decode_all(decoder: FrameDecoder, pieces: list[bytes]) -> list[Frame]:
    return [f for piece in pieces for f in decoder.feed(piece, host_time=1.0)]


def reencode(frame: Frame, **header: int) -> bytes:
    """Encode ``frame`` with header fields overridden, CRC recomputed: a buggy sender."""
    body = bytearray(cobs_decode(encode_frame(frame)[:-1]))
    fields = dict(zip(("version", "flags", "sensor_id", "seq", "time", "rows", "cols"),
                      HEADER.unpack_from(body), strict=True)) | header
    HEADER.pack_into(body, 0, *fields.values())
    return with_crc(bytes(body[:-4]))


def with_crc(body: bytes) -> bytes:
    return cobs_encode(body + zlib.crc32(body).to_bytes(4, "little")) + b"\x00"


# --- round trips ------------------------------------------------------------------------------

@settings(max_examples=150, deadline=None)
@given(frames())
def test_any_frame_round_trips(frame: Frame) -> None:
    decoder = FrameDecoder()
    [out] = decoder.feed(encode_frame(frame), host_time=3.5)
    assert key(out) == key(frame)
    assert out.raw.dtype == np.uint16 and out.raw.flags.c_contiguous
    assert out.host_time == 3.5 and out.strain is None
    assert decoder.stats.frames == 1 and decoder.stats.rejected == 0


@settings(max_examples=60, deadline=None)
@given(st.lists(frames(max_side=8), min_size=1, max_size=8), st.data())
def test_stream_split_at_arbitrary_boundaries(batch: list[Frame], data: st.DataObject) -> None:
    for k, frame in enumerate(batch):  # one sensor, consecutive seqs: no gaps, no duplicates
        frame.seq, frame.sensor_id = k, 0
    stream = b"\x00" + b"".join(encode_frame(f) for f in batch)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=20)))
    pieces = [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]
    decoder = FrameDecoder()
    assert [key(f) for f in decode_all(decoder, pieces)] == [key(f) for f in batch]
    assert decoder.stats.rejected == 0 and decoder.stats.lost == 0
    assert decoder.stats.bytes == len(stream) and decoder.buffered == 0


def test_one_frame_split_at_every_byte_boundary() -> None:
    frame, after = make_frames(2)
    wire = encode_frame(frame)
    for cut in range(len(wire) + 1):
        decoder = FrameDecoder()
        out = decode_all(decoder, [wire[:cut], wire[cut:], encode_frame(after)])
        assert [key(f) for f in out] == [key(frame), key(after)], cut
    decoder = FrameDecoder()  # and one byte at a time
    out = decode_all(decoder, [wire[i : i + 1] for i in range(len(wire))])
    assert [key(f) for f in out] == [key(frame)]
    assert decoder.stats == DecoderStats(frames=1, bytes=len(wire))


def test_leading_and_extra_zero_bytes_are_harmless() -> None:
    a, b = make_frames(2)
    decoder = FrameDecoder()
    out = decoder.feed(b"\x00\x00\x00" + encode_frame(a) + b"\x00\x00" + encode_frame(b) + b"\x00")
    assert [key(f) for f in out] == [key(a), key(b)]
    assert decoder.stats.rejected == 0 and decoder.stats.resyncs == 0


def test_bytearray_and_memoryview_input() -> None:
    a, b = make_frames(2)
    decoder = FrameDecoder()
    out = decoder.feed(bytearray(encode_frame(a))) + decoder.feed(memoryview(encode_frame(b)))
    assert [key(f) for f in out] == [key(a), key(b)]


def test_host_time_is_stamped() -> None:
    a, b = make_frames(2)
    decoder = FrameDecoder()
    before = time.monotonic()
    [out] = decoder.feed(encode_frame(a))
    assert before <= out.host_time <= time.monotonic()
    [out] = decoder.feed(encode_frame(b), host_time=42.25)
    assert out.host_time == 42.25


# --- garbage and resynchronisation ------------------------------------------------------------

@settings(max_examples=150, deadline=None)
@given(st.one_of(st.binary(min_size=1, max_size=600),
                 st.binary(max_size=600).map(lambda b: b.replace(b"\x00", b"\x5a"))),
       st.integers(1, 64))
def test_garbage_between_frames(garbage: bytes, chunk: int) -> None:
    before, after = make_frames(6)[:3], make_frames(6)[3:]
    stream = b"".join(map(encode_frame, before)) + garbage + b"".join(map(encode_frame, after))
    decoder = FrameDecoder()
    out = decode_all(decoder, [stream[i : i + chunk] for i in range(0, len(stream), chunk)])
    good = {key(f) for f in before + after}
    assert all(key(f) in good for f in out)  # nothing corrupt is ever accepted
    delivered = [f.seq for f in out]
    # Garbage ending in 0x00 costs nothing; otherwise it is glued to the next frame only.
    clean_end = not garbage or garbage.endswith(b"\x00")
    expected = [0, 1, 2, 3, 4, 5] if clean_end else [0, 1, 2, 4, 5]
    assert delivered == expected
    assert decoder.stats.lost == 6 - len(expected)
    if garbage.strip(b"\x00"):
        assert decoder.stats.rejected >= 1 and decoder.stats.resyncs == 1


def test_memory_bounded_under_long_garbage() -> None:
    rng = np.random.default_rng(5)
    garbage = rng.integers(1, 256, 50_000).astype(np.uint8).tobytes()  # no 0x00 at all
    a, b, c = make_frames(3)
    decoder = FrameDecoder()
    out = decoder.feed(encode_frame(a))
    for i in range(0, len(garbage), 1000):
        out += decoder.feed(garbage[i : i + 1000])
        assert decoder.buffered <= MAX_ENCODED_LEN
    out += decoder.feed(encode_frame(b) + encode_frame(c))
    assert decoder.stats.oversize == 1  # one over-long run, counted once
    assert [f.seq for f in out] == [0, 2]  # b's delimiter ends the run; c is intact
    assert decoder.buffered == 0


def test_oversize_chunk_in_one_feed() -> None:
    decoder = FrameDecoder()
    a, b = make_frames(2)
    junk = b"\x01" * (MAX_ENCODED_LEN + 1) + b"\x00"
    out = decoder.feed(junk + encode_frame(a) + encode_frame(b))
    assert decoder.stats.oversize == 1 and [f.seq for f in out] == [0, 1]


@pytest.mark.parametrize("shape", [(2, 2), (8, 8)])
def test_every_single_bit_flip_is_rejected(shape: tuple[int, int]) -> None:
    f0, f1, f2, f3 = make_frames(4, shape=shape)
    wire = encode_frame(f1)
    head, tail = encode_frame(f0), encode_frame(f2) + encode_frame(f3)
    for bit in range(8 * len(wire)):
        bad = bytearray(wire)
        bad[bit // 8] ^= 1 << (bit % 8)
        decoder = FrameDecoder()
        out = decoder.feed(head + bytes(bad) + tail)
        delimiter_hit = bit // 8 == len(wire) - 1  # glues f1 to f2: both lost
        expected = [f0, f3] if delimiter_hit else [f0, f2, f3]
        assert [key(f) for f in out] == [key(f) for f in expected], bit
        assert decoder.stats.rejected >= 1, bit
        assert decoder.stats.lost == (2 if delimiter_hit else 1)


def test_truncated_frames_at_every_length() -> None:
    f0, f1, f2 = make_frames(3)
    wire = encode_frame(f1)[:-1]
    for cut in range(1, len(wire)):
        decoder = FrameDecoder()
        # The sender resets mid-frame and sends its start-up 0x00.
        out = decoder.feed(encode_frame(f0) + wire[:cut] + b"\x00" + encode_frame(f2))
        assert [f.seq for f in out] == [0, 2], cut
        assert decoder.stats.truncated == 1 and decoder.stats.rejected == 1, cut
        assert decoder.stats.lost == 1 and decoder.stats.resyncs == 1


# --- header errors ----------------------------------------------------------------------------

@pytest.mark.parametrize(
    ("header", "counter"),
    [
        ({"rows": 4}, "length_errors"),  # 4x8 declared, 8x8 sent
        ({"cols": 9}, "length_errors"),  # 8x9 declared
        ({"rows": 0}, "length_errors"),
        ({"rows": 65, "cols": 65}, "length_errors"),  # over MAX_TACTELS
        ({"version": 3}, "version_errors"),
        ({"version": 2}, "length_errors"),  # version 2 with axes 0 (the flags byte)
    ],
)
def test_sender_header_errors_with_good_crc(header: dict, counter: str) -> None:
    a, b, c = make_frames(3)
    decoder = FrameDecoder()
    out = decoder.feed(encode_frame(a) + reencode(b, **header) + encode_frame(c))
    assert [f.seq for f in out] == [0, 2]
    assert getattr(decoder.stats, counter) == 1 and decoder.stats.rejected == 1


def test_flags_are_ignored() -> None:
    [frame] = make_frames(1)
    [out] = FrameDecoder().feed(reencode(frame, flags=0x80))
    assert key(out) == key(frame)


@pytest.mark.parametrize(("field", "offset", "value", "counter"),
                         [("rows", 16, 9, "truncated"), ("rows", 16, 7, "crc_errors"),
                          ("cols", 17, 200, "truncated"), ("cols", 17, 1, "crc_errors")])
def test_length_fields_corrupted_in_transit(field: str, offset: int, value: int,
                                            counter: str) -> None:
    a, b, c = make_frames(3)
    body = bytearray(cobs_decode(encode_frame(b)[:-1]))
    body[offset] = value  # CRC left as sent
    decoder = FrameDecoder()
    out = decoder.feed(encode_frame(a) + cobs_encode(bytes(body)) + b"\x00" + encode_frame(c))
    assert [f.seq for f in out] == [0, 2], field
    assert getattr(decoder.stats, counter) == 1 and decoder.stats.rejected == 1


# --- sequence numbers -------------------------------------------------------------------------

def run_seqs(seqs: list[int],
             sensor_ids: list[int] | None = None) -> tuple[list[int], DecoderStats]:
    raw = np.ones((2, 2), dtype=np.uint16)
    ids = sensor_ids or [0] * len(seqs)
    stream = b"".join(encode_frame(Frame(seq=s, device_time_us=k, sensor_id=i, raw=raw))
                      for k, (s, i) in enumerate(zip(seqs, ids, strict=True)))
    decoder = FrameDecoder()
    return [f.seq for f in decoder.feed(stream)], decoder.stats


@pytest.mark.parametrize(
    ("seqs", "delivered", "lost", "duplicated", "restarts"),
    [
        ([0, 1, 2, 3], [0, 1, 2, 3], 0, 0, 0),
        ([0, 1, 5, 6], [0, 1, 5, 6], 3, 0, 0),
        ([0, 1, 1, 2, 2, 2], [0, 1, 2], 0, 3, 0),
        ([U32 - 2, U32 - 1, 0, 1], [U32 - 2, U32 - 1, 0, 1], 0, 0, 0),  # wrap-around
        ([U32 - 2, 1], [U32 - 2, 1], 2, 0, 0),  # a gap across the wrap
        ([U32 - 1, U32 - 1, 0], [U32 - 1, 0], 0, 1, 0),
        ([100, 101, 0, 1], [100, 101, 0, 1], 0, 0, 1),  # device reset
        ([5, 3], [5, 3], 0, 0, 1),  # any step backwards is a restart
        ([3, 2**31 + 2], [3, 2**31 + 2], 2**31 - 2, 0, 0),  # largest forward gap
        ([3, 2**31 + 3], [3, 2**31 + 3], 0, 0, 1),  # half the ring: taken as backwards
    ],
)
def test_sequence_bookkeeping(seqs: list[int], delivered: list[int], lost: int, duplicated: int,
                              restarts: int) -> None:
    out, stats = run_seqs(seqs)
    assert out == delivered
    assert (stats.lost, stats.duplicated, stats.restarts) == (lost, duplicated, restarts)
    assert stats.frames == len(delivered)


@settings(max_examples=100, deadline=None)
@given(st.integers(0, U32 - 1), st.lists(st.integers(1, 1000), min_size=1, max_size=20))
def test_gaps_are_counted_across_wrap_around(start: int, steps: list[int]) -> None:
    seqs = [start]
    for step in steps:
        seqs.append((seqs[-1] + step) % U32)
    out, stats = run_seqs(seqs)
    assert out == seqs
    assert stats.lost == sum(steps) - len(steps) and stats.restarts == 0


def test_sequences_are_tracked_per_sensor() -> None:
    out, stats = run_seqs([10, 500, 11, 501, 12, 503], sensor_ids=[1, 2, 1, 2, 1, 2])
    assert out == [10, 500, 11, 501, 12, 503]
    assert stats.lost == 1 and stats.duplicated == 0


def test_reset_forgets_partial_data_and_sequence() -> None:
    a, b = make_frames(2)
    decoder = FrameDecoder()
    decoder.feed(encode_frame(a) + encode_frame(b)[:20])
    decoder.reset()
    assert decoder.buffered == 0
    assert [f.seq for f in decoder.feed(encode_frame(a))] == [0]  # not a restart any more
    assert decoder.stats.restarts == 0 and decoder.stats.rejected == 0


# --- fuzz -------------------------------------------------------------------------------------

GOOD = make_frames(4, shape=(3, 5), seed=9) + make_frames(2, start=U32 - 1, seed=8)
GOOD_WIRE = [encode_frame(f) for f in GOOD]
GOOD_KEYS = {key(f) for f in GOOD}


@st.composite
def hostile_streams(draw: st.DrawFn) -> bytes:
    """Random bytes, zeros, good frames, and good frames cut or corrupted."""
    parts = []
    for _ in range(draw(st.integers(0, 12))):
        kind = draw(st.sampled_from(["bytes", "zeros", "frame", "cut", "flip", "ff"]))
        if kind == "bytes":
            parts.append(draw(st.binary(max_size=300)))
        elif kind == "zeros":
            parts.append(b"\x00" * draw(st.integers(1, 3)))
        elif kind == "ff":
            parts.append(b"\xff" * draw(st.integers(1, 2000)))
        else:
            wire = bytearray(draw(st.sampled_from(GOOD_WIRE)))
            if kind == "cut":
                wire = wire[: draw(st.integers(0, len(wire)))]
            elif kind == "flip":
                pos = draw(st.integers(0, 8 * len(wire) - 1))
                wire[pos // 8] ^= 1 << (pos % 8)
            parts.append(bytes(wire))
    return b"".join(parts)


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.binary(max_size=3000), hostile_streams()), st.integers(1, 512))
def test_fuzz_never_raises_and_stays_bounded(stream: bytes, chunk: int) -> None:
    decoder = FrameDecoder()
    out = []
    for i in range(0, len(stream), chunk):
        out += decoder.feed(stream[i : i + chunk])
        assert decoder.buffered <= MAX_ENCODED_LEN
    assert all(key(f) in GOOD_KEYS for f in out)  # only intact frames get through
    stats = asdict(decoder.stats)
    assert all(v >= 0 for v in stats.values()) and stats["frames"] == len(out)
    assert decoder.stats.bytes == len(stream)


def test_fuzz_huge_stream_of_garbage() -> None:
    rng = np.random.default_rng(11)
    decoder = FrameDecoder()
    for _ in range(20):
        data = rng.integers(0, 256, 50_000).astype(np.uint8)
        data[data < 2] = 1 if rng.random() < 0.5 else 0  # with and without zeros
        assert decoder.feed(data.tobytes()) == []
        assert decoder.buffered <= MAX_ENCODED_LEN
    assert decoder.stats.rejected > 0


# --- many frames in fixed pieces ----------------------------------------------------------------
# (The decoder's speed is a benchmark's: ``python -m tactiled_bench.framer_cost``.)

def test_1000_frames_in_512_byte_pieces_come_out_whole_and_in_order(same_frame) -> None:
    rng = np.random.default_rng(2)
    # Counts below 256: a zero high byte per tactel, the most COBS groups per frame.
    batch = [Frame(seq=k, device_time_us=k, raw=rng.integers(0, 256, (8, 8)).astype(np.uint16))
             for k in range(1000)]
    stream = b"".join(map(encode_frame, batch))
    pieces = [stream[i : i + 512] for i in range(0, len(stream), 512)]
    decoder = FrameDecoder()
    out = decode_all(decoder, pieces)
    assert len(out) == 1000
    assert all(same_frame(a, b) for a, b in zip(out, batch, strict=True))
    stats = decoder.stats
    assert (stats.frames, stats.bytes, stats.rejected, stats.lost) == (1000, len(stream), 0, 0)
    assert decoder.buffered == 0

"""Hostile input for the frame decoder: property-based fuzz (hypothesis) of byte streams, a time
bound per megabyte for the worst patterns, and bounded memory over long streams.

Each runs against the Python reference (``FrameDecoder``) and the compiled core's decoder
(``NativeFrameDecoder``), and the two must agree frame for frame and
counter for counter.  ``FrameDecoder.feed`` must never raise, whatever the bytes: every bad chunk between two 0x00 is
counted once in its stats (and nothing else happens), it holds at most ``MAX_ENCODED_LEN`` bytes
between calls, and the result does not depend on how the stream is cut into reads.
"""

from __future__ import annotations

import gc
import os
import random
import time
import tracemalloc
from dataclasses import asdict

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rel_helpers import figures

from tactiled.frames import MAX_ENCODED_LEN, Frame, FrameDecoder, NativeFrameDecoder, encode_frame

MB = 1 << 20
READ = 4096  # bytes per read, as the serial driver reads

#: the decoders under test: the reference, and the core's (built by the install, whichever of
#: the two TACTILED_CORE selects for the daemon)
DECODERS = [FrameDecoder, NativeFrameDecoder]
each_decoder = pytest.mark.parametrize("make", DECODERS, ids=lambda c: c.__name__)

FUZZ = settings(max_examples=300, deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


# --------------------------------------------------------------------------------------------
# Streams


@st.composite
def frames_bytes(draw: st.DrawFn) -> bytes:
    rows = draw(st.integers(1, 10))
    cols = draw(st.integers(1, 10))
    axes = draw(st.sampled_from([1, 3]))  # a 1-axis (version 1) or 3-axis (version 2) frame
    counts = np.asarray(draw(st.lists(st.integers(0, 65535), min_size=rows * cols * axes,
                                      max_size=rows * cols * axes)), dtype=np.uint16)
    taxels = None if axes == 1 else counts.reshape(rows, cols, 3)
    raw = counts.reshape(rows, cols) if axes == 1 else taxels[..., 2].copy()
    frame = Frame(seq=draw(st.integers(0, 2**32 - 1)),
                  device_time_us=draw(st.integers(0, 2**64 - 1)), raw=raw,
                  sensor_id=draw(st.sampled_from([0, 1, 7, 65535])), taxels=taxels)
    return encode_frame(frame)


@st.composite
def damaged(draw: st.DrawFn) -> bytes:
    """A valid frame, cut short, with bits flipped, or without its delimiter."""
    data = bytearray(draw(frames_bytes()))
    how = draw(st.sampled_from(["cut", "flip", "glue", "zero_inside"]))
    if how == "cut":
        data = data[:draw(st.integers(1, len(data) - 1))]
    elif how == "flip":
        for _ in range(draw(st.integers(1, 4))):
            i = draw(st.integers(0, len(data) - 1))
            data[i] ^= 1 << draw(st.integers(0, 7))
    elif how == "glue":
        data = data[:-1]
    else:
        data[draw(st.integers(0, len(data) - 2))] = 0
    return bytes(data)


pieces = st.one_of(
    frames_bytes(),
    damaged(),
    st.binary(min_size=1, max_size=300),
    st.binary(min_size=MAX_ENCODED_LEN - 5, max_size=MAX_ENCODED_LEN + 20).map(
        lambda b: b.replace(b"\x00", b"\x01")),  # around the oversize bound, no delimiter
    st.just(b"\x00"),
    st.just(b"\x00" * 5),
)
streams = st.lists(pieces, max_size=25).map(b"".join)


def feed_in_pieces(data: bytes, cuts: list[int], make: type = FrameDecoder,
                   ) -> tuple[FrameDecoder, list[Frame], int]:
    """Feed ``data`` cut at ``cuts`` to a new ``make()``; returns the decoder, its frames and
    the most bytes it held between calls.  Any exception escapes (and fails the test)."""
    dec = make()
    out: list[Frame] = []
    held = 0
    for a, b in zip(cuts, cuts[1:]):
        out += dec.feed(data[a:b], host_time=1.0)
        held = max(held, dec.buffered)
        assert dec.buffered <= MAX_ENCODED_LEN
    return dec, out, held


def wire(frame: Frame) -> tuple[int, int, int, bytes, bytes | None]:
    taxels = None if frame.taxels is None else frame.taxels.tobytes()
    return (frame.sensor_id, frame.seq, frame.device_time_us, frame.raw.tobytes(), taxels)


def expected_outcomes(data: bytes) -> int:
    """Chunks between 0x00 that each end as exactly one of: delivered, duplicate, rejected."""
    *complete, tail = data.split(b"\x00")
    return sum(1 for c in complete if c) + (len(tail) > MAX_ENCODED_LEN)


@each_decoder
def test_an_oversize_tail_after_a_good_frame_is_not_a_resync(make: type) -> None:
    """Found by the fuzz below (bug 6): a good frame then more than MAX_ENCODED_LEN bytes
    with no 0x00, read at once, counted the tail's rejection before the frame and so the
    frame as a resync; read in two pieces it did not.  Stream order is what counts."""
    good = encode_frame(Frame(seq=1, device_time_us=1, raw=np.zeros((8, 8), np.uint16)))
    stream = good + b"\x01" * (MAX_ENCODED_LEN + 10)
    for cuts in ([0, len(stream)], [0, len(good), len(stream)], [0, 26, len(stream)]):
        dec, frames, _ = feed_in_pieces(stream, cuts, make)
        assert len(frames) == 1 and dec.stats.oversize == 1, cuts
        assert dec.stats.resyncs == 0, cuts


@each_decoder
@FUZZ
@given(data=st.data(), stream=streams)
def test_fuzzed_streams_are_counted_and_cut_anywhere(make: type, data: st.DataObject,
                                                     stream: bytes) -> None:
    whole, whole_frames, _ = feed_in_pieces(stream, [0, len(stream)], make)
    cuts = data.draw(st.lists(st.integers(0, len(stream)), max_size=30).map(
        lambda points: [0, *sorted(set(points)), len(stream)]))
    cut, cut_frames, _ = feed_in_pieces(stream, cuts, make)
    # How the stream is cut into reads changes nothing.
    assert [wire(f) for f in cut_frames] == [wire(f) for f in whole_frames]
    assert asdict(cut.stats) == asdict(whole.stats)
    s = whole.stats
    # Every chunk is accounted for exactly once: delivered, dropped as a duplicate, or rejected
    # (and counted in one of the rejection counters).
    assert s.frames + s.duplicated + s.rejected == expected_outcomes(stream)
    assert s.frames == len(whole_frames) and s.bytes == len(stream)
    # Nothing is delivered that was not sent as that exact frame.
    chunks = set(stream.split(b"\x00"))
    assert all(encode_frame(f)[:-1] in chunks for f in whole_frames)


@FUZZ
@given(data=st.data(), stream=streams)
def test_the_core_decodes_as_the_reference(data: st.DataObject, stream: bytes) -> None:
    """The same frames (header, shape, dtype, counts), the same counters, the same bytes held,
    however the stream is cut."""
    cuts = data.draw(st.lists(st.integers(0, len(stream)), max_size=30).map(
        lambda points: [0, *sorted(set(points)), len(stream)]))
    ref, ref_frames, ref_held = feed_in_pieces(stream, cuts, FrameDecoder)
    got, got_frames, got_held = feed_in_pieces(stream, cuts, NativeFrameDecoder)
    assert [wire(f) for f in got_frames] == [wire(f) for f in ref_frames]
    assert all(f.raw.dtype == np.uint16 and f.raw.shape == r.raw.shape and f.host_time == 1.0
               for f, r in zip(got_frames, ref_frames))
    assert asdict(got.stats) == asdict(ref.stats)
    assert (got.buffered, got_held) == (ref.buffered, ref_held)


@each_decoder
@FUZZ
@given(stream=st.binary(max_size=30000), step=st.integers(1, 9000))
def test_random_bytes_never_raise(make: type, stream: bytes, step: int) -> None:
    cuts = [*range(0, len(stream), step), len(stream)]
    dec, frames, held = feed_in_pieces(stream, cuts, make)
    assert held <= MAX_ENCODED_LEN
    s = dec.stats
    assert s.frames + s.duplicated + s.rejected == expected_outcomes(stream)


# --------------------------------------------------------------------------------------------
# Time and memory


def _patterns(size: int = MB) -> dict[str, bytes]:
    """``size`` bytes of each kind of hostile stream (and two of valid ones, for scale)."""
    rng = random.Random(1)
    block = b"\x01" * MAX_ENCODED_LEN + b"\x00"
    valid = b"".join(encode_frame(Frame(seq=k, device_time_us=k,
                                        raw=np.full((8, 8), k, np.uint16)))
                     for k in range(size // 152 + 1))
    big = b"".join(encode_frame(Frame(seq=k, device_time_us=k, raw=np.random.default_rng(k)
                                      .integers(0, 65536, (64, 64), dtype=np.uint16)))
                   for k in range(size // 8247 + 1))
    return {
        "random bytes": os.urandom(size),
        "no 0x00 at all (oversize)": rng.randbytes(size).replace(b"\x00", b"\x01"),
        "longest chunks of 0x01 (COBS worst)": (block * (size // len(block) + 1))[:size],
        "1-byte chunks": b"\x01\x00" * (size // 2),
        "23-byte chunks with headers": (rng.randbytes(23).replace(b"\x00", b"\x02")
                                        + b"\x00") * (size // 24),
        "valid 8x8 frames": valid[:size],
        "valid 64x64 frames": big[:size],
    }


@each_decoder
def test_each_megabyte_of_the_worst_patterns_is_accounted_for(make: type) -> None:
    """Each megabyte of the worst patterns is read to the end, every chunk ending as exactly
    one outcome, within the held-bytes bound.  The seconds per megabyte are printed (``-rP``),
    not asserted: the decoder's speed is reported by ``python -m tactiled_bench.framer_cost``
    (``wire``); a decoder that hung would hit the suite's timeout."""
    results = {}
    for name, data in _patterns().items():
        cuts = [*range(0, len(data), READ), len(data)]
        t = time.perf_counter()
        dec, frames, held = feed_in_pieces(data, cuts, make)
        results[name] = round((time.perf_counter() - t) / (len(data) / MB), 3)
        assert held <= MAX_ENCODED_LEN
        s = dec.stats
        assert s.bytes == len(data), name
        assert s.frames + s.duplicated + s.rejected == expected_outcomes(data), name
        assert len(frames) == s.frames, name
        if name.startswith("valid"):
            # every complete frame delivered: only the cut-off last one is not
            assert s.rejected == 0 and s.frames == expected_outcomes(data), name
    figures(f"decoder_time_per_MB[{make.__name__}]", seconds_per_MB=results)


def _memory_growth(megabytes: int) -> dict:
    """Feed ``megabytes`` of the patterns above (quarter-megabyte blocks, round robin) in
    4096-byte reads; traced memory after the first block and at the end."""
    patterns = list(_patterns(MB // 4).values())
    dec = FrameDecoder()
    gc.collect()
    tracemalloc.start()
    try:
        start = None
        peak_held = 0
        for k in range(4 * megabytes):
            data = patterns[k % len(patterns)]
            for i in range(0, len(data), READ):
                dec.feed(data[i:i + READ], host_time=0.0)
                peak_held = max(peak_held, dec.buffered)
            if k == 0:
                gc.collect()
                start = tracemalloc.get_traced_memory()[0]
        gc.collect()
        end, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert start is not None
    return {"growth_bytes": end - start, "peak_over_start": peak - start,
            "max_buffered": peak_held, "bytes_fed": dec.stats.bytes,
            "rejected": dec.stats.rejected, "frames": dec.stats.frames}


@pytest.mark.parametrize("megabytes", [4, pytest.param(64, marks=pytest.mark.slow)])
def test_memory_is_bounded_over_a_long_stream(megabytes: int) -> None:
    r = _memory_growth(megabytes)
    assert r["max_buffered"] <= MAX_ENCODED_LEN
    assert r["growth_bytes"] < 16 * 1024, r  # nothing accumulates
    assert r["peak_over_start"] < 256 * 1024, r  # one read and one chunk at a time
    figures(f"decoder_memory[{megabytes} MB]", **r)


@pytest.mark.parametrize("ids", [16384, pytest.param(65536, marks=pytest.mark.slow)])
def test_sequence_memory_is_bounded_by_the_sensor_id_space(ids: int) -> None:
    """The one structure that grows with the input: the last seq per sensor id, at most 65536
    entries (a stream claiming every possible sensor id; ~70 bytes each)."""
    sweeps = [b"".join(encode_frame(Frame(seq=seq, device_time_us=0,
                                          raw=np.zeros((1, 1), np.uint16), sensor_id=sid))
                       for sid in range(ids)) for seq in (0, 1)]
    dec = FrameDecoder()
    gc.collect()
    tracemalloc.start()
    try:
        start = tracemalloc.get_traced_memory()[0]
        grown = []
        for data in sweeps:
            for i in range(0, len(data), READ):
                dec.feed(data[i:i + READ], host_time=0.0)
            grown.append(tracemalloc.get_traced_memory()[0] - start)
    finally:
        tracemalloc.stop()
    assert dec.stats.frames == 2 * ids
    assert grown[1] - grown[0] < 64 * 1024  # a second sweep adds nothing
    assert grown[0] < 128 * ids  # bytes per sensor id seen: 8 MB for all 65536
    figures(f"decoder_sequence_memory[{ids} ids]", bytes=grown[0],
            bytes_per_id=round(grown[0] / ids, 1))

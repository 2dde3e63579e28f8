"""3-axis frames on the wire (version 2, docs/reference/protocol.md): round trips through both
decoders, the worked example, and hostile headers counted and skipped."""

from __future__ import annotations

import re
import zlib
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest

from tactiled.frames import (
    HEADER,
    MAX_TACTELS,
    VERSION,
    VERSION_AXES,
    Frame,
    FrameDecoder,
    NativeFrameDecoder,
    cobs_decode,
    cobs_encode,
    decode_frame,
    encode_frame,
)

DECODERS = [FrameDecoder, NativeFrameDecoder]
each_decoder = pytest.mark.parametrize("make", DECODERS, ids=lambda c: c.__name__)
PROTOCOL_MD = Path(__file__).resolve().parents[2] / "docs" / "reference" / "protocol.md"


def taxel_frames(n: int, shape: tuple[int, int] = (4, 4), seed: int = 0,
                 start: int = 0) -> list[Frame]:
    """Consecutive 3-axis frames, x y z counts drawn over the whole uint16 range."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        xyz = rng.integers(0, 0x10000, (*shape, 3)).astype(np.uint16)
        out.append(Frame(seq=start + k, device_time_us=1000 * k, sensor_id=3,
                         raw=xyz[..., 2].copy(), taxels=xyz))
    return out


def key(frame: Frame) -> tuple:
    taxels = None if frame.taxels is None else (frame.taxels.shape, frame.taxels.tobytes())
    return (frame.seq, frame.device_time_us, frame.sensor_id, frame.raw.shape,
            frame.raw.tobytes(), taxels)


def body_of(frame: Frame) -> bytearray:
    return bytearray(cobs_decode(encode_frame(frame)[:-1]))


def with_crc(body: bytes) -> bytes:
    """A sender's frame: ``body`` (header and counts) with its CRC, encoded and delimited."""
    return cobs_encode(body + zlib.crc32(body).to_bytes(4, "little")) + b"\x00"


@each_decoder
def test_3_axis_frames_round_trip_with_x_y_z_per_taxel(make: type) -> None:
    frames = taxel_frames(5, shape=(4, 6))
    out = make().feed(b"".join(encode_frame(f) for f in frames), host_time=1.0)
    assert [key(f) for f in out] == [key(f) for f in frames]
    for f in out:
        assert f.axes == 3 and f.taxels.shape == (4, 6, 3) and f.taxels.dtype == np.uint16
        np.testing.assert_array_equal(f.raw, f.taxels[..., 2])  # z: what the 1-axis path reads


def test_the_header_says_version_2_and_3_axes_and_the_counts_are_x_y_z_per_taxel() -> None:
    [frame] = taxel_frames(1, shape=(2, 3))
    body = body_of(frame)
    version, axes, _, _, _, rows, cols = HEADER.unpack_from(body)
    assert (version, axes, rows, cols) == (VERSION_AXES, 3, 2, 3)
    counts = np.frombuffer(bytes(body[HEADER.size:-4]), dtype="<u2")
    # taxel [1, 2]'s y is count (1 * 3 + 2) * 3 + 1
    assert counts[(1 * 3 + 2) * 3 + 1] == frame.taxels[1, 2, 1]
    assert len(body) == HEADER.size + 2 * 2 * 3 * 3 + 4


def test_a_1_axis_frame_is_version_1_as_it_always_was() -> None:
    raw = np.arange(6, dtype=np.uint16).reshape(2, 3)
    body = body_of(Frame(seq=1, device_time_us=2, raw=raw))
    assert body[0] == VERSION and body[1] == 0 and len(body) == HEADER.size + 12 + 4


@each_decoder
def test_1_and_3_axis_frames_interleave_in_one_stream(make: type) -> None:
    """Two sensors on one stream, one of each kind; seq tracked per sensor as before."""
    three = taxel_frames(4)
    one = [Frame(seq=k, device_time_us=k, sensor_id=9, raw=np.full((8, 8), k, np.uint16))
           for k in range(4)]
    stream = b"".join(encode_frame(f) for pair in zip(three, one) for f in pair)
    dec = make()
    out = dec.feed(stream, host_time=1.0)
    assert [f.axes for f in out] == [3, 1] * 4
    assert dec.stats.frames == 8 and dec.stats.lost == 0 and dec.stats.rejected == 0


@each_decoder
def test_a_version_2_frame_of_1_axis_is_a_1_axis_frame(make: type) -> None:
    raw = np.arange(4, dtype=np.uint16).reshape(2, 2)
    body = HEADER.pack(VERSION_AXES, 1, 0, 5, 6, 2, 2) + raw.astype("<u2").tobytes()
    [f] = make().feed(with_crc(body), host_time=1.0)
    assert f.taxels is None and f.axes == 1
    np.testing.assert_array_equal(f.raw, raw)


@pytest.mark.parametrize(
    ("header", "counts", "counter"),
    [
        # 3 axes claimed, 1 axis of counts sent: the sender's error, CRC good
        ({"axes": 3}, 16, "length_errors"),
        ({"axes": 3}, 3 * 16 + 1, "length_errors"),
        ({"axes": 2}, 2 * 16, "length_errors"),  # no such kind of taxel
        ({"axes": 0}, 0, "length_errors"),
        ({"axes": 255}, 16, "length_errors"),
        ({"rows": 37, "cols": 37}, 3 * 16, "length_errors"),  # 4107 counts: over MAX_TACTELS
        ({"version": 3}, 3 * 16, "version_errors"),
    ],
)
@each_decoder
def test_hostile_3_axis_headers_with_good_crc_are_counted_and_skipped(
        make: type, header: dict, counts: int, counter: str) -> None:
    a, b, c = taxel_frames(3)
    fields = {"version": VERSION_AXES, "axes": 3, "sensor_id": 3, "seq": 1, "t": 1000,
              "rows": 4, "cols": 4} | header
    bad = with_crc(HEADER.pack(*fields.values()) + b"\x01\x02" * counts)
    dec = make()
    out = dec.feed(encode_frame(a) + bad + encode_frame(c), host_time=1.0)
    assert [f.seq for f in out] == [0, 2]
    assert getattr(dec.stats, counter) == 1 and dec.stats.rejected == 1
    assert dec.stats.lost == 1 and dec.stats.resyncs == 1


def test_37_by_37_would_pass_as_1_axis_but_not_as_3() -> None:
    assert 37 * 37 <= MAX_TACTELS < 3 * 37 * 37


@each_decoder
def test_a_3_axis_frame_cut_at_every_length_is_truncated(make: type) -> None:
    f0, f1, f2 = taxel_frames(3)
    wire = encode_frame(f1)[:-1]
    for cut in range(1, len(wire)):
        dec = make()
        out = dec.feed(encode_frame(f0) + wire[:cut] + b"\x00" + encode_frame(f2), host_time=1.0)
        assert [f.seq for f in out] == [0, 2], cut
        assert dec.stats.truncated == 1 and dec.stats.rejected == 1, cut


@each_decoder
def test_every_single_bit_flip_of_a_3_axis_frame_is_rejected(make: type) -> None:
    f0, f1, f2, f3 = taxel_frames(4, shape=(2, 2))
    wire = encode_frame(f1)
    head, tail = encode_frame(f0), encode_frame(f2) + encode_frame(f3)
    for bit in range(8 * len(wire)):
        bad = bytearray(wire)
        bad[bit // 8] ^= 1 << (bit % 8)
        dec = make()
        out = dec.feed(head + bytes(bad) + tail, host_time=1.0)
        glued = bit // 8 == len(wire) - 1
        expected = [f0, f3] if glued else [f0, f2, f3]
        assert [key(f) for f in out] == [key(f) for f in expected], bit
        assert dec.stats.rejected >= 1, bit


def test_the_two_decoders_agree_on_a_mixed_hostile_stream() -> None:
    rng = np.random.default_rng(5)
    frames = taxel_frames(30, shape=(4, 6), seed=2)
    pieces = []
    for f in frames:
        wire = bytearray(encode_frame(f))
        kind = rng.integers(0, 4)
        if kind == 1:
            wire = wire[: rng.integers(1, len(wire))]
        elif kind == 2:
            wire[rng.integers(0, len(wire) - 1)] ^= 0x10
        pieces.append(bytes(wire))
    stream = b"".join(pieces)
    cuts = sorted({0, len(stream), *rng.integers(0, len(stream), 20).tolist()})
    ref, got = FrameDecoder(), NativeFrameDecoder()
    for a, b in zip(cuts, cuts[1:]):
        want, have = ref.feed(stream[a:b], 1.0), got.feed(stream[a:b], 1.0)
        assert [key(f) for f in have] == [key(f) for f in want]
    assert asdict(got.stats) == asdict(ref.stats)
    assert ref.stats.frames > 0 and ref.stats.rejected > 0


@pytest.mark.parametrize(
    ("taxels", "match"),
    [
        (np.zeros((2, 2, 2), np.uint16), "shape"),
        (np.zeros((2, 2), np.uint16), "shape"),
        (np.full((2, 2, 3), -1), "uint16"),
        (np.zeros((40, 40, 3), np.uint16), "counts"),
        (np.zeros((0, 2, 3), np.uint16), "rows and cols"),
    ],
)
def test_unencodable_taxels_raise_value_error(taxels: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        encode_frame(Frame(seq=0, device_time_us=0, raw=np.zeros((2, 2), np.uint16),
                           taxels=taxels))


def test_decode_frame_reads_one_3_axis_frame() -> None:
    [frame] = taxel_frames(1)
    assert key(decode_frame(encode_frame(frame))) == key(frame)


# --- the worked example of docs/reference/protocol.md ----------------------------------------

def doc_hex(marker: str) -> bytes:
    text = PROTOCOL_MD.read_text()
    match = re.search(rf"<!-- worked-example:{marker} -->\s*```text\n(.*?)```", text, re.S)
    assert match, f"no worked-example:{marker} block in {PROTOCOL_MD}"
    return bytes.fromhex(match.group(1))


EXAMPLE = Frame(seq=258, device_time_us=1_000_000, sensor_id=7,
                raw=np.array([[0x0300, 0x8000]], np.uint16),
                taxels=np.array([[[0x0001, 0x0102, 0x0300], [0x7FFF, 0xFFFF, 0x8000]]],
                                np.uint16))


def test_3_axis_worked_example_body_matches_doc() -> None:
    body = doc_hex("body3")
    assert bytes(body_of(EXAMPLE)) == body
    assert int.from_bytes(body[-4:], "little") == zlib.crc32(body[:-4])


def test_3_axis_worked_example_wire_bytes_match_doc() -> None:
    wire = doc_hex("wire3")
    assert encode_frame(EXAMPLE) == wire
    assert key(decode_frame(wire)) == key(EXAMPLE)

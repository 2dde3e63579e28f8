"""COBS, the frame encoder, and the worked example and C sketch in docs/reference/protocol.md."""

from __future__ import annotations

import re
import shutil
import subprocess
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactiled.errors import FrameError
from tactiled.frames import (
    MAX_ENCODED_LEN,
    MAX_TACTELS,
    Frame,
    cobs_decode,
    cobs_encode,
    decode_frame,
    encode_frame,
)

PROTOCOL_MD = Path(__file__).resolve().parents[2] / "docs" / "reference" / "protocol.md"

# The worked example of docs/reference/protocol.md.
EXAMPLE = Frame(seq=258, device_time_us=1_000_000, sensor_id=7,
                raw=np.array([[0x0000, 0x0102], [0x0300, 0xFFFF]], dtype=np.uint16))


def doc_hex(marker: str) -> bytes:
    """The hex bytes of the fenced block following ``<!-- worked-example:{marker} -->``."""
    text = PROTOCOL_MD.read_text()
    match = re.search(rf"<!-- worked-example:{marker} -->\s*```text\n(.*?)```", text, re.S)
    assert match, f"no worked-example:{marker} block in {PROTOCOL_MD}"
    return bytes.fromhex(match.group(1))


def doc_c_sketch() -> str:
    match = re.search(r"```c\n(.*?)```", PROTOCOL_MD.read_text(), re.S)
    assert match, "no C sketch in docs/reference/protocol.md"
    return match.group(1)


# --- COBS -------------------------------------------------------------------------------------

R = bytes(range(256))
# Wikipedia's "Consistent Overhead Byte Stuffing" examples (without the trailing delimiter).
COBS_VECTORS = [
    (b"", b"\x01"),
    (b"\x00", b"\x01\x01"),
    (b"\x00\x00", b"\x01\x01\x01"),
    (b"\x00\x11\x00", b"\x01\x02\x11\x01"),
    (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
    (b"\x11\x22\x33\x44", b"\x05\x11\x22\x33\x44"),
    (b"\x11\x00\x00\x00", b"\x02\x11\x01\x01\x01"),
    (R[1:255], b"\xff" + R[1:255]),
    (R[0:255], b"\x01\xff" + R[1:255]),
    (R[1:256], b"\xff" + R[1:255] + b"\x02\xff"),
    (R[2:256] + b"\x00", b"\xff" + R[2:256] + b"\x01\x01"),
    (R[3:256] + b"\x00\x01", b"\xfe" + R[3:256] + b"\x02\x01"),
]


@pytest.mark.parametrize(("data", "encoded"), COBS_VECTORS)
def test_cobs_reference_vectors(data: bytes, encoded: bytes) -> None:
    assert cobs_encode(data) == encoded
    assert cobs_decode(encoded) == data


@settings(max_examples=200, deadline=None)
@given(st.one_of(
    st.binary(max_size=1200),
    st.lists(st.sampled_from([b"\x00", b"\x01", b"\xff" * 300]), max_size=8).map(b"".join),
))
def test_cobs_round_trip(data: bytes) -> None:
    encoded = cobs_encode(data)
    assert b"\x00" not in encoded
    assert len(encoded) <= len(data) + max(1, -(-len(data) // 254))  # the documented overhead
    assert cobs_decode(encoded) == data


@pytest.mark.parametrize("bad", [b"", b"\x05\x01", b"\x02\x01\x00\x01", b"\x03\x01"])
def test_cobs_decode_rejects_invalid(bad: bytes) -> None:
    with pytest.raises(FrameError):
        cobs_decode(bad)


# --- encoder ----------------------------------------------------------------------------------

def test_worked_example_body_matches_doc() -> None:
    body = doc_hex("body")
    assert cobs_decode(encode_frame(EXAMPLE)[:-1]) == body
    assert zlib.crc32(body[:-4]) == int.from_bytes(body[-4:], "little")


def test_worked_example_wire_bytes_match_doc() -> None:
    wire = doc_hex("wire")
    assert encode_frame(EXAMPLE) == wire
    decoded = decode_frame(wire)
    assert (decoded.seq, decoded.device_time_us, decoded.sensor_id) == (258, 1_000_000, 7)
    np.testing.assert_array_equal(decoded.raw, EXAMPLE.raw)


def test_encoded_frame_has_exactly_one_zero_at_the_end() -> None:
    raw = np.zeros((64, 64), dtype=np.uint16)  # all zeros: the worst case for COBS runs
    for raw in (raw, np.full((64, 64), 0xFFFF, dtype=np.uint16)):
        wire = encode_frame(Frame(seq=0, device_time_us=0, raw=raw))
        assert wire.index(b"\x00") == len(wire) - 1
        assert len(wire) <= MAX_ENCODED_LEN + 1


def test_encoder_accepts_other_integer_dtypes() -> None:
    counts = np.arange(12).reshape(3, 4)
    wire = encode_frame(Frame(seq=1, device_time_us=2, raw=counts.astype(np.int64)))
    assert wire == encode_frame(Frame(seq=1, device_time_us=2, raw=counts.astype(np.uint16)))
    assert wire == encode_frame(Frame(seq=np.uint32(1), device_time_us=2, raw=counts.astype(float)))


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"raw": np.array([[1, 70000]])}, "70000"),
        ({"raw": np.array([[-1, 2]])}, "-1"),
        ({"raw": np.array([[1.5, 2.0]])}, "1.5"),
        ({"raw": np.array([[np.nan, 2.0]])}, "nan"),
        ({"raw": np.array([["a", "b"]])}, "dtype"),
        ({"raw": np.zeros((0, 4), dtype=np.uint16)}, r"\(0, 4\)"),
        ({"raw": np.zeros(4, dtype=np.uint16)}, r"\(4,\)"),
        ({"raw": np.zeros((256, 1), dtype=np.uint16)}, r"\(256, 1\)"),
        ({"raw": np.zeros((65, 64), dtype=np.uint16)}, "4160"),
        ({"seq": 1 << 32}, "4294967296"),
        ({"seq": -1}, "seq"),
        ({"seq": 1.0}, "seq"),
        ({"sensor_id": 65536}, "65536"),
        ({"device_time_us": 1 << 64}, "18446744073709551616"),
    ],
)
def test_unencodable_frames_raise_value_error_naming_the_value(changes: dict, match: str) -> None:
    fields = {"seq": 0, "device_time_us": 0, "sensor_id": 0, "raw": np.zeros((2, 2), np.uint16)}
    with pytest.raises(ValueError, match=match):
        encode_frame(Frame(**(fields | changes)))


def test_largest_frame_encodes_and_decodes() -> None:
    raw = np.resize(np.arange(MAX_TACTELS, dtype=np.uint16), (64, 64))
    frame = decode_frame(encode_frame(Frame(seq=5, device_time_us=6, raw=raw)))
    np.testing.assert_array_equal(frame.raw, raw)


def test_decode_frame_raises_frame_error() -> None:
    wire = bytearray(encode_frame(EXAMPLE))
    wire[10] ^= 0x10
    with pytest.raises(FrameError, match="crc"):
        decode_frame(bytes(wire))
    with pytest.raises(FrameError, match="several"):
        decode_frame(encode_frame(EXAMPLE) * 2)


# --- the C sketch in docs/reference/protocol.md ---------------------------------------------------------

def c_array(values: np.ndarray) -> str:
    return "{" + ",".join(str(int(v)) for v in values.ravel()) + "}"


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler")
def test_c_sketch_in_doc_matches_encoder(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    frames = [
        EXAMPLE,
        Frame(seq=0xFFFFFFFF, device_time_us=(1 << 64) - 1, sensor_id=0xFFFF,
              raw=rng.integers(0, 300, (8, 8)).astype(np.uint16)),
        # all bytes non-zero: exercises 0xFF runs, including one ending at the last byte
        Frame(seq=0x01010101, device_time_us=0x0101010101010101, sensor_id=0x0101,
              raw=rng.integers(0x0101, 0xFFFF, (16, 16)).astype(np.uint16)),
        Frame(seq=3, device_time_us=4, raw=rng.integers(0, 0x10000, (64, 64)).astype(np.uint16)),
        # a 3-axis array (version 2)
        Frame(seq=9, device_time_us=10, raw=np.zeros((4, 6), np.uint16),
              taxels=rng.integers(0, 0x10000, (4, 6, 3)).astype(np.uint16)),
    ]
    calls = []
    for k, f in enumerate(frames):
        rows, cols = f.shape
        counts = f.raw if f.taxels is None else f.taxels
        calls.append(
            f"static const uint16_t c{k}[] = {c_array(counts)};\n"
            f"n = tactile_encode_frame({f.sensor_id}u, {f.seq}u, {f.device_time_us}ull, "
            f"{rows}, {cols}, {f.axes}, c{k}, wire);\n"
            "for (size_t i = 0; i < n; i++)\n    printf(\"%02x\", wire[i]);\nprintf(\"\\n\");\n"
        )
    main = ("#include <stdio.h>\nint main(void) {\nstatic uint8_t wire[TACTILE_MAX_WIRE];\n"
            "size_t n;\n" + "".join(calls) + "return 0;\n}\n")
    source = tmp_path / "sketch.c"
    source.write_text(doc_c_sketch() + main)
    exe = tmp_path / "sketch"
    flags = ["-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-O1"]
    subprocess.run(["cc", *flags, "-o", str(exe), str(source)],
                   check=True, capture_output=True, timeout=60)
    out = subprocess.run([str(exe)], check=True, capture_output=True, text=True, timeout=60)
    assert out.stdout.split() == [encode_frame(f).hex() for f in frames]

"""An atheris fuzz target for the framers: the compiled core's (the wire format, text lines,
FlexiTac, Robotiq), each input a stream and the reads it is cut into, fed to the core's framer
and to its Python reference: they must agree frame for frame and counter for counter, never
raise, and hold no more than the format's bound (Robotiq: whole 7x4 frames of its finger, at
most two packets' bytes held); between reads the port may reopen (both framers reset).

Run it by hand for as long as you like (libFuzzer's options after the script)::

    .venv/bin/python tests/native/fuzz_framers.py -runs=1000000 -max_len=65536

tests/native/test_fuzz_framers.py runs it briefly (longer with ``-m slow``).  Coverage guides
the Python side only: the extension is built by g++ without libFuzzer's instrumentation, so
the input is built from structure (valid frames, damaged frames, noise, delimiters) rather than
left to coverage to find a CRC.
"""

from __future__ import annotations

import sys
import zlib
from dataclasses import asdict

import atheris

# Only this project's modules are instrumented: coverage of numpy's or the standard library's
# Python code guides nothing here, and instrumenting them made up most of a run's start-up.
with atheris.instrument_imports(include=["tactiled", "tactiled_drivers"]):
    from tactiled.frames import (MAX_ENCODED_LEN, Frame, FrameDecoder, NativeFrameDecoder,
                                  cobs_encode)
    from tactiled_drivers.flexitac import FlexiTacFramer, NativeFlexiTacFramer
    from tactiled_drivers.lines import MAX_LINE, LinesFramer, NativeLinesFramer
    from tactiled_drivers.robotiq import (
        FIELD_BYTES,
        HEADER as ROBOTIQ_HEADER,
        MAX_DATA,
        START,
        NativeRobotiqFramer,
        RobotiqFramer,
        encode_finger,
    )

import numpy as np

HEADER = (1).to_bytes(1, "little")


@atheris.instrument_func
def _wire_frame(fdp: atheris.FuzzedDataProvider) -> bytes:
    """A frame as a device sends it (its header fields drawn, some of them out of range):
    version 1 (1 axis), version 2 (3 axes, or 1; or a hostile count of axes), or any version."""
    rows, cols = fdp.ConsumeIntInRange(0, 70), fdp.ConsumeIntInRange(0, 70)
    kind = fdp.ConsumeIntInRange(0, 3)
    version = (1, 2, 2, fdp.ConsumeIntInRange(0, 255))[kind]
    axes = (0, 3, fdp.ConsumeIntInRange(0, 255), fdp.ConsumeIntInRange(0, 255))[kind]
    head = (bytes([version, axes]) + fdp.ConsumeIntInRange(0, 65535).to_bytes(2, "little")
            + fdp.ConsumeIntInRange(0, 2**32 - 1).to_bytes(4, "little")
            + fdp.ConsumeIntInRange(0, 2**64 - 1).to_bytes(8, "little") + bytes([rows, cols]))
    values = rows * cols * (max(axes, 1) if version == 2 else 1)
    n = values if fdp.ConsumeBool() else fdp.ConsumeIntInRange(0, 5000)
    body = head + fdp.ConsumeBytes(2 * n).ljust(2 * n, b"\x01")
    return cobs_encode(body + zlib.crc32(body).to_bytes(4, "little")) + b"\x00"


@atheris.instrument_func
def _stream(fdp: atheris.FuzzedDataProvider) -> bytes:
    out = bytearray()
    for _ in range(fdp.ConsumeIntInRange(0, 12)):
        kind = fdp.ConsumeIntInRange(0, 5)
        if kind <= 1:
            piece = bytearray(_wire_frame(fdp))
            if kind == 1 and piece:  # damaged: cut, or a byte changed
                i = fdp.ConsumeIntInRange(0, len(piece) - 1)
                if fdp.ConsumeBool():
                    piece = piece[:i]
                else:
                    piece[i] = fdp.ConsumeIntInRange(0, 255)
            out += piece
        elif kind == 2:
            out += fdp.ConsumeBytes(fdp.ConsumeIntInRange(0, 400))
        elif kind == 3:
            out += b"\x00" * fdp.ConsumeIntInRange(1, 3)
        elif kind == 4:  # around the oversize bound, no delimiter
            out += b"\x07" * (MAX_ENCODED_LEN + fdp.ConsumeIntInRange(-3, 3))
        else:
            out += fdp.ConsumeBytes(fdp.ConsumeIntInRange(0, 40))
    return bytes(out)


def _maybe_reset(fdp: atheris.FuzzedDataProvider, ref: object, got: object) -> None:
    """Between two reads, one time in eight, the port reopened: both framers reset (a unit
    cut short by it counted alike, the sequence history forgotten alike)."""
    if fdp.ConsumeIntInRange(0, 7) == 0:
        ref.reset()  # type: ignore[attr-defined]
        got.reset()  # type: ignore[attr-defined]
        assert got.buffered == ref.buffered == 0  # type: ignore[attr-defined]
        assert asdict(got.stats) == asdict(ref.stats)  # type: ignore[attr-defined]


def _wire_key(f: Frame) -> tuple:
    taxels = None if f.taxels is None else (f.taxels.shape, f.taxels.tobytes())
    return (f.seq, f.device_time_us, f.sensor_id, f.raw.shape, f.raw.tobytes(), taxels)


@atheris.instrument_func
def wire_decoders(data: bytes) -> None:
    """The wire format: FrameDecoder against NativeFrameDecoder."""
    fdp = atheris.FuzzedDataProvider(data)
    stream = _stream(fdp)
    cuts = sorted({0, len(stream), *(fdp.ConsumeIntInRange(0, len(stream)) for _ in range(8))})
    ref, got = FrameDecoder(), NativeFrameDecoder()
    for a, b in zip(cuts, cuts[1:]):
        want, have = ref.feed(stream[a:b], 1.0), got.feed(stream[a:b], 1.0)
        assert [_wire_key(f) for f in have] == [_wire_key(f) for f in want]
        assert got.buffered == ref.buffered <= MAX_ENCODED_LEN
        _maybe_reset(fdp, ref, got)
    assert asdict(got.stats) == asdict(ref.stats)


@atheris.instrument_func
def lines_framers(data: bytes) -> None:
    """Text lines: LinesFramer against NativeLinesFramer (a shape, separator and clock column
    drawn; lines of fields built from digits, signs, blanks, underscores and noise)."""
    fdp = atheris.FuzzedDataProvider(data)
    rows, cols = fdp.ConsumeIntInRange(1, 3), fdp.ConsumeIntInRange(1, 3)
    sep = fdp.PickValueInList([",", "space", "tab"])
    time_col = fdp.ConsumeBool()
    unit = fdp.PickValueInList(["ms", "us", "s"])
    joiner = {",": b",", "space": b" ", "tab": b"\t"}[sep]
    alphabet = b"0123456789+-_ \t\r,x\x0b"
    out = bytearray()
    for _ in range(fdp.ConsumeIntInRange(0, 12)):
        if fdp.ConsumeIntInRange(0, 9) == 0:  # noise, or a run past the longest line
            out += (fdp.ConsumeBytes(fdp.ConsumeIntInRange(0, 60)) if fdp.ConsumeBool()
                    else b"7" * (MAX_LINE + fdp.ConsumeIntInRange(-2, 2)))
            continue
        n = rows * cols + time_col + fdp.ConsumeIntInRange(-1, 1)
        fields = [bytes(alphabet[b % len(alphabet)] for b in fdp.ConsumeBytes(
            fdp.ConsumeIntInRange(0, 22))) for _ in range(max(n, 0))]
        out += joiner.join(fields) + b"\n"
    stream = bytes(out)
    cuts = sorted({0, len(stream), *(fdp.ConsumeIntInRange(0, len(stream)) for _ in range(6))})
    ref = LinesFramer(rows, cols, sep=sep, time_col=time_col, time_unit=unit)
    got = NativeLinesFramer(rows, cols, sep=sep, time_col=time_col, time_unit=unit)
    for k, (a, b) in enumerate(zip(cuts, cuts[1:])):
        want, have = ref.feed(stream[a:b], 0.25 * k), got.feed(stream[a:b], 0.25 * k)
        assert [(f.seq, f.device_time_us, f.raw.tobytes()) for f in have] \
            == [(f.seq, f.device_time_us, f.raw.tobytes()) for f in want]
        assert got.buffered == ref.buffered <= MAX_LINE
        _maybe_reset(fdp, ref, got)
    assert asdict(got.stats) == asdict(ref.stats)


@atheris.instrument_func
def flexitac_framers(data: bytes) -> None:
    """FlexiTac: FlexiTacFramer against NativeFlexiTacFramer (frames with markers, markers in
    their data, noise, torn frames)."""
    fdp = atheris.FuzzedDataProvider(data)
    rows, cols = fdp.ConsumeIntInRange(1, 4), fdp.ConsumeIntInRange(1, 6)
    out = bytearray()
    for _ in range(fdp.ConsumeIntInRange(0, 16)):
        kind = fdp.ConsumeIntInRange(0, 4)
        body = fdp.ConsumeBytes(rows * cols).ljust(rows * cols, b"\x00")
        if kind <= 2:
            out += b"\xaa\x55" + body
        elif kind == 3:
            out += (b"\xaa\x55" + body)[:fdp.ConsumeIntInRange(0, rows * cols + 1)]
        else:
            out += fdp.ConsumeBytes(fdp.ConsumeIntInRange(0, 30))
    stream = bytes(out)
    cuts = sorted({0, len(stream), *(fdp.ConsumeIntInRange(0, len(stream)) for _ in range(6))})
    ref, got = FlexiTacFramer(rows, cols), NativeFlexiTacFramer(rows, cols)
    for k, (a, b) in enumerate(zip(cuts, cuts[1:])):
        want, have = ref.feed(stream[a:b], 0.5 * k), got.feed(stream[a:b], 0.5 * k)
        assert [(f.seq, f.device_time_us, f.raw.tobytes()) for f in have] \
            == [(f.seq, f.device_time_us, f.raw.tobytes()) for f in want]
        assert got.buffered == ref.buffered
        _maybe_reset(fdp, ref, got)
    assert asdict(got.stats) == asdict(ref.stats)


@atheris.instrument_func
def robotiq_framer(data: bytes) -> None:
    """Robotiq: RobotiqFramer against NativeRobotiqFramer (whole readings of drawn fingers,
    torn packets, packets with drawn (often unknown) fields and lengths, and noise rich in the
    start byte, cut into drawn reads)."""
    fdp = atheris.FuzzedDataProvider(data)
    finger = fdp.ConsumeIntInRange(0, 3)
    kinds = [*FIELD_BYTES, 0x00, 0x80, 0xF0]
    out = bytearray()
    for _ in range(fdp.ConsumeIntInRange(0, 12)):
        kind = fdp.ConsumeIntInRange(0, 4)
        if kind <= 1:  # a reading (kind 1: torn at a drawn byte)
            raw = np.frombuffer(fdp.ConsumeBytes(56).ljust(56, b"\x00"), dtype=np.uint16)
            piece = encode_finger(fdp.ConsumeIntInRange(0, 3), raw.reshape(7, 4).copy(),
                                  timestamp_ms=fdp.ConsumeIntInRange(0, 2**20))
            out += piece if kind == 0 else piece[:fdp.ConsumeIntInRange(0, len(piece))]
        elif kind == 2:  # a packet of drawn fields, its length drawn near the truth
            body = bytearray()
            for _ in range(fdp.ConsumeIntInRange(0, 4)):
                field = fdp.PickValueInList(kinds) | (fdp.ConsumeIntInRange(0, 15))
                size = FIELD_BYTES.get(field & 0xF0, 2)
                if field & 0xF0 == 0x70 and fdp.ConsumeBool():
                    size = 8  # pyrobotiqtactile's uint64 timestamp
                body += bytes([field]) + fdp.ConsumeBytes(size)
            length = max(0, min(255, len(body) + fdp.ConsumeIntInRange(-2, 2)))
            out += bytes([START, fdp.ConsumeIntInRange(0, 255), 0x58, length]) + body
        elif kind == 3:  # noise with start bytes in it
            out += bytes(START if b < 40 else b for b in fdp.ConsumeBytes(
                fdp.ConsumeIntInRange(0, 200)))
        else:
            out += fdp.ConsumeBytes(fdp.ConsumeIntInRange(0, 40))
    stream = bytes(out)
    cuts = sorted({0, len(stream), *(fdp.ConsumeIntInRange(0, len(stream)) for _ in range(6))})
    framer, got, seqs = RobotiqFramer(finger), NativeRobotiqFramer(finger), []
    for k, (a, b) in enumerate(zip(cuts, cuts[1:])):
        want, have = framer.feed(stream[a:b], 0.5 * k), got.feed(stream[a:b], 0.5 * k)
        for f in want:
            assert f.raw.shape == (7, 4) and f.raw.dtype == np.uint16, f.raw
            assert f.sensor_id == finger and f.device_time_us >= 0
            seqs.append(f.seq)
        assert [_robotiq_key(f) for f in have] == [_robotiq_key(f) for f in want]
        assert got.buffered == framer.buffered <= 2 * (ROBOTIQ_HEADER + MAX_DATA)
        _maybe_reset(fdp, framer, got)
    st = framer.stats
    assert seqs == list(range(len(seqs))) and st.frames == len(seqs)
    assert st.bytes == len(stream) and st.discarded + framer.buffered <= st.bytes
    assert asdict(got.stats) == asdict(st) and got.packets == framer.packets


def _robotiq_key(f: Frame) -> tuple:
    return (f.seq, f.device_time_us, f.sensor_id, f.host_time, f.clocked,
            list(f.extras.items()), f.raw.dtype, f.raw.tobytes())


TARGETS = {"wire": wire_decoders, "lines": lines_framers, "flexitac": flexitac_framers,
           "robotiq": robotiq_framer}


def one_input(data: bytes) -> None:
    """Every target on the same input."""
    for target in TARGETS.values():
        target(data)


if __name__ == "__main__":
    atheris.Setup(sys.argv, one_input)
    atheris.Fuzz()

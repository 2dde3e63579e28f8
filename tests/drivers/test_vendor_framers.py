"""The vendor framers, fuzzed: byte streams built as each format's sources describe, cut into
any chunks, with garbage, torn frames and markers inside the data.  Nothing malformed is ever
delivered, no good frame after the damage is lost, memory stays bounded, and every drop is
counted."""

from __future__ import annotations

import json
from dataclasses import asdict

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactiled_drivers import flexitac, lines, robotiq, xela

SMALL = st.integers(1, 4)
#: the FlexiTac framer and its compiled core's (held equal below)
FLEXITAC = pytest.mark.parametrize("make", [flexitac.FlexiTacFramer,
                                            flexitac.NativeFlexiTacFramer],
                                   ids=lambda c: c.__name__)
#: the lines framer and its compiled core's (tests/drivers/test_lines_core.py holds them equal)
LINES = pytest.mark.parametrize("make", [lines.LinesFramer, lines.NativeLinesFramer],
                                ids=lambda c: c.__name__)
#: the Robotiq framer and its compiled core's (held equal below)
ROBOTIQ = pytest.mark.parametrize("make", [robotiq.RobotiqFramer, robotiq.NativeRobotiqFramer],
                                  ids=lambda c: c.__name__)


def feed_chunks(framer, data: bytes, cuts: list[int]) -> list:
    """Feed ``data`` cut at ``cuts`` (any chunking must give the same frames)."""
    out, start = [], 0
    for cut in sorted(set(c % (len(data) + 1) for c in cuts)) + [len(data)]:
        out += framer.feed(data[start:cut], host_time=1.0)
        start = cut
    return out


class F:
    """An array standing in for a frame (for :func:`is_subsequence`)."""

    def __init__(self, raw: np.ndarray) -> None:
        self.raw = raw


def same(frames, arrays) -> bool:
    return len(frames) == len(arrays) and all(
        f.raw.shape == a.shape and np.array_equal(f.raw, a) for f, a in zip(frames, arrays))


def is_subsequence(frames, arrays) -> bool:
    it = iter(arrays)
    return all(any(np.array_equal(f.raw, a) for a in it) for f in frames)


# --------------------------------------------------------------------------------------------
# FlexiTac


@st.composite
def flexitac_stream(draw, markers: bool = True):
    rows, cols = draw(SMALL), draw(st.integers(2, 6))
    n = draw(st.integers(2, 8))
    imgs = [np.array(draw(st.lists(st.integers(0, 255), min_size=rows * cols,
                                   max_size=rows * cols)), dtype=np.uint16).reshape(rows, cols)
            for _ in range(n)]
    if markers and draw(st.booleans()):  # a marker inside the data of some frames
        for img in imgs:
            if draw(st.booleans()):
                k = draw(st.integers(0, rows * cols - 2))
                img.flat[k:k + 2] = (0xAA, 0x55)
    return rows, cols, imgs


@FLEXITAC
@settings(max_examples=150, deadline=None)
@given(flexitac_stream(), st.lists(st.integers(0, 10_000), max_size=6))
def test_flexitac_clean_stream_any_chunking(make, stream, cuts) -> None:
    rows, cols, imgs = stream
    framer = make(rows, cols)
    got = feed_chunks(framer, b"".join(flexitac.encode(i) for i in imgs), cuts)
    # each frame is confirmed by the next one's marker: all but the last come out, once the
    # first two have set the phase (which takes a byte of the third)
    assert is_subsequence(got, imgs[:-1])
    if framer.stats.ambiguous == 0:
        assert same(got, imgs[:-1] if len(imgs) >= 3 else [])
    assert framer.stats.rejected == 0 and framer.buffered <= 2 * framer.period + 1 + 0


@FLEXITAC
@settings(max_examples=150, deadline=None)
@given(flexitac_stream(markers=False), st.binary(min_size=1, max_size=300), st.integers(0, 6),
       st.lists(st.integers(0, 10_000), max_size=4))
def test_flexitac_garbage_costs_only_its_neighbour(make, stream, junk, at, cuts) -> None:
    """Garbage between frames.  (With a marker inside the data *and* garbage, a marker that
    happens to lie exactly one period before the first frame after the garbage is a frame to
    any reader of this format: it has no checksum.  docs/howto/drivers.md says so.)"""
    rows, cols, imgs = stream
    junk = junk.replace(b"\xaa", b"\x00")  # garbage without a marker byte
    at = min(at, len(imgs) - 1)
    data = (b"".join(flexitac.encode(i) for i in imgs[:at]) + junk
            + b"".join(flexitac.encode(i) for i in imgs[at:]))
    framer = make(rows, cols)
    got = feed_chunks(framer, data, cuts)
    assert is_subsequence(got, imgs)
    if framer.stats.ambiguous == 0:
        # the frame before the garbage is unconfirmed (never delivered); every frame after it
        # with two successors comes out (the phase is confirmed within them)
        must = [i for k, i in enumerate(imgs[:-1]) if k != at - 1 and (k < at or k + 2 < len(imgs))]
        assert is_subsequence([F(m) for m in must], [g.raw for g in got])
    assert framer.stats.discarded >= len(junk)


@FLEXITAC
@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=3000), st.lists(st.integers(0, 3000), max_size=8))
def test_flexitac_never_raises_and_stays_bounded(make, data, cuts) -> None:
    framer = make(2, 3)
    for frame in feed_chunks(framer, data, cuts):
        assert frame.raw.shape == (2, 3) and frame.raw.dtype == np.uint16
    assert framer.buffered <= 2 * framer.period + 1


@FLEXITAC
def test_flexitac_still_image_with_a_marker_waits_then_locks(make) -> None:
    """A still image holding AA 55 at the same place confirms two phases: the framer counts
    the ambiguity and delivers nothing until the data (its noise) tells them apart."""
    rows, cols = 3, 4
    still = np.arange(12, dtype=np.uint16).reshape(rows, cols)
    still.flat[5:7] = (0xAA, 0x55)
    framer = make(rows, cols)
    got = framer.feed(b"\x01\x02" + flexitac.encode(still) * 6)
    assert got == [] or all(np.array_equal(f.raw, still) for f in got)
    assert framer.stats.ambiguous >= 1
    rng = np.random.default_rng(1)
    moving = [np.where(rng.random((rows, cols)) < 0.5, still, still // 2) for _ in range(6)]
    for m in moving:
        m.flat[5:7] = rng.integers(0, 100, 2)  # the pair changes: only the true phase repeats
    got = framer.feed(b"".join(flexitac.encode(m) for m in moving))
    assert all(any(np.array_equal(f.raw, m) for m in [still, *moving]) for f in got)
    assert sum(any(np.array_equal(f.raw, m) for m in moving) for f in got) >= 3


@FLEXITAC
def test_flexitac_torn_frame_counted(make) -> None:
    imgs = [np.full((2, 3), k, dtype=np.uint16) for k in range(1, 6)]
    torn = flexitac.encode(imgs[1])[:5]  # unplugged mid-frame, the device restarts
    data = flexitac.encode(imgs[0]) + torn + b"".join(flexitac.encode(i) for i in imgs[2:])
    framer = make(2, 3)
    got = framer.feed(data)
    # the frame before the torn one is confirmed by its marker; the torn one never comes out
    assert same(got, [imgs[0], imgs[2], imgs[3]]) and framer.stats.truncated == 1
    assert framer.stats.resyncs == 1 and [f.seq for f in got] == [0, 1, 2]


@settings(max_examples=200, deadline=None)
@given(flexitac_stream(), st.lists(st.tuples(st.integers(0, 8), st.binary(max_size=40)),
                                   max_size=3),
       st.lists(st.integers(0, 10_000), max_size=6), st.booleans())
def test_flexitac_core_frames_as_the_reference(stream, junk, cuts, reset) -> None:
    """The same frames (seq, device time, counts) and counters, on clean streams, markers in
    the data, garbage and torn frames, cut anywhere, and after a reset."""
    rows, cols, imgs = stream
    units = [flexitac.encode(i) for i in imgs]
    for at, j in junk:
        units.insert(min(at, len(units)), j)
    data = b"".join(units)
    ref, got = flexitac.FlexiTacFramer(rows, cols), flexitac.NativeFlexiTacFramer(rows, cols)

    def wire(framer):  # each read at its own host time (the device time is the host clock)
        points = [0, *sorted({c % (len(data) + 1) for c in cuts}), len(data)]
        return [(f.seq, f.device_time_us, f.host_time, f.raw.dtype, f.raw.tobytes())
                for k, (a, b) in enumerate(zip(points, points[1:]))
                for f in framer.feed(data[a:b], host_time=3.0 + 0.0013 * k)]

    for _ in range(2 if reset else 1):
        assert wire(got) == wire(ref)
        assert (got.buffered, asdict(got.stats)) == (ref.buffered, asdict(ref.stats))
        ref.reset()
        got.reset()


# --------------------------------------------------------------------------------------------
# Lines


@st.composite
def lines_stream(draw):
    rows, cols = draw(SMALL), draw(SMALL)
    sep = draw(st.sampled_from([",", "space", "tab"]))
    n = draw(st.integers(1, 8))
    arrays = [np.array(draw(st.lists(st.integers(-10**6, 10**6), min_size=rows * cols,
                                     max_size=rows * cols)), dtype=np.int64).reshape(rows, cols)
              for _ in range(n)]
    return rows, cols, sep, arrays


@LINES
@settings(max_examples=150, deadline=None)
@given(lines_stream(), st.lists(st.tuples(st.sampled_from(["text", "short", "long"]),
                                          st.binary(max_size=60)), max_size=4),
       st.lists(st.integers(0, 5000), max_size=6), st.data())
def test_lines_good_lines_survive_bad_ones(make, stream, bad, cuts, data) -> None:
    rows, cols, sep, arrays = stream
    n = rows * cols
    units = [(lines.encode(a, sep), a) for a in arrays]
    for kind, junk in bad:
        line = {"text": b"x" + junk.replace(b"\n", b""),
                "short": b",".join([b"1"] * (n - 1)) if n > 1 else b"x",
                "long": b",".join([b"1"] * (n + 1))}[kind]
        if sep != ",":
            line = line.replace(b",", b" " if sep == "space" else b"\t")
        units.insert(data.draw(st.integers(0, len(units))), (line + b"\n", None))
    framer = make(rows, cols, sep=sep)
    got = feed_chunks(framer, b"".join(u for u, _ in units), cuts)
    assert same(got, arrays)
    assert framer.stats.rejected == len(bad) and framer.stats.frames == len(arrays)
    assert all(f.raw.dtype == np.int64 for f in got)


@LINES
def test_lines_counts_each_kind_and_time_column(make) -> None:
    framer = make(2, 2, sep=",", time_col=True, time_unit="ms")
    got = framer.feed(b"10,1,2,3,4\r\n11,1,2\n12,1,2,3,4,5\n13,1,x,3,4\n-1,1,2,3,4\n\n14,5,6,7,8,\n"
                      b"9223372036854775807,1,2,3,4\n")
    assert [f.device_time_us for f in got] == [10_000, 14_000]
    assert [f.seq for f in got] == [0, 1] and got[1].raw.tolist() == [[5, 6], [7, 8]]
    s = framer.stats
    # (a clock past int64 once in microseconds is a parse error too)
    assert (s.truncated, s.length_errors, s.parse_errors, s.resyncs) == (1, 1, 3, 1)


@LINES
def test_lines_ten_megabyte_line_costs_no_memory(make) -> None:
    framer = make(2, 2)
    chunk = b"7" * 65536
    peak = 0
    framer.feed(b"1,2,3,4\n")
    for _ in range(160):  # 10 MiB without a newline
        assert framer.feed(chunk) == []
        peak = max(peak, framer.buffered)
    got = framer.feed(b"\n5,6,7,8\n")
    assert peak <= lines.MAX_LINE and framer.stats.oversize == 1
    assert [f.raw.tolist() for f in got] == [[[5, 6], [7, 8]]]


# --------------------------------------------------------------------------------------------
# Robotiq


@st.composite
def robotiq_stream(draw):
    n = draw(st.integers(1, 6))
    readings = []
    for k in range(n):
        finger = draw(st.integers(0, 1))
        raw = np.array(draw(st.lists(st.integers(0, 65535), min_size=28, max_size=28)),
                       dtype=np.uint16).reshape(7, 4)
        readings.append((finger, raw, k * 7))
    return readings


@ROBOTIQ
@settings(max_examples=150, deadline=None)
@given(robotiq_stream(), st.lists(st.binary(max_size=90), max_size=3),
       st.lists(st.integers(0, 5000), max_size=6), st.integers(0, 1), st.data())
def test_robotiq_garbage_between_packets(make, readings, junks, cuts, finger, data) -> None:
    units = [robotiq.encode_finger(f, raw, timestamp_ms=t) for f, raw, t in readings]
    for junk in junks:  # garbage without a start byte
        units.insert(data.draw(st.integers(0, len(units))), junk.replace(b"\x9a", b"\x9b"))
    framer = make(finger)
    # the next packet's start byte at the end: a last packet that spans reads waits for it
    got = feed_chunks(framer, b"".join(units) + b"\x9a", cuts)
    mine = [(raw, t) for f, raw, t in readings if f == finger]
    assert same(got, [raw for raw, _ in mine])
    assert [g.device_time_us for g in got] == [t * 1000 for _, t in mine]
    assert all(g.sensor_id == finger and g.extras["timestamp"] == t for g, (_, t) in zip(got, mine))


@ROBOTIQ
@settings(max_examples=200, deadline=None)
@given(robotiq_stream(), st.binary(min_size=1, max_size=200),
       st.lists(st.integers(0, 5000), max_size=6))
def test_robotiq_start_bytes_in_garbage_deliver_nothing_false(make, readings, junk, cuts) -> None:
    data = junk + b"".join(robotiq.encode_finger(f, raw) for f, raw, _ in readings)
    framer = make(0)
    got = feed_chunks(framer, data, cuts)
    sent = [raw for f, raw, _ in readings if f == 0]
    # whatever the garbage held, a delivered frame is a sent one... unless the garbage itself
    # is a well-formed packet: then it is one (the format has no working checksum)
    assert all(g.raw.shape == (7, 4) for g in got)
    tail = got[len(got) - min(len(got), len(sent)):]
    assert is_subsequence(tail, sent) or len(got) > len(sent)
    assert framer.buffered <= robotiq.HEADER + robotiq.MAX_DATA


@ROBOTIQ
def test_robotiq_pyrobotiqtactile_uint64_timestamp_parses(make) -> None:
    raw = np.arange(28, dtype=np.uint16).reshape(7, 4)
    stamp = bytes([robotiq.TIMESTAMP]) + (123456789).to_bytes(8, "big") + bytes([robotiq.DYNAMIC, 0, 5])
    static = bytes([robotiq.STATIC]) + raw.astype(">u2").tobytes()
    packet = b"".join(bytes([robotiq.START, 0, 0x58, len(d)]) + d for d in (stamp, static))
    framer = make(0)
    (frame,) = framer.feed(packet)
    assert np.array_equal(frame.raw, raw) and frame.extras["timestamp"] == 123456789
    assert frame.extras["dynamic"] == 5


@ROBOTIQ
def test_robotiq_timestamp_unwraps(make) -> None:
    framer = make(0)
    raw = np.zeros((7, 4), dtype=np.uint16)
    stamps = [65000, 65500, 200, 900]
    got = framer.feed(b"".join(robotiq.encode_finger(0, raw, timestamp_ms=t) for t in stamps))
    assert [f.device_time_us // 1000 for f in got] == [65000, 65500, 65736, 66436]


#: field types of drawn packets: every kind, unknown ones, any finger and index bits
ROBOTIQ_KINDS = st.sampled_from([*robotiq.FIELD_BYTES, 0x00, 0x80, 0xF0])


@st.composite
def robotiq_field(draw) -> bytes:
    kind = draw(ROBOTIQ_KINDS) | draw(st.integers(0, 15))
    size = robotiq.FIELD_BYTES.get(kind & 0xF0, 2)
    if kind & 0xF0 == robotiq.TIMESTAMP and draw(st.booleans()):
        size = 8  # pyrobotiqtactile's uint64, any value (its microseconds may pass 2^64)
    return bytes([kind]) + draw(st.binary(min_size=size, max_size=size))


@st.composite
def robotiq_hostile_unit(draw) -> bytes:
    """A whole reading, a torn one, a packet of drawn fields with its length drawn near the
    truth, or noise rich in the start byte."""
    kind = draw(st.integers(0, 3))
    if kind <= 1:
        raw = np.array(draw(st.lists(st.integers(0, 65535), min_size=28, max_size=28)),
                       dtype=np.uint16).reshape(7, 4)
        unit = robotiq.encode_finger(draw(st.integers(0, 3)), raw,
                                     timestamp_ms=draw(st.integers(0, 2**17)),
                                     dynamic=draw(st.integers(-32768, 32767)),
                                     accelerometer=(draw(st.integers(-32768, 32767)), 0, -1))
        return unit if kind == 0 else unit[:draw(st.integers(0, len(unit)))]
    if kind == 2:
        body = b"".join(draw(st.lists(robotiq_field(), max_size=4)))
        length = max(0, min(255, len(body) + draw(st.integers(-2, 2))))
        return bytes([robotiq.START, draw(st.integers(0, 255)), 0x58, length]) + body
    noise = draw(st.binary(max_size=120))
    return bytes(robotiq.START if b < 40 else b for b in noise)


def robotiq_wire(framer, data: bytes, cuts: list[int]) -> list[tuple]:
    """Every field of every frame, read by read, each read at its own host time (a frame with
    no timestamp yet is clocked by the host), the extras' order too."""
    points = [0, *sorted({c % (len(data) + 1) for c in cuts}), len(data)]
    return [(f.seq, f.device_time_us, f.sensor_id, f.host_time, f.clocked,
             list(f.extras.items()), f.raw.dtype, f.raw.shape, f.raw.tobytes())
            for k, (a, b) in enumerate(zip(points, points[1:]))
            for f in framer.feed(data[a:b], host_time=5.0 + 0.0011 * k)]


@settings(max_examples=300, deadline=None)
@given(st.lists(robotiq_hostile_unit(), max_size=14), st.lists(st.integers(0, 4000), max_size=8),
       st.integers(0, 3), st.booleans())
def test_robotiq_core_frames_as_the_reference(units, cuts, finger, reset) -> None:
    """The same frames (seq, clocks, extras, counts) and counters, packets, held bytes, on
    hostile streams cut anywhere, and after a reset."""
    data = b"".join(units)
    ref, got = robotiq.RobotiqFramer(finger), robotiq.NativeRobotiqFramer(finger)
    for _ in range(2 if reset else 1):
        assert robotiq_wire(got, data, cuts) == robotiq_wire(ref, data, cuts)
        assert (got.buffered, got.packets, asdict(got.stats)) \
            == (ref.buffered, ref.packets, asdict(ref.stats))
        ref.reset()
        got.reset()


def test_robotiq_core_takes_a_timestamp_past_64_bits_as_the_reference() -> None:
    """A uint64 timestamp near 2^64 ms: its microseconds pass 2^64; a uint16 one after it
    unwraps past 2^64 ms; the two framers give the same Python ints."""
    static = bytes([robotiq.STATIC]) + np.arange(28, dtype=">u2").tobytes()
    stamps = [bytes([robotiq.TIMESTAMP]) + (2**64 - 5).to_bytes(8, "big"),
              bytes([robotiq.TIMESTAMP]) + (3).to_bytes(2, "big")]
    data = b"".join(bytes([robotiq.START, 0, 0x58, len(d)]) + d
                    for stamp in stamps for d in (stamp + bytes([robotiq.DYNAMIC, 0xFF, 0xFE]),
                                                  static))
    want = robotiq_wire(robotiq.RobotiqFramer(0), data, [])
    assert [w[1] for w in want] == [(2**64 - 5) * 1000, (2**64 - 2**16 + 3 + 2**16) * 1000]
    assert want[0][5] == [("dynamic", -2), ("timestamp", 2**64 - 5)]
    assert robotiq_wire(robotiq.NativeRobotiqFramer(0), data, []) == want


def test_robotiq_core_refuses_a_finger_past_3() -> None:
    with pytest.raises(ValueError, match="finger"):
        robotiq.NativeRobotiqFramer(4)


def test_robotiq_commands() -> None:
    assert robotiq.autosend(10) == bytes([0x9A, 0x00, 0x58, 0x01, 10])
    assert robotiq.autosend(0)[-1] == 0
    with pytest.raises(ValueError):
        robotiq.autosend(256)


# --------------------------------------------------------------------------------------------
# XELA


def xyz_strategy(rows: int, cols: int):
    return st.lists(st.integers(0, 65535), min_size=rows * cols * 3,
                    max_size=rows * cols * 3).map(
        lambda v: np.array(v, dtype=np.uint16).reshape(rows, cols, 3))


@settings(max_examples=100, deadline=None)
@given(st.lists(xyz_strategy(4, 6), min_size=1, max_size=5),
       st.lists(st.one_of(st.binary(max_size=60), st.just(b'{"message": 3, "1": {}}'),
                          st.just(b"[1, 2]"), st.just(b'{"message": 4, "1": {"taxels": 24, '
                                                      b'"data": "zz", "model": "XR1946"}}')),
                max_size=4))
def test_xela_messages(grids, bad) -> None:
    framer = xela.XelaFramer(sensor=1)
    got = []
    for k, grid in enumerate(grids):
        for b in bad[k:k + 1]:
            got += framer.feed(b)
        got += framer.feed(xela.message(k + 10, {1: ("XR1946", grid), 2: ("XR1944", grid[:, :4])},
                                        100.0 + k).encode())
    assert same(got, [g[..., 2] for g in grids])
    assert all(np.array_equal(f.taxels, g) and f.axes == 3 for f, g in zip(got, grids))
    assert [f.seq for f in got] == [k + 10 for k in range(len(grids))]
    assert [f.device_time_us for f in got] == [round((100.0 + k) * 1e6) for k in range(len(grids))]


def test_xela_counts_and_layouts() -> None:
    framer = xela.XelaFramer(sensor=2)
    grid = np.arange(48, dtype=np.uint16).reshape(4, 4, 3)
    assert framer.feed(xela.WELCOME.encode()) == []
    assert len(framer.feed(xela.message(1, {2: ("XR1944", grid)}, 1.0).encode())) == 1
    assert framer.feed(xela.message(1, {2: ("XR1944", grid)}, 1.0).encode()) == []  # repeat
    assert len(framer.feed(xela.message(5, {2: ("XR1944", grid)}, 2.0).encode())) == 1
    wrong = json.loads(xela.message(6, {2: ("XR1944", grid)}, 3.0))
    wrong["2"]["taxels"] = 15
    assert framer.feed(json.dumps(wrong).encode()) == []
    assert framer.feed(b"{" * 10) == [] and framer.feed(b"x" * (xela.MAX_MESSAGE + 1)) == []
    s = framer.stats
    assert (s.duplicated, s.lost, s.length_errors, s.parse_errors, s.oversize) == (1, 3, 1, 1, 1)

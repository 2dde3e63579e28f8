"""The PaXini PX-6AX driver: its framer against an independent parser of the answers on hostile
streams (torn answers, garbage, corrupt checksums), and the source against the simulated module
(`tactiled simulate --as paxini`, a real pty answering real requests)."""

from __future__ import annotations

import re
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from procs import SimulatedDevice, read_source
from tactiled_drivers import paxini

ROWS, COLS = 2, 3
N = ROWS * COLS
SIZE = 14 + 3 * N + 1


def oracle(stream: bytes, module: int, points: int) -> list[np.ndarray]:
    """The answers in ``stream``, parsed with a regular expression and struct: a unit counts
    only where its whole prefix matches, no other answer's prefix begins inside it, and its
    sum of bytes is 0 mod 256; points as (x int8, y int8, z uint8)."""
    n = 3 * points
    prefix = (b"\xaa\x55" + struct.pack("<HBBB", 10 + n, module + 1, 0, 0xFB)
              + struct.pack("<IHB", 0x040E, n, 0))
    starts = [m.start() for m in re.finditer(re.escape(prefix), stream)]
    out = []
    for k, s in enumerate(starts):
        end = s + len(prefix) + n + 1
        if end > len(stream) or (k + 1 < len(starts) and starts[k + 1] < end):
            continue
        unit = stream[s:end]
        if sum(unit) % 256:
            continue
        out.append(np.array(struct.unpack("<" + "bbB" * points, unit[len(prefix):-1])).reshape(points, 3))
    return out


points = st.lists(st.tuples(st.integers(-128, 127), st.integers(-128, 127), st.integers(0, 255)),
                  min_size=N, max_size=N).map(lambda p: np.array(p, dtype=np.int64))
noise = st.binary(max_size=20).map(lambda b: b.replace(b"\xaa", b"\x00"))


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(points, st.integers(0, 3), st.integers(1, SIZE - 1), noise, points),
                min_size=1, max_size=6))
def test_torn_answers_cost_themselves_only(units) -> None:
    """Each good answer is preceded by garbage and, often, an answer torn off at any byte:
    every good answer is delivered exactly, no malformed frame, one rejection per torn one."""
    stream = b""
    good, torn = [], 0
    for pts, how, cut, junk, torn_pts in units:
        stream += junk
        if how:  # a torn answer (how 3: a corrupt checksum instead, whole)
            whole = paxini.response(0, torn_pts)
            if how == 3:
                stream += whole[:-1] + bytes(((whole[-1] + 1) & 0xFF,))
            else:
                stream += whole[:cut]
            torn += how == 3 or cut >= 2  # one byte is no header yet: garbage, not a unit
        stream += paxini.response(0, pts)
        good.append(pts)
    framer = paxini.PaxiniFramer(0, ROWS, COLS)
    got = []
    for i in range(0, len(stream), 7):  # fed in arbitrary pieces
        got += framer.feed(stream[i:i + 7], host_time=1.0)
    want = oracle(stream, 0, N)
    assert len(want) == len(good) and all(np.array_equal(a, b) for a, b in zip(want, good))
    assert len(got) == len(good)
    for frame, pts in zip(got, good):
        assert frame.axes == 3 and frame.taxels.shape == (ROWS, COLS, 3)
        back = frame.taxels.reshape(-1, 3).astype(np.int64) - paxini.ZERO_COUNTS
        assert np.array_equal(back, pts)
        assert np.array_equal(frame.raw, frame.taxels[..., 2])
    assert framer.stats.rejected == torn
    assert framer.stats.frames == len(good)


def test_request_bytes() -> None:
    """The request as PaXini's reference tool writes it (module 0 -> address 01, 93 bytes)."""
    want = bytes.fromhex("55AA0900010 0FB0E0400005D00".replace(" ", ""))
    req = paxini.request(0, 31)
    assert req[:-1] == want and sum(req) % 256 == 0


def test_other_module_and_wrong_length_rejected() -> None:
    framer = paxini.PaxiniFramer(0, ROWS, COLS)
    pts = np.zeros((N, 3), dtype=np.int64)
    assert framer.feed(paxini.response(1, pts)) == []  # module 2's answer
    assert framer.feed(paxini.response(0, np.zeros((N + 1, 3)))) == []
    assert framer.feed(paxini.response(0, pts, status=3)) == []
    assert len(framer.feed(paxini.response(0, pts))) == 1
    assert framer.stats.rejected >= 3 and framer.stats.frames == 1


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux ptys")
def test_source_reads_the_simulated_module(tmp_path: Path) -> None:
    """The source asks, the simulated module (a real pty) answers; frames arrive, none bad."""
    link = tmp_path / "px"
    with SimulatedDevice("--as", "paxini", "--device", str(link), "--rate", "500",
                         "--seed", "2") as device:
        assert device.line().startswith("pty: ")
        assert device.line() == f"link: {link}"

        got, stats = read_source(f"paxini://{link}", lambda got: len(got) >= 50, 20.0)
    assert len(got) >= 50
    assert all(f.taxels.shape == (10, 12, 3) and f.raw.shape == (10, 12) for f in got)
    assert stats.rejected == 0
    assert [f.seq for f in got] == list(range(len(got)))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux ptys")
def test_the_simulated_module_pushes_sideways(tmp_path: Path) -> None:
    """`--scene push`: the answers carry the 3-axis model's x and y, far above the rest's
    noise (1 count), and z of the press; none is rejected."""
    link = tmp_path / "px"

    def pushed(got: list) -> bool:
        return max((np.abs(f.taxels[..., :2].astype(int) - paxini.ZERO_COUNTS).max()
                    for f in got), default=0) >= 8

    with SimulatedDevice("--as", "paxini", "--device", str(link), "--rate", "1000",
                         "--seed", "2", "--scene", "push") as device:
        assert device.line().startswith("pty: ")
        assert device.line() == f"link: {link}"

        got, stats = read_source(f"paxini://{link}", pushed, 30.0)
    xyz = np.stack([f.taxels for f in got]).astype(int) - paxini.ZERO_COUNTS
    assert np.abs(xyz[..., :2]).max() >= 8, np.abs(xyz[..., :2]).max()
    assert xyz[..., 2].max() > 20 and xyz[..., 2].min() >= 0
    assert stats.rejected == 0


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(points, noise), min_size=1, max_size=5), st.integers(1, 40))
def test_answers_without_a_checksum_byte(answers, chunk) -> None:
    """A module whose answers end with their payload (`checksum=0`, as the public drivers read
    them): each answer is one frame, whatever the reads; garbage between costs nothing."""
    stream = b"".join(junk + paxini.response(0, pts, checksum=False) for pts, junk in answers)
    framer = paxini.PaxiniFramer(0, ROWS, COLS, checksum=False)
    got = [f for k in range(0, len(stream), chunk) for f in framer.feed(stream[k:k + chunk])]
    assert len(got) == len(answers)
    for f, (pts, _junk) in zip(got, answers):
        np.testing.assert_array_equal(f.taxels.reshape(-1, 3).astype(int) - paxini.ZERO_COUNTS, pts)
    assert framer.stats.rejected == 0


def test_the_checksum_parameter() -> None:
    from tactiled.sources import open_source

    assert open_source("paxini:///dev/null").decoder.checksum is True
    assert open_source("paxini:///dev/null?checksum=0").decoder.checksum is False
    with pytest.raises(ValueError, match="checksum"):
        open_source("paxini:///dev/null?checksum=2")
    # with the checksum expected, a good answer's payload with a byte changed is refused
    pts = np.zeros((N, 3), np.int64)
    bad = bytearray(paxini.response(0, pts))
    bad[20] ^= 1
    framer = paxini.PaxiniFramer(0, ROWS, COLS)
    assert framer.feed(bytes(bad)) == [] and framer.stats.crc_errors == 1

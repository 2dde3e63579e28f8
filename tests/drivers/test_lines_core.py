"""The compiled core's lines framer (core/lines.cpp, ``NativeLinesFramer``) against its Python
reference (``LinesFramer``): the same frames (seq, device time, counts, dtype) and the same
counters for the same bytes however they are cut, on hypothesis-drawn streams of good lines,
lines Python's ``int`` reads in odd ways (signs, blanks, underscores, numbers past int64) and
noise; and the vendor framer tests' checks against the core."""

from __future__ import annotations

from dataclasses import asdict

from hypothesis import given, settings
from hypothesis import strategies as st

from tactiled_drivers import lines
from tactiled_drivers.lines import LinesFramer, NativeLinesFramer

ODD_FIELDS = st.sampled_from([
    b"+5", b"-0", b" 7", b"7 ", b"1_000", b"1__0", b"_1", b"1_", b"", b"x", b"0x10", b"\xff",
    b"9223372036854775807", b"9223372036854775808", b"-9223372036854775808",
    b"-9223372036854775809", b"99999999999999999999999", b"007", b"\x0b3\x0c", b"1.5", b"--1"])


@st.composite
def stream(draw: st.DrawFn) -> tuple[int, int, str, bool, str, bytes]:
    rows, cols = draw(st.integers(1, 3)), draw(st.integers(1, 3))
    sep = draw(st.sampled_from([",", "space", "tab"]))
    time_col = draw(st.booleans())
    unit = draw(st.sampled_from(["ms", "us", "s"]))
    joiner = {",": b",", "space": b" ", "tab": b"\t"}[sep]
    out = []
    for _ in range(draw(st.integers(0, 10))):
        kind = draw(st.integers(0, 3))
        n = rows * cols + time_col + (draw(st.integers(-1, 1)) if kind == 3 else 0)
        if kind <= 1:
            fields = [str(v).encode() for v in draw(st.lists(
                st.integers(-10**4, 10**19 if kind == 1 else 10**6), min_size=n, max_size=n))]
        elif kind == 2:
            fields = draw(st.lists(st.one_of(ODD_FIELDS, st.integers(0, 99).map(
                lambda v: str(v).encode())), min_size=n, max_size=n))
        else:
            fields = draw(st.lists(st.binary(max_size=4), min_size=max(n, 0), max_size=max(n, 0)))
        line = joiner.join(fields) + draw(st.sampled_from([b"", joiner, b"\r"]))
        out.append(line + b"\n")
    return rows, cols, sep, time_col, unit, b"".join(out) + draw(st.binary(max_size=10))


def _feed(framer: LinesFramer | NativeLinesFramer, data: bytes, cuts: list[int],
          times: list[float]) -> list[tuple]:
    got = []
    points = [0, *sorted({c % (len(data) + 1) for c in cuts}), len(data)]
    for k, (a, b) in enumerate(zip(points, points[1:])):
        for f in framer.feed(data[a:b], host_time=times[k % len(times)]):
            got.append((f.seq, f.device_time_us, f.sensor_id, f.host_time, f.raw.dtype,
                        f.raw.shape, f.raw.tobytes()))
    return got


@settings(max_examples=300, deadline=None)
@given(stream(), st.lists(st.integers(0, 5000), max_size=8),
       st.lists(st.floats(0.0, 1e4), min_size=1, max_size=4), st.booleans())
def test_the_core_frames_lines_as_the_reference(s: tuple, cuts: list[int], times: list[float],
                                                reset: bool) -> None:
    rows, cols, sep, time_col, unit, data = s
    ref = LinesFramer(rows, cols, sep=sep, time_col=time_col, time_unit=unit)
    got = NativeLinesFramer(rows, cols, sep=sep, time_col=time_col, time_unit=unit)
    assert _feed(got, data, cuts, times) == _feed(ref, data, cuts, times)
    assert (got.buffered, asdict(got.stats)) == (ref.buffered, asdict(ref.stats))
    if reset:  # a reopened port: the torn line counted, then the stream goes on
        ref.reset()
        got.reset()
        assert _feed(got, data, cuts, times) == _feed(ref, data, cuts, times)
        assert asdict(got.stats) == asdict(ref.stats)


def test_a_lines_source_frames_through_the_core_unless_told_otherwise() -> None:
    from tactiled import native

    source = lines.LinesSource("lines:///dev/null?rows=2&cols=3")
    assert isinstance(source.decoder, NativeLinesFramer if native.core is not None
                      else LinesFramer)
    assert source.decoder.shape == (2, 3)

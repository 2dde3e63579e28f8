"""The replay driver: record frames, play them back identically, fast or at the recorded pace;
and a conformance test run against each frame source that can be fed known frames."""

from __future__ import annotations

import asyncio
import time
from urllib.parse import quote

import pytest

from tactiled.errors import DeviceTimeoutError, DriverError, FrameError
from tactiled.frames import encode_frame
from tactiled.io.recording import Recorder, RecordingWriter
from tactiled.sources import open_source
from tactiled_drivers.replay import ReplaySource


def record(path, frames, period: float, t0: float = 1000.0):
    """Write ``frames`` as if received ``period`` seconds apart; returns the path."""
    with Recorder(path) as recorder:
        for k, frame in enumerate(frames):
            recorder.record(frame, host_time=t0 + k * period)
    return path


def replay_url(path, **params: object) -> str:
    query = "&".join(f"{k}={v}" for k, v in params.items())
    return f"replay://{quote(str(path))}" + (f"?{query}" if query else "")


async def replay_all(url: str, **kwargs):
    async with open_source(url, **kwargs) as src:
        start = time.monotonic()
        frames = [f async for f in src.frames(timeout=5.0)]
        return src, frames, time.monotonic() - start


def test_url_parameters(tmp_path) -> None:
    src = open_source(replay_url(tmp_path / "x.tact", speed=2.5, loop=1, clock="recorded"))
    assert isinstance(src, ReplaySource)
    assert (src.path, src.speed, src.loop, src.clock) == (str(tmp_path / "x.tact"), 2.5, True,
                                                          "recorded")
    default = open_source("replay://rel/x.tact")
    assert (default.path, default.speed, default.loop, default.clock) == ("rel/x.tact", 1.0,
                                                                          False, "live")
    for bad, message in [("speed=-1", r"speed='-1' is not >= 0"),
                         ("speed=fast", "speed='fast' is not a number"),
                         ("speed=nan", "finite"),
                         ("loop=2", "loop='2' is not a boolean"),
                         ("clock=wall", "clock='wall' is not one of live, recorded"),
                         ("sped=1", r"unknown parameter\(s\) sped")]:
        with pytest.raises(ValueError, match=message):
            open_source(f"replay://x.tact?{bad}")
    with pytest.raises(ValueError, match="no recording file"):
        open_source("replay://?speed=0")


def test_fast_replay_gives_identical_frames(tmp_path, frame_factory, same_frame) -> None:
    sent = frame_factory(200, seed=11, start_seq=1000, sensor_id=4)
    # an hour between frames: pacing even one gap would take an hour (and hit the timeout)
    path = record(tmp_path / "a.tact", sent, period=3600.0)

    src, got, elapsed = asyncio.run(replay_all(replay_url(path, speed=0)))
    assert elapsed < 3600.0  # no recorded gap was waited for
    assert all(same_frame(a, b) for a, b in zip(got, sent, strict=True))
    assert src.bytes_read == sum(len(encode_frame(f)) for f in sent)
    assert src.decoder.stats.rejected == 0 and src.decoder.stats.lost == 0
    assert src.sensor_id == 0 and src.passes == 1 and src.last_error == ""


def test_fast_replay_lets_other_tasks_run(tmp_path, frame_factory) -> None:
    path = record(tmp_path / "a.tact", frame_factory(300), period=0.01)

    async def main() -> int:
        ticks = 0

        async def ticker() -> None:
            nonlocal ticks
            while True:
                await asyncio.sleep(0)
                ticks += 1

        task = asyncio.create_task(ticker())
        await replay_all(replay_url(path, speed=0))
        task.cancel()
        return ticks

    assert asyncio.run(main()) >= 250


@pytest.mark.parametrize("speed", [1.0, 3.0])
def test_paced_replay_takes_the_recorded_time(tmp_path, frame_factory, speed) -> None:
    sent = frame_factory(16)
    # 0.45 s between first and last; recorded times negative so they cannot pass for live ones
    path = record(tmp_path / "a.tact", sent, period=0.03, t0=-1e6)
    expected = 15 * 0.03 / speed

    _, got, elapsed = asyncio.run(replay_all(replay_url(path, speed=speed)))
    assert len(got) == 16
    assert 0.8 * expected <= elapsed <= 3 * expected
    # Frames are stamped at replay (live clock), spread like the recording.  Single gaps may
    # be short: a late frame is followed by an early one, because the schedule is absolute
    # (it never drifts), so only the span is checked.
    span = got[-1].host_time - got[0].host_time
    assert 0.8 * expected <= span <= 3 * expected
    assert got[0].host_time > 0


def test_recorded_clock_stamps_recorded_host_times(tmp_path, frame_factory) -> None:
    path = record(tmp_path / "a.tact", frame_factory(5), period=0.5, t0=42.0)
    _, got, _ = asyncio.run(replay_all(replay_url(path, speed=0, clock="recorded")))
    assert [f.host_time for f in got] == [42.0, 42.5, 43.0, 43.5, 44.0]


def test_loop_replays_again(tmp_path, frame_factory, same_frame) -> None:
    sent = frame_factory(3)
    path = record(tmp_path / "a.tact", sent, period=0.01)

    async def main():
        async with open_source(replay_url(path, speed=0, loop=1)) as src:
            got = []
            async for frame in src.frames(timeout=1.0):
                got.append(frame)
                if len(got) == 8:
                    break
            return src, got

    src, got = asyncio.run(main())
    assert [f.seq for f in got] == [0, 1, 2, 0, 1, 2, 0, 1]
    assert all(same_frame(a, sent[k % 3]) for k, a in enumerate(got))
    assert src.passes == 2
    # Repeating seq numbers at a new pass are neither duplicates nor losses.
    assert src.decoder.stats.duplicated == 0 and src.decoder.stats.lost == 0


def test_loop_of_a_single_frame_keeps_coming(tmp_path, frame_factory, same_frame) -> None:
    sent = frame_factory(1)[0]
    path = record(tmp_path / "one.tact", [sent], period=0.01)

    async def three(src):
        got = []
        async for frame in src.frames():
            got.append(frame)
            if len(got) == 3:
                return got

    async def main():
        async with open_source(replay_url(path, speed=0, loop=1)) as src:
            # Were the repeats dropped as duplicates, bytes would flow but no frame come.
            return await asyncio.wait_for(three(src), 10.0)

    assert all(same_frame(f, sent) for f in asyncio.run(main()))


def test_empty_recording_with_loop_ends(tmp_path) -> None:
    RecordingWriter(tmp_path / "e.tact").close()
    _, got, _ = asyncio.run(replay_all(replay_url(tmp_path / "e.tact", loop=1)))
    assert got == []


def test_truncated_recording_replays_what_is_complete(tmp_path, frame_factory,
                                                      same_frame) -> None:
    sent = frame_factory(5)
    path = record(tmp_path / "a.tact", sent, period=0.01)
    with open(path, "r+b") as f:
        f.truncate(path.stat().st_size - 20)

    src, got, _ = asyncio.run(replay_all(replay_url(path, speed=0)))
    assert all(same_frame(a, b) for a, b in zip(got, sent[:4], strict=True))
    assert "truncated" in src.last_error and str(path) in src.last_error


def test_open_errors(tmp_path) -> None:
    async def main() -> None:
        with pytest.raises(DriverError, match="cannot open recording"):
            await open_source(replay_url(tmp_path / "missing.tact")).open()
        (tmp_path / "junk.tact").write_bytes(b"x" * 64)
        with pytest.raises(FrameError, match="not a tactiled recording"):
            await open_source(replay_url(tmp_path / "junk.tact")).open()

    asyncio.run(main())


def test_close_ends_a_paced_read_promptly(tmp_path, frame_factory, wait_until) -> None:
    path = record(tmp_path / "a.tact", frame_factory(3), period=10.0)

    async def main() -> float:
        src = open_source(replay_url(path))
        await src.open()
        got = []

        async def consume() -> None:
            async for frame in src.frames():
                got.append(frame)

        task = asyncio.create_task(consume())
        await wait_until(lambda: len(got) == 1, 5.0)  # the next frame is due in 10 s
        start = time.monotonic()
        await src.close()
        await asyncio.wait_for(task, 12.0)
        assert len(got) == 1  # closing ends the stream, it does not release the frame
        return time.monotonic() - start

    # promptly: not at the next frame, 10 s away (the margin is a loaded machine's)
    assert asyncio.run(main()) < 3.0


def test_read_timeout_consumes_nothing(tmp_path, frame_factory) -> None:
    path = record(tmp_path / "a.tact", frame_factory(3), period=10.0)

    async def main() -> None:
        async with open_source(replay_url(path)) as src:
            first = await src.read()
            with pytest.raises(DeviceTimeoutError):
                await src.read(timeout=0.05)
            # The frame whose wait was cancelled is still next: served at once when the
            # pace no longer holds it back.
            src.speed = 0
            second, third = await src.read(timeout=1.0), await src.read(timeout=1.0)
            assert await src.read(timeout=1.0) == b""
        assert [first, second, third] == [encode_frame(f) for f in frame_factory(3)]

    asyncio.run(main())

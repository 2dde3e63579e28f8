"""The serial driver against a real pseudo-terminal: pyserial reads the pty slave through a
stable symlink, the test plays the device on the master side."""

from __future__ import annotations

import asyncio
import logging
import os
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import quote

import numpy as np
import pytest
import serial

from tactiled.errors import DeviceConnectionError, DeviceTimeoutError
from tactiled.frames import Frame, encode_frame
from tactiled.sources import FrameSource, open_source
from tactiled_drivers.serial import SerialSource

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux ptys and /proc/self/fd")

#: How long a wait for the driver (bytes read, frames decoded, a port lost or back) may take on
#: a loaded machine: not a bar; the tests that time the driver assert their own bounds.
WAIT_S = 10.0


def serial_url(path: str, **params: object) -> str:
    query = "&".join(f"{k}={v}" for k, v in params.items())
    return f"serial://{quote(path)}" + (f"?{query}" if query else "")


async def collect(src: FrameSource, out: list[Frame]) -> None:
    async for frame in src.frames():
        out.append(frame)


class Consumer:
    """Open a source and read its frames into ``self.frames`` in a background task."""

    def __init__(self, url: str, **kwargs: object) -> None:
        self.src = open_source(url, **kwargs)
        self.frames: list[Frame] = []
        self.task: asyncio.Task[None] | None = None

    async def __aenter__(self) -> Consumer:
        await self.src.open()
        self.task = asyncio.create_task(collect(self.src, self.frames))
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.src.close()
        assert self.task is not None
        # close() must end a pending read promptly: frames() then finishes by itself.
        await asyncio.wait_for(self.task, 1.0)


def test_url_opens_serial_driver(pty_device) -> None:
    src = open_source(serial_url(pty_device.path, baud=115200))
    assert isinstance(src, SerialSource)
    assert src.path == pty_device.path and src.baud == 115200 and src.exclusive


def test_frames_decoded(pty_device, frame_factory, same_frame, wait_until) -> None:
    sent = frame_factory(50, seed=1)

    async def main() -> None:
        async with Consumer(serial_url(pty_device.path)) as c:
            await pty_device.send(b"".join(encode_frame(f) for f in sent))
            await wait_until(lambda: len(c.frames) == len(sent), WAIT_S)
            assert c.src.connected
            assert c.src.bytes_read == sum(len(encode_frame(f)) for f in sent)
        assert all(same_frame(a, b) for a, b in zip(c.frames, sent, strict=True))
        assert c.src.decoder.stats.rejected == 0 and c.src.decoder.stats.lost == 0
        # Host times are stamped at receipt (monotonic seconds), never left at zero.
        assert all(0 < f.host_time <= time.monotonic() for f in c.frames)

    asyncio.run(main())


def test_frame_split_at_every_byte_boundary(pty_device, frame_factory, same_frame,
                                            wait_until) -> None:
    length = len(encode_frame(frame_factory(1)[0]))
    sent = frame_factory(length - 1, seed=2)

    async def main() -> None:
        async with Consumer(serial_url(pty_device.path)) as c:
            for k, frame in enumerate(sent, start=1):
                wire = encode_frame(frame)
                assert len(wire) == length
                before = c.src.bytes_read
                pty_device.write(wire[:k])
                # The driver must have *read* the first part before the rest is written, so
                # the frame really is split across reads.
                await wait_until(lambda n=before + k: c.src.bytes_read == n, WAIT_S)
                assert len(c.frames) == k - 1
                pty_device.write(wire[k:])
                await wait_until(lambda k=k: len(c.frames) == k, WAIT_S)
        assert all(same_frame(a, b) for a, b in zip(c.frames, sent, strict=True))
        assert c.src.decoder.stats.rejected == 0

    asyncio.run(main())


def test_garbage_between_frames(pty_device, frame_factory, same_frame, wait_until) -> None:
    sent = frame_factory(30, seed=3)
    rng = np.random.default_rng(3)

    def garbage() -> bytes:
        # Line noise, zeros included, closed by a delimiter: it must cost no frame.
        noise = rng.integers(0, 256, size=int(rng.integers(1, 60)), dtype=np.uint8).tobytes()
        return b"\xff\x13" + noise + b"\x00"

    async def main() -> None:
        async with Consumer(serial_url(pty_device.path)) as c:
            await pty_device.send(b"".join(garbage() + encode_frame(f) for f in sent))
            await wait_until(lambda: len(c.frames) == len(sent), WAIT_S)
            assert all(same_frame(a, b) for a, b in zip(c.frames, sent, strict=True))
            assert c.src.decoder.stats.rejected >= len(sent)  # each b"\xff\x13..." chunk
            # Garbage *without* a final 0x00 is glued to the next frame: that one is lost,
            # the one after it arrives.
            more = frame_factory(2, seed=4, start_seq=len(sent))
            await pty_device.send(b"\x07\x99\x42" + encode_frame(more[0]) + encode_frame(more[1]))
            await wait_until(lambda: len(c.frames) == len(sent) + 1, WAIT_S)
            assert same_frame(c.frames[-1], more[1])
            assert c.src.decoder.stats.lost == 1

    asyncio.run(main())


def test_3_axis_frames_and_hostile_3_axis_headers(pty_device, wait_until) -> None:
    """Version-2 (3-axis) frames arrive whole through the pty; a header claiming 3 axes over
    a 1-axis payload (good CRC) and one cut short are counted and skipped, the frames after
    them delivered."""
    import zlib

    from tactiled.frames import HEADER, cobs_encode

    rng = np.random.default_rng(5)
    sent = []
    for k in range(6):
        xyz = rng.integers(0, 0x10000, (4, 6, 3)).astype(np.uint16)
        sent.append(Frame(seq=k, device_time_us=1000 * k, raw=xyz[..., 2].copy(), taxels=xyz))
    body = HEADER.pack(2, 3, 0, 100, 0, 4, 6) + b"\x01\x02" * 24  # 3 axes claimed, 1 sent
    liar = cobs_encode(body + zlib.crc32(body).to_bytes(4, "little")) + b"\x00"
    cut = encode_frame(sent[3])[:60] + b"\x00"
    stream = (encode_frame(sent[0]) + encode_frame(sent[1]) + liar + encode_frame(sent[2])
              + cut + b"".join(encode_frame(f) for f in sent[4:]))

    async def main() -> None:
        async with Consumer(serial_url(pty_device.path)) as c:
            await pty_device.send(stream)
            await wait_until(lambda: len(c.frames) == 5, WAIT_S)
            assert [f.seq for f in c.frames] == [0, 1, 2, 4, 5]
            for got in c.frames:
                np.testing.assert_array_equal(got.taxels, sent[got.seq].taxels)
            stats = c.src.decoder.stats
            assert (stats.length_errors, stats.truncated, stats.rejected) == (1, 1, 2)

    asyncio.run(main())


def test_read_never_blocks_the_event_loop(pty_device) -> None:
    async def main() -> None:
        ticks = 0

        async def ticker() -> None:
            nonlocal ticks
            while True:
                await asyncio.sleep(0.001)
                ticks += 1

        async with open_source(serial_url(pty_device.path)) as src:
            task = asyncio.create_task(ticker())
            with pytest.raises(DeviceTimeoutError):
                await src.read(timeout=0.1)  # no data: the wait must be in the loop
            task.cancel()
        # A blocking read would have starved the ticker for the whole 0.1 s: it would not have
        # run once before the read returned.  It ran again and again (a loaded machine may
        # wake a 1 ms sleep tens of ms late, so no count per second is asked for).
        assert ticks >= 3

    asyncio.run(main())


def test_read_timeout_loses_no_data(pty_device, frame_factory, same_frame) -> None:
    sent = frame_factory(1, seed=5)[0]

    async def main() -> None:
        async with open_source(serial_url(pty_device.path)) as src:
            start = time.monotonic()
            with pytest.raises(DeviceTimeoutError, match="no data within"):
                await src.read(timeout=0.05)
            assert 0.04 <= time.monotonic() - start < 0.5
            assert src.connected  # a quiet device is not a lost one
            # The cancelled wait left no waiter behind for the reader thread to wake.
            assert src._reader is not None and src._reader._waiter is None
            pty_device.write(encode_frame(sent))
            got = [f async for f in _first(src, 1)]
            assert src._reader._waiter is None
        assert same_frame(got[0], sent)

    asyncio.run(main())


async def _first(src: FrameSource, n: int):
    count = 0
    async for frame in src.frames(timeout=1.0):
        yield frame
        count += 1
        if count == n:
            return


def test_unplug_reported_and_replug_resumes(pty_device, frame_factory, same_frame,
                                            wait_until, caplog) -> None:
    before, after = frame_factory(5, seed=6), frame_factory(5, seed=7, start_seq=5)
    half = encode_frame(frame_factory(1, seed=8, start_seq=99)[0])[:70]

    async def main() -> None:
        async with Consumer(serial_url(pty_device.path)) as c:
            await pty_device.send(b"".join(map(encode_frame, before)) + half)
            await wait_until(lambda: len(c.frames) == 5 and c.src.decoder.buffered == 70, WAIT_S)

            pty_device.unplug()
            lost_after = await wait_until(lambda: not c.src.connected, 1.0)
            assert lost_after < 0.25
            assert c.src.disconnects == 1 and c.src.reconnects == 0
            assert pty_device.path in c.src.last_error and "lost" in c.src.last_error

            pty_device.replug()
            back_after = await wait_until(lambda: c.src.connected, 2.0)
            assert back_after < 1.0
            assert c.src.reconnects == 1 and c.src.disconnects == 1
            # The half frame from before the unplug must not spoil the first new frame.
            await pty_device.send(b"".join(map(encode_frame, after)))
            await wait_until(lambda: len(c.frames) == 10, WAIT_S)
        assert all(same_frame(a, b) for a, b in zip(c.frames, before + after, strict=True))
        assert c.src.decoder.stats.rejected == 0

    with caplog.at_level(logging.INFO, logger="tactiled_drivers.serial"):
        asyncio.run(main())
    lost = [r for r in caplog.records if "lost" in r.getMessage()]
    assert len(lost) == 1 and lost[0].levelno == logging.WARNING
    assert any("is back" in r.getMessage() for r in caplog.records)


def test_late_replug_resumes_within_a_second(pty_device, wait_until) -> None:
    async def main() -> None:
        async with Consumer(serial_url(pty_device.path)) as c:
            pty_device.unplug()
            await wait_until(lambda: not c.src.connected, WAIT_S)
            await asyncio.sleep(0.45)  # the retries at 0.1 s and 0.3 s find nothing
            assert not c.src.connected
            assert "does not exist" in c.src.last_error
            pty_device.replug()
            assert await wait_until(lambda: c.src.connected, 2.0) < 1.0

    asyncio.run(main())


class _FastRetry(SerialSource):
    """Backoff scaled down so its shape can be timed quickly; records open attempts and the
    pauses it takes before each re-open."""

    RETRY_MIN = 0.015
    RETRY_MAX = 0.24
    attempts: list[float]
    pauses: list[float]

    def _open_port(self) -> serial.Serial:
        self.attempts.append(time.monotonic())
        return super()._open_port()

    async def _pause(self, delay: float, *, while_open: bool) -> None:
        if while_open:
            self.pauses.append(delay)
        await super()._pause(delay, while_open=while_open)


def test_backoff_doubles_up_to_the_cap(pty_device, wait_until) -> None:
    """The pauses the source takes double from ``RETRY_MIN`` up to ``RETRY_MAX`` (what it
    asks for, exactly), and it waits them: no attempt comes before its pause is over (a
    loaded machine may make one late, never early)."""
    assert (SerialSource.RETRY_MIN, SerialSource.RETRY_MAX) == (0.1, 2.0)

    async def main() -> None:
        src = _FastRetry(serial_url(pty_device.path))
        src.attempts, src.pauses = [], []
        async with src:
            task = asyncio.create_task(collect(src, []))
            await asyncio.sleep(0.01)
            pty_device.unplug()
            await wait_until(lambda: not src.connected, WAIT_S)
            await wait_until(lambda: len(src.attempts) >= 7, WAIT_S)  # the first open + 6
            pty_device.replug()
            await wait_until(lambda: src.connected, WAIT_S)
        await asyncio.wait_for(task, WAIT_S)
        assert src.pauses[:6] == pytest.approx([0.015, 0.03, 0.06, 0.12, 0.24, 0.24])
        # attempts[0] is the first open; each re-open k comes after its pause k
        gaps = np.diff(src.attempts[1:7])
        assert all(g >= 0.95 * d for g, d in zip(gaps, src.pauses[1:6])), (gaps, src.pauses)

    asyncio.run(main())


def test_retry_pause_is_cut_short_only_by_a_device_that_appears(pty_device) -> None:
    """The backoff spaces out attempts that keep failing the same way (here: the port held
    by another open, so the node is there and unchanged), but a device that appears during
    the pause is tried at once instead of up to ``RETRY_MAX`` later."""

    async def main() -> tuple[float, float]:
        src = SerialSource(serial_url(pty_device.path))
        holder = serial.Serial(pty_device.path, timeout=0, exclusive=True)
        try:
            with pytest.raises(DeviceConnectionError, match="in use"):
                src._open_port()
            start = time.monotonic()
            await src.retry_pause(0.4)
            unchanged = time.monotonic() - start
        finally:
            holder.close()
        pty_device.unplug()
        with pytest.raises(DeviceConnectionError, match="does not exist"):
            src._open_port()
        asyncio.get_running_loop().call_later(0.2, pty_device.replug)
        start = time.monotonic()
        await src.retry_pause(5.0)
        return unchanged, time.monotonic() - start

    unchanged, appeared = asyncio.run(main())
    assert unchanged >= 0.4
    # at once: one 50 ms watch step plus scheduling (2 s: a loaded machine's margin), not
    # the 5 s pause
    assert 0.2 <= appeared < 0.2 + 2.0, appeared


class _SlowRetry(SerialSource):
    RETRY_MIN = 5.0


def test_close_while_device_is_away_is_prompt(pty_device, wait_until) -> None:
    async def main() -> float:
        src = _SlowRetry(serial_url(pty_device.path))
        async with src:
            task = asyncio.create_task(collect(src, []))
            await asyncio.sleep(0.01)
            pty_device.unplug()
            await wait_until(lambda: not src.connected, WAIT_S)
            await asyncio.sleep(0.01)  # now in the 5 s backoff
            start = time.monotonic()
        await asyncio.wait_for(task, 6.0)
        return time.monotonic() - start

    assert asyncio.run(main()) < 0.5


def test_no_fd_leak_over_20_replugs(pty_device, wait_until, open_fd_count) -> None:
    async def main() -> None:
        async with Consumer(serial_url(pty_device.path)) as c:
            await asyncio.sleep(0.01)
            baseline = open_fd_count()
            for _ in range(20):
                pty_device.unplug()
                await wait_until(lambda: not c.src.connected, WAIT_S)
                pty_device.replug()
                await wait_until(lambda: c.src.connected, WAIT_S)
                assert open_fd_count() == baseline
            assert c.src.reconnects == 20 and c.src.disconnects == 20

    asyncio.run(main())


def test_close_releases_the_port(pty_device, fd_leak_check) -> None:
    async def main() -> None:
        src = open_source(serial_url(pty_device.path))
        before = _fd_count()
        await src.open()
        assert _fd_count() > before
        await src.close()
        assert _fd_count() == before and not src.connected and not src.is_open
        await src.close()  # idempotent
        # Released: an exclusive opener now succeeds.
        serial.Serial(pty_device.path, exclusive=True, timeout=0).close()

    asyncio.run(main())


def _fd_count() -> int:
    return len(os.listdir("/proc/self/fd"))


_OPENER = """
import asyncio, sys
from tactiled.errors import DeviceConnectionError
from tactiled.sources import open_source

async def main() -> int:
    src = open_source(sys.argv[1])
    try:
        await src.open()
    except DeviceConnectionError as err:
        print("REFUSED:", err)
        return 3
    await src.close()
    print("OPENED")
    return 0

sys.exit(asyncio.run(main()))
"""


def _open_in_subprocess(url: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", _OPENER, url], capture_output=True,
                          text=True, timeout=30)


def test_exclusive_open_refused_for_a_second_opener(pty_device) -> None:
    url = serial_url(pty_device.path)

    async def main() -> None:
        async with open_source(url):
            other = _open_in_subprocess(url)
            assert other.returncode == 3, other.stderr
            assert "in use by another process" in other.stdout
            assert pty_device.path in other.stdout
            # flock belongs to the open file description, so a second open() in this very
            # process is refused as well.
            with pytest.raises(DeviceConnectionError, match="in use"):
                await open_source(url).open()
        # Once closed, the port is free again.
        again = _open_in_subprocess(url)
        assert again.returncode == 0 and "OPENED" in again.stdout, again.stdout + again.stderr

    asyncio.run(main())


def test_exclusive_can_be_switched_off(pty_device) -> None:
    async def main() -> None:
        async with open_source(serial_url(pty_device.path, exclusive=0)) as src:
            assert src.exclusive is False
            serial.Serial(pty_device.path, timeout=0).close()  # no lock taken

    asyncio.run(main())


def test_missing_device_and_non_tty(tmp_path: Path) -> None:
    async def main() -> None:
        with pytest.raises(DeviceConnectionError, match="does not exist"):
            await open_source(serial_url(str(tmp_path / "nope"))).open()
        plain = tmp_path / "plain-file"
        plain.write_bytes(b"")
        with pytest.raises(DeviceConnectionError, match=str(plain)):
            await open_source(serial_url(str(plain))).open()

    asyncio.run(main())


def test_serial_url_errors() -> None:
    with pytest.raises(ValueError, match="no device path"):
        open_source("serial://")
    with pytest.raises(ValueError, match="baud='fast'"):
        open_source("serial:///dev/ttyACM0?baud=fast")
    with pytest.raises(ValueError, match="baud='0'"):
        open_source("serial:///dev/ttyACM0?baud=0")
    with pytest.raises(ValueError, match="exclusive='maybe'"):
        open_source("serial:///dev/ttyACM0?exclusive=maybe")
    with pytest.raises(ValueError, match=r"unknown parameter.*bauds"):
        open_source("serial:///dev/ttyACM0?bauds=9600")


def test_one_read_drains_more_than_the_ttys_4095_byte_chunks(pty_device) -> None:
    """A tty hands out at most 4095 bytes per read(); with 8 KB waiting, one read() of the
    driver returns all of it (everything its reader thread holds), so a busy event loop that
    gets to the port rarely does not let a 1 kHz finger fill the device buffer (bug 7)."""

    async def main() -> int:
        async with SerialSource(serial_url(pty_device.path)) as src:
            pty_device.write(bytes(range(1, 256)) * 32)  # 8160 bytes, no frame delimiter
            await asyncio.sleep(0.2)  # all of it in the slave's buffer
            return len(await src.read(timeout=2.0))

    assert asyncio.run(main()) == 255 * 32


def test_host_time_is_when_the_bytes_arrived_not_when_the_loop_took_them(
        pty_device, frame_factory) -> None:
    """A frame's ``host_time`` (the start of its latency) is stamped by the reader thread as
    the bytes arrive: a loop busy for 0.3 s must show up as 0.3 s of latency."""
    sent = frame_factory(1, seed=9)[0]

    async def main() -> tuple[float, float, float]:
        async with SerialSource(serial_url(pty_device.path)) as src:
            before = time.monotonic()
            pty_device.write(encode_frame(sent))
            time.sleep(0.3)  # the loop is busy; the thread reads meanwhile
            taken = time.monotonic()
            frame = [f async for f in _first(src, 1)][0]
            return before, frame.host_time, taken

    before, host_time, taken = asyncio.run(main())
    assert before <= host_time < before + 0.15 < taken

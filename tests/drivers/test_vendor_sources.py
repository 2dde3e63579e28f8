"""The serial vendor drivers over a real pseudo-terminal (pyserial on the slave, the test plays
the device on the master): hostile streams, an unplug mid-frame, a device that stops and comes
back, a 10 MB line, and the Robotiq device's two fingers on one port with its auto-send."""

from __future__ import annotations

import asyncio
import os
import sys
import time
from urllib.parse import quote

import numpy as np
import pytest

from tactiled import native
from tactiled.errors import DriverError
from tactiled.frames import Frame
from tactiled.sources import FrameSource, open_source
from tactiled_drivers import flexitac, lines, robotiq

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux ptys and /proc/self/fd")


class Reader:
    """Open a source and collect its frames in a background task."""

    def __init__(self, url: str) -> None:
        self.src: FrameSource = open_source(url)
        self.frames: list[Frame] = []
        self.task: asyncio.Task[None] | None = None

    async def _collect(self) -> None:
        try:
            async for frame in self.src.frames():
                self.frames.append(frame)
        except DriverError:
            if self.src.is_open:  # closed between two reads: the stream ended, else a failure
                raise

    async def __aenter__(self) -> Reader:
        await self.src.open()
        self.task = asyncio.create_task(self._collect())
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.src.close()
        assert self.task is not None
        await asyncio.wait_for(self.task, 2.0)


def arrays(n: int, shape: tuple[int, int], hi: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, hi, shape).astype(np.uint16) for _ in range(n)]


def match(frames: list[Frame], sent: list[np.ndarray]) -> bool:
    return len(frames) == len(sent) and all(np.array_equal(f.raw, a)
                                            for f, a in zip(frames, sent))


def test_lines_hostile_stream_and_ten_megabyte_line(pty_device, wait_until) -> None:
    sent = arrays(30, (4, 5), 60000, seed=1)
    good = [lines.encode(a) for a in sent]
    bad = [b"1,2,3\r\n", b"1," * 25 + b"\n", b"a,b,c,d,e,f,g,h,i,j,k,l,m,n,o,p,q,r,s,t\n",
           b"\xff\xfe\x00garbage\n"]

    async def main() -> None:
        url = f"lines://{quote(pty_device.path)}?rows=4&cols=5&sep=,&baud=115200"
        async with Reader(url) as r:
            stream = b"".join(good[:10]) + b"".join(bad) + b"".join(good[10:20])
            await pty_device.send(stream)
            await wait_until(lambda: len(r.frames) == 20, 5.0)
            # a line of 10 MB without a newline: dropped as it arrives
            big = b"7" * (10 << 20)
            await pty_device.send(big, chunk=1 << 16)
            await pty_device.send(b"\n" + b"".join(good[20:]))
            await wait_until(lambda: len(r.frames) == 30, 30.0)
            framer = r.src.decoder
            assert framer.buffered <= lines.MAX_LINE
            st = r.src.status()
            assert st.connected and st.decoder["oversize"] == 1
            assert (st.decoder["truncated"], st.decoder["length_errors"],
                    st.decoder["parse_errors"]) == (2, 1, 1)  # a field count is checked first
            assert st.bytes_read == len(stream) + len(big) + 1 + sum(map(len, good[20:]))
        assert match(r.frames, sent) and [f.seq for f in r.frames] == list(range(30))
        assert all(f.device_time_us >= 0 for f in r.frames)

    asyncio.run(main())


def test_flexitac_markers_in_data_unplug_mid_frame_and_return(pty_device, wait_until) -> None:
    sent = arrays(40, (12, 32), 256, seed=2)
    for k, a in enumerate(sent):  # the marker inside the data, at a new place in every frame
        a.flat[k * 7:k * 7 + 2] = (0xAA, 0x55)
    data = [flexitac.encode(a) for a in sent]

    async def main() -> None:
        url = f"flexitac://{quote(pty_device.path)}"
        async with Reader(url) as r:
            assert r.src.baud == 2_000_000 and r.src.device_array().shape == (12, 32)
            await pty_device.send(b"\x55\xaa\x13" + b"".join(data[:20]) + data[20][:100])
            await wait_until(lambda: len(r.frames) == 20, 5.0)  # 19 good + the one confirmed
            pty_device.unplug()  # mid-frame
            await wait_until(lambda: r.src.disconnects == 1, 5.0)
            await asyncio.sleep(0.3)
            pty_device.replug()
            await wait_until(lambda: r.src.connected and r.src.reconnects == 1, 5.0)
            await asyncio.sleep(0.1)
            await pty_device.send(b"".join(data[21:]))
            await wait_until(lambda: len(r.frames) == 38, 5.0)
            st = r.src.status()
        # frame 19 was confirmed by frame 20's marker; frame 20 was cut by the unplug; after the
        # return every frame but the last (waiting for its successor) comes out
        assert match(r.frames, sent[:20] + sent[21:39])
        assert st.decoder["truncated"] == 1 and st.decoder["discarded"] >= 3
        assert "ttyTACT" in st.last_error  # the last problem stays on record

    asyncio.run(main())


def read_master(pty_device, want: int, timeout: float = 3.0) -> bytes:
    got = b""
    deadline = time.monotonic() + timeout
    while len(got) < want and time.monotonic() < deadline:
        try:
            got += os.read(pty_device.master, 4096)
        except BlockingIOError:
            time.sleep(0.005)
    return got


def test_robotiq_two_fingers_share_the_port(pty_device, wait_until) -> None:
    left, right = arrays(15, (7, 4), 65536, seed=3), arrays(15, (7, 4), 65536, seed=4)
    packets = [robotiq.encode_finger(0, a, timestamp_ms=10 * k, dynamic=k)
               + robotiq.encode_finger(1, b, timestamp_ms=10 * k)
               for k, (a, b) in enumerate(zip(left, right))]
    other = robotiq.encode_finger(2, left[0])

    async def main() -> None:
        base = f"robotiq://{quote(pty_device.path)}"
        async with Reader(base + "?finger=0&period_ms=5") as r0:
            # the first finger to open starts the device's auto-send (period 5 ms, CRC byte 0)
            assert read_master(pty_device, 5) == bytes([0x9A, 0x00, 0x58, 0x01, 0x05])
            async with Reader(base + "?finger=1") as r1:
                assert read_master(pty_device, 1, timeout=0.2) == b""  # the port is shared
                junk = b"\x9a\x00\x58\x30" + b"\x9a" * 7 + b"noise"
                # A packet whose bytes span reads and end the stream waits for the next
                # packet's start (the driver's module text): a third finger's packets, which
                # neither reader frames, confirm each burst's last.
                await pty_device.send(b"".join(packets[:8]) + junk + b"".join(packets[8:])
                                      + other)
                await wait_until(lambda: len(r0.frames) == 15 and len(r1.frames) == 15, 5.0)
                assert r0.src.connected and r1.src.connected
                assert r0.src.device_array().shape == (7, 4)
            # the other finger still reads
            more = robotiq.encode_finger(0, left[0], timestamp_ms=999)
            await pty_device.send(more + other)
            await wait_until(lambda: len(r0.frames) == 16, 5.0)
        # the last to close stops the auto-send
        assert read_master(pty_device, 5) == bytes([0x9A, 0x00, 0x58, 0x01, 0x00])
        assert match(r0.frames, [*left, left[0]]) and match(r1.frames, right)
        assert [f.sensor_id for f in r1.frames] == [1] * 15
        assert [f.device_time_us for f in r0.frames][:3] == [0, 10_000, 20_000]
        assert r0.frames[2].extras["dynamic"] == 2 and "accelerometer" in r0.frames[2].extras
        assert r0.src.decoder.stats.rejected >= 1 and r0.src.decoder.stats.resyncs == 1
        assert robotiq._PORTS == {}
        # the compiled core's framer, unless TACTILED_CORE=python chose the reference
        assert type(r0.src.decoder) is (robotiq.RobotiqFramer if native.core is None
                                        else robotiq.NativeRobotiqFramer)

    asyncio.run(main())


def test_robotiq_unplug_mid_packet_and_replug(pty_device, wait_until) -> None:
    """Unplugged mid-packet with both fingers reading: the cut packet is counted, never glued
    to the new connection's bytes (a static field is 57 bytes whatever they hold), and the
    auto-send is started again on the new device."""
    a, b = arrays(3, (7, 4), 65536, seed=5), arrays(3, (7, 4), 65536, seed=6)
    other = robotiq.encode_finger(2, a[0])

    async def main() -> None:
        base = f"robotiq://{quote(pty_device.path)}"
        async with Reader(base + "?finger=0") as r0, Reader(base + "?finger=1") as r1:
            assert read_master(pty_device, 5)[:3] == bytes([0x9A, 0x00, 0x58])
            await pty_device.send(robotiq.encode_finger(0, a[0]) + robotiq.encode_finger(1, b[0])
                                  + other)  # (confirms finger 1's packet: as above)
            await wait_until(lambda: len(r0.frames) == 1 and len(r1.frames) == 1, 5.0)
            cut = robotiq.encode_finger(0, a[1]) + robotiq.encode_finger(1, b[1])
            await pty_device.send(cut[:len(cut) - 30])  # finger 1's static packet, cut short
            await asyncio.sleep(0.2)
            pty_device.unplug()
            await wait_until(lambda: r0.src.disconnects == 1 and not r1.src.connected, 5.0)
            pty_device.replug()
            await wait_until(lambda: r0.src.reconnects == 1 and r1.src.connected, 5.0)
            assert read_master(pty_device, 5) == bytes([0x9A, 0x00, 0x58, 0x01, 10])
            await pty_device.send(robotiq.encode_finger(0, a[2]) + robotiq.encode_finger(1, b[2])
                                  + other)  # (confirms finger 1's packet: as above)
            await wait_until(lambda: len(r0.frames) == 3 and len(r1.frames) == 2, 5.0)
            assert "ttyTACT" in r0.src.status().last_error
            await asyncio.sleep(0.1)
        assert match(r0.frames, a) and match(r1.frames, [b[0], b[2]])
        assert r1.src.decoder.stats.truncated == 1

    asyncio.run(main())


@pytest.mark.parametrize("url", [
    "lines:///dev/null?rows=2", "lines:///dev/null?rows=2&cols=2&sep=;",
    "flexitac:///dev/null?rows=0", "robotiq:///dev/null?finger=5", "robotiq://?finger=0",
    "xela://127.0.0.1:99999", "xela://127.0.0.1:5000?rows=4", "flexitac:///dev/null?colour=1",
])
def test_bad_urls_name_the_problem(url) -> None:
    with pytest.raises(ValueError, match=r"'(lines|flexitac|robotiq|xela)://"):
        open_source(url)

"""The serial driver's reader thread (``PortReader``) against a real pseudo-terminal: it must
drain the device while the event loop is stuck, stop at its memory limit, hand over every
byte before an error, and stop promptly."""

from __future__ import annotations

import asyncio
import contextlib
import os
import sys
import threading
import time
import tracemalloc
from collections.abc import Iterator

import pytest
import serial

from procs import block_until

from tactiled_drivers.plumbing.port_reader import TAKE_LIMIT, PortReader

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux ptys")

PAYLOAD = bytes(range(1, 256)) * 257  # 65 535 bytes: four times what a pty buffers


class Writer(threading.Thread):
    """Plays the device from a thread (the event loop is blocked on purpose): writes
    ``data`` to the pty master, retrying on a full buffer, until ``deadline`` s."""

    def __init__(self, master: int, data: bytes, deadline: float) -> None:
        super().__init__(daemon=True)
        self.master, self.data, self.deadline = master, data, deadline
        self.accepted = 0
        self.finished_at: float | None = None

    def run(self) -> None:
        end = time.monotonic() + self.deadline
        view = memoryview(self.data)
        while self.accepted < len(self.data) and time.monotonic() < end:
            try:
                self.accepted += os.write(self.master, view[self.accepted:self.accepted + 1024])
            except BlockingIOError:
                time.sleep(0.001)
        if self.accepted == len(self.data):
            self.finished_at = time.monotonic()


def open_port(path: str) -> serial.Serial:
    return serial.Serial(path, timeout=None, exclusive=True)


@contextlib.contextmanager
def reading(path: str, **kwargs: int) -> Iterator[tuple[serial.Serial, PortReader]]:
    """The port open with a reader on it; both stopped and closed on the way out."""
    port = open_port(path)
    reader = PortReader(port, **kwargs)
    try:
        yield port, reader
    finally:
        reader.stop()
        port.close()


async def take_all(reader: PortReader, n: int, timeout: float = 5.0) -> bytes:
    got = b""
    async with asyncio.timeout(timeout):
        while len(got) < n:
            got += await reader.take()
    return got


def test_drains_the_device_while_the_event_loop_is_stuck(pty_device) -> None:
    """64 KB arrive while the loop is blocked for 1.5 s: a reader in the loop would let the
    pty fill after ~15 KB and the device would stall (or drop, at 1 kHz); the thread takes
    it all as it comes, and the loop then gets every byte in order."""

    async def main() -> None:
        with reading(pty_device.path) as (_port, reader):
            writer = Writer(pty_device.master, PAYLOAD, deadline=1.5)
            start = time.monotonic()
            writer.start()
            time.sleep(1.5)  # the event loop is stuck (a GC pause, a CPU-starved process)
            writer.join()
            assert writer.accepted == len(PAYLOAD), \
                f"the device could write only {writer.accepted} of {len(PAYLOAD)} bytes"
            assert writer.finished_at is not None and writer.finished_at - start < 1.5
            assert await take_all(reader, len(PAYLOAD)) == PAYLOAD
            assert reader.peak >= 32 * 1024  # held for the loop: it really was behind

    asyncio.run(main())


def test_a_backlog_goes_to_the_loop_in_bounded_pieces(pty_device) -> None:
    """After the loop was held up, what the thread holds comes out oldest first in pieces of
    at most TAKE_LIMIT: a backlog of a megabyte must not become one block of a megabyte
    (freed after decoding, it left glibc's heap grown by as much)."""
    payload = PAYLOAD * 3  # ~192 KB: three pieces' worth

    async def main() -> None:
        with reading(pty_device.path) as (_port, reader):
            writer = Writer(pty_device.master, payload, deadline=3.0)
            writer.start()
            time.sleep(1.5)  # the event loop is stuck
            writer.join()
            assert writer.accepted == len(payload)
            pieces = []
            async with asyncio.timeout(5.0):
                while sum(map(len, pieces)) < len(payload):
                    pieces.append(await reader.take())
            assert b"".join(pieces) == payload
            assert len(pieces) >= 3 and max(map(len, pieces)) <= TAKE_LIMIT
            assert reader.held == 0

    asyncio.run(main())


def test_a_stall_costs_no_memory_beyond_the_ring(pty_device) -> None:
    """While the loop is stuck, what the thread reads goes into its ring, allocated once: a
    backlog of ~190 KB allocates next to nothing (the 1-hour soak's service grew after stalls
    of minutes by what the reader threads had allocated for their backlog, scattered through
    their malloc arenas: docs/performance/reliability.md)."""
    payload = PAYLOAD * 3

    async def main() -> None:
        with reading(pty_device.path) as (_port, reader):
            tracemalloc.start()
            try:
                before = tracemalloc.take_snapshot()
                writer = Writer(pty_device.master, payload, deadline=3.0)
                writer.start()
                time.sleep(1.5)  # the event loop is stuck
                writer.join()
                after = tracemalloc.take_snapshot()
            finally:
                tracemalloc.stop()
            assert writer.accepted == len(payload)
            assert reader.held >= len(payload) // 2  # it really holds a backlog
            grown = sum(d.size_diff for d in after.compare_to(before, "filename")
                        if d.size_diff > 0)
            # bytes objects per read would be the backlog itself (~190 KB); the ring's
            # marks cost about a hundred bytes per read
            assert grown < 48 * 1024, f"{grown} bytes allocated during the stall"
            assert await take_all(reader, len(payload)) == payload

    asyncio.run(main())


def test_stops_reading_at_its_limit_and_loses_nothing(pty_device) -> None:
    """At ``limit`` bytes held the thread stops reading, so the kernel buffer fills and the
    device is held back (memory stays bounded); once the loop takes, reading resumes and
    every byte arrives in order."""

    async def main() -> None:
        with reading(pty_device.path, limit=4096) as (_port, reader):
            writer = Writer(pty_device.master, PAYLOAD, deadline=5.0)
            writer.start()
            # the reader at its limit and the kernel buffer holding what it no longer reads
            block_until(lambda: reader.full and writer.accepted > reader.peak, 5.0,
                        "the reader at its limit")
            held_back = writer.accepted
            assert held_back < len(PAYLOAD)  # back-pressure reached the device
            assert 4096 <= reader.peak < held_back
            got = await take_all(reader, len(PAYLOAD))
            writer.join()
            assert got == PAYLOAD

    asyncio.run(main())


def test_error_comes_after_every_byte_read_before_it(pty_device) -> None:
    async def main() -> None:
        with reading(pty_device.path) as (_port, reader):
            pty_device.write(PAYLOAD[:3000])
            block_until(lambda: reader.held >= 3000, 5.0, "the bytes read")
            pty_device.unplug()  # the slave's reads now fail (EIO)
            block_until(lambda: not reader.alive, 5.0, "the reader ended by the error")
            assert await take_all(reader, 3000) == PAYLOAD[:3000]
            with pytest.raises((serial.SerialException, OSError)):
                await reader.take()
            assert await reader.take() == b""  # the error is raised once, then end of data

    asyncio.run(main())


def test_stop_wakes_a_pending_take_and_leaves_the_port_open(pty_device) -> None:
    async def main() -> None:
        port = open_port(pty_device.path)
        reader = PortReader(port)
        try:
            pending = asyncio.create_task(reader.take())
            await asyncio.sleep(0.05)
            assert not pending.done()
            start = time.monotonic()
            reader.stop()
            assert await asyncio.wait_for(pending, 1.0) == b""
            assert time.monotonic() - start < 1.0
            assert not reader.alive
            assert port.is_open
        finally:
            port.close()

    asyncio.run(main())


def test_a_cancelled_take_loses_nothing(pty_device) -> None:
    async def main() -> None:
        with reading(pty_device.path) as (_port, reader):
            with pytest.raises(TimeoutError):
                await asyncio.wait_for(reader.take(), 0.05)
            assert reader._waiter is None
            pty_device.write(b"abc")
            assert await take_all(reader, 3) == b"abc"

    asyncio.run(main())


def test_limit_must_be_positive(pty_device) -> None:
    async def main() -> None:
        port = open_port(pty_device.path)
        try:
            with pytest.raises(ValueError, match="limit must be at least 1 byte"):
                PortReader(port, limit=0)
        finally:
            port.close()

    asyncio.run(main())


def test_the_loop_reads_every_port_and_one_thread_stands_guard(pty_devices, wait_until) -> None:
    """Three ports: while the loop is free, the loop reads each port's bytes as they arrive
    (whole and in order) and the one guard thread of the process reads nothing; while the
    loop is held up, the thread reads them (the device never waits), and the loop then gets
    them in order.  The thread ends when the last port stops."""
    from tactiled_drivers.plumbing import read_thread

    devices = [pty_devices(f"tty{i}") for i in range(3)]

    async def main() -> None:
        ports = [open_port(d.path) for d in devices]
        readers = [PortReader(p) for p in ports]
        try:
            names = [t.name for t in threading.enumerate() if t.name.startswith("tactiled-read")]
            assert names == ["tactiled-read"], names
            thread = readers[0]._shared
            assert thread is not None and all(r._shared is thread for r in readers)
            # the guard looking rarely (an idle port is one the loop has not read for a
            # while, so a guard at its 4 ms might happen on a write before the loop's call)
            thread.interval = 0.5
            await asyncio.sleep(0.05)
            before = thread.drains
            for k in range(20):  # the loop free between the writes
                for i, d in enumerate(devices):
                    d.write(bytes([i + 1, k]) * 50)
                got = await asyncio.gather(*(take_all(r, 100) for r in readers))
                assert got == [bytes([i + 1, k]) * 50 for i in range(3)]
                await asyncio.sleep(0.001)
            assert thread.drains == before  # the loop read it all
            thread.interval = read_thread.GUARD_INTERVAL_S
            await asyncio.sleep(0.6)  # (the guard's long wait ends)
            for i, d in enumerate(devices):
                d.write(bytes([i + 1]) * 100)
            time.sleep(0.1)  # the loop is stuck: the guard reads
            assert thread.drains > before
            assert all(r.held == 100 for r in readers)
            for i, d in enumerate(devices):
                d.write(bytes([i + 7]) * 100)
            got = await asyncio.gather(*(take_all(r, 200) for r in readers))
            assert got == [bytes([i + 1]) * 100 + bytes([i + 7]) * 100 for i in range(3)]
        finally:
            for r in readers:
                r.stop()
            for p in ports:
                p.close()
        await wait_until(lambda: not any(t.name == "tactiled-read"
                                         for t in threading.enumerate()), 5.0)

    asyncio.run(main())


def test_a_full_ring_is_not_read_until_the_loop_takes(pty_device, monkeypatch) -> None:
    """At its limit a port is read by nobody (its bytes wait in the kernel): the loop stops
    watching it, rather than being called at every turn to find no room, until it takes."""
    calls = 0
    on_readable = PortReader._on_readable

    def counted(self: PortReader) -> None:
        nonlocal calls
        calls += 1
        on_readable(self)

    monkeypatch.setattr(PortReader, "_on_readable", counted)

    async def main() -> None:
        with reading(pty_device.path, limit=4096) as (_port, reader):
            writer = Writer(pty_device.master, PAYLOAD, deadline=5.0)
            writer.start()
            # (the loop is held: the guard fills the ring)
            block_until(lambda: reader.full, 10.0, "the ring full")
            before = calls
            await asyncio.sleep(0.3)  # the loop free, the ring full, the port readable
            assert reader.full and not reader._watched
            assert calls - before <= 1, calls - before  # thousands if it spun
            got = await take_all(reader, len(PAYLOAD))
            writer.join()
            assert got == PAYLOAD
            assert calls > before  # (the loop read the rest once it had room)

    asyncio.run(main())

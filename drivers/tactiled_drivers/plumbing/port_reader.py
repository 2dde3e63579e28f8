"""A reader that empties a serial port's kernel buffer as soon as bytes arrive.

The event loop reads the port as bytes arrive (``loop.add_reader``) and the process's
:class:`~tactiled_drivers.plumbing.read_thread.ReadThread` reads it whenever the loop has not
for a few milliseconds, into one preallocated ring of ``limit`` bytes (memory bounded, no
allocation per read).  An error (device unplugged) reaches the consumer after every byte read
before it, so no good frame is lost to it.
"""
# Why: a tty buffers little (a pty about 15 KB, a USB CDC-ACM port some 64 KB: 30 ms to 0.4 s of
# an array at 1 kHz), and the loop can wake up to 1.5 s late under load
# (docs/performance/reliability.md), which, read by the loop alone, loses frames on full ptys.
# While the loop keeps up no thread stands between a frame and its decoding.  A port without a
# descriptor (not POSIX) gets a thread of its own that blocks in pyserial's reads.  Decoding
# stays on the loop, which takes everything read so far when it gets round to it.
# The ring: 4 MiB by default (~27 s of a 1 kHz finger), read into with os.readv.  At the limit
# nobody reads the port, so the kernel buffer fills and the device drops.  The loop takes at most
# TAKE_LIMIT (64 KiB) per PortReader.take.  Both rules keep glibc's heap flat over hour-long
# runs: a megabyte backlog handed over as one block and freed leaves the heap grown for good
# (the mmap threshold rises to the largest block freed), and thousands of few-kilobyte reads
# allocated in the reader thread's arena and freed from the loop's thread fragment that arena
# beyond what malloc_trim gives back.  With the ring, a stall of any length costs no memory
# beyond the ring itself.

from __future__ import annotations

import asyncio
import logging
import os
import select
import threading
import time
from collections import deque

import serial

from tactiled_drivers.plumbing import read_thread
from tactiled_drivers.plumbing.futures import resolve
from tactiled_drivers.plumbing.read_thread import ReadThread

log = logging.getLogger(__name__)

DEFAULT_LIMIT = 4 << 20  # bytes held before reading pauses
TAKE_LIMIT = 64 << 10  # bytes handed to the loop per take() (a larger read comes whole)
JOIN_TIMEOUT = 2.0  # seconds stop() waits for the thread


def _hung_up(fd: int) -> bool:
    """``fd`` polls hung up or in error, now."""
    poller = select.poll()
    poller.register(fd, select.POLLIN)
    return any(ev & (select.POLLHUP | select.POLLERR) for _fd, ev in poller.poll(0))


class PortReader:
    """Reads ``port`` as bytes arrive (see the module's doc); :meth:`take` hands them to the
    event loop.

    ``port`` must be open with ``timeout=None`` (a port without a descriptor is read in
    blocking reads that :meth:`stop` interrupts with pyserial's ``cancel_read``).  Create it
    from the event loop's thread; :meth:`take` and :meth:`stop` are called from that thread
    too.
    """

    def __init__(self, port: serial.Serial, *, limit: int = DEFAULT_LIMIT) -> None:
        if limit < 1:
            raise ValueError(f"limit must be at least 1 byte, got {limit}")
        self._port = port
        self._loop = asyncio.get_running_loop()
        self.limit = limit
        self._lock = threading.Lock()
        self._ring = bytearray(limit)  # every byte read lives here until taken
        self._view = memoryview(self._ring)
        #: absolute byte counts: read into the ring so far, and taken from it (held = the
        #: difference; a byte's place in the ring is its count modulo ``limit``)
        self._written = 0
        self._taken = 0
        #: one mark per read, oldest first: (absolute end of its bytes, monotonic s read)
        self._marks: deque[tuple[int, float]] = deque()
        # the descriptor to read into the ring (pyserial's POSIX ports); else port.read() is
        # copied into it
        fd = getattr(port, "fd", None)
        self._fd: int | None = fd if isinstance(fd, int) and fd >= 0 else None
        #: Most bytes held at once: how far the loop fell behind the device (bytes).
        self.peak = 0
        self._error: BaseException | None = None
        #: ``time.monotonic()`` when the newest of the bytes :meth:`take` last returned were
        #: read from the device (s): the host time of those frames, loop lag included.
        self.arrival = 0.0
        self._ended = False
        self._stopping = False
        self._waiter: asyncio.Future[None] | None = None
        self._room = threading.Event()
        self._room.set()
        #: held while the port is read (by the loop or the read thread): one read at a time
        self.read_lock = threading.Lock()
        #: ``time.monotonic()`` when the loop last read the port (s): the read thread reads it
        #: when this is too old (read_thread.STALL_S)
        self.last_read = time.monotonic()
        #: the read thread took bytes since the loop's last read: a readiness the loop then
        #: finds empty was the thread's doing, not a vanished device
        self._guard_took = False
        self._watched = False  # the loop calls _on_readable when the port has bytes
        #: the process's read thread (a port with a descriptor), else a thread of its own
        self._shared: ReadThread | None = None
        self._thread: threading.Thread | None = None
        if self._fd is not None:
            self._watch()
            self._shared = read_thread.register(self)
        else:
            self._thread = threading.Thread(target=self._run, daemon=True,
                                            name=f"tactiled-read {port.port}")
            self._thread.start()

    @property
    def fd(self) -> int:
        """The port's descriptor (a reader of the shared read thread has one)."""
        assert self._fd is not None
        return self._fd

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        """The event loop :meth:`take` runs on."""
        return self._loop

    @property
    def full(self) -> bool:
        """The ring holds ``limit`` bytes: nothing more is read until the loop takes some."""
        return not self._room.is_set()

    # -- reading: the loop's side --------------------------------------------------------------

    def _watch(self) -> None:
        if not self._watched:
            self._loop.add_reader(self.fd, self._on_readable)
            self._watched = True

    def _unwatch(self) -> None:
        if self._watched:
            self._watched = False
            try:
                self._loop.remove_reader(self.fd)
            except (OSError, ValueError, RuntimeError):  # closed already: nothing to remove
                pass

    def _on_readable(self) -> None:
        """(The loop's callback.)  The port has bytes: read them into the ring and wake the
        waiting :meth:`take`, if any."""
        if self._stopping or self._ended:
            self._unwatch()
            return
        error = None
        with self.read_lock:
            self.last_read = time.monotonic()
            strict, self._guard_took = not self._guard_took, False
            try:
                waiter = self._drain(0, woke=strict)
            except Exception as err:  # noqa: BLE001 (the device went away, or a bug)
                waiter, error = None, err
        if error is not None:
            self._unwatch()
            if self._shared is not None:
                self._shared.remove(self, 0.0)
            waiter = self.failed(error)
        elif self.full:
            self._unwatch()  # until take() makes room: the kernel buffer holds the rest
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    # -- reading: the guard's side and the thread of a port without a descriptor -------------

    def guard_drain(self) -> tuple[int, asyncio.Future[None] | None]:
        """(The read thread's call.)  The loop has not read the port for a while: read what
        it holds into the ring, unless the loop is reading it now.  Returns the bytes read
        and the waiting :meth:`take` to wake, if any.  Raises the port's error."""
        if not self.read_lock.acquire(blocking=False):
            return 0, None  # the loop is at it
        try:
            if self._stopping or self._ended or self.full:
                return 0, None
            before = self._written
            waiter = self._drain(0, woke=False)
            read = self._written - before
            if not read and _hung_up(self.fd):
                # (what the loop's readiness would say: a pty whose master closed, an
                # unplugged adapter, reads b"" and polls hung up)
                raise serial.SerialException(
                    "device reports readiness to read but returned no data "
                    "(device disconnected or multiple access on port?)")
            self._guard_took = self._guard_took or read > 0
            return read, waiter
        finally:
            self.read_lock.release()

    def failed(self, err: BaseException) -> asyncio.Future[None] | None:
        """(The reading side's call.)  Reading raised ``err``: it goes to the consumer after
        the bytes read before it, and this reader ends.  Returns the take to wake."""
        if not isinstance(err, (serial.SerialException, OSError)):
            log.error("reader of %s failed", self._port.port, exc_info=err)
            self._fail(err)
        elif not self._stopping:  # the device went away
            self._fail(err)
        return self._end()

    def _run(self) -> None:
        """A port without a descriptor, in a thread of its own: pyserial's blocking reads."""
        port = self._port
        try:
            while not self._stopping:
                if not self._room.is_set():  # at the limit: let the kernel buffer hold it
                    self._room.wait()
                    continue
                pending = self._read_one()
                if pending is None:  # cancelled by stop()
                    continue
                self._wake(self._drain(pending))
        except (serial.SerialException, OSError) as err:  # the device went away
            if not self._stopping:
                self._fail(err)
        except Exception as err:  # a bug: report it to the consumer rather than die silently
            log.exception("reader of %s failed", port.port)
            self._fail(err)
        finally:
            self._wake(self._end())

    def _read_one(self) -> int | None:
        """A port without a descriptor (not POSIX): block in pyserial's ``read(1)``; the byte
        goes into the ring (1), or None when cancelled."""
        data = self._port.read(1)
        if not data:
            return None
        pos, _room = self._room_at(0)  # room for one byte was checked by the caller
        self._ring[pos] = data[0]
        return 1

    def _drain(self, pending: int, woke: bool = False) -> asyncio.Future[None] | None:
        """Read what the device holds into the ring after ``pending`` bytes of this wake, and
        commit them (made the loop's, one mark per piece); a mark never crosses the ring's end
        nor TAKE_LIMIT.  ``woke``: the port said readable, so the first read must return
        something.  Returns the waiting take to wake, if any."""
        waiter = None
        while not self._stopping:
            pos, room = self._room_at(pending)
            if pending and (pos == 0 or pending >= TAKE_LIMIT):
                waiter = self._commit(pending) or waiter
                pending = 0
                continue
            n = min(room, TAKE_LIMIT - pending)
            if n <= 0:
                break  # the ring is full: wait for room at the top of the loop
            got = self._read_into(pos, n)
            if not got and woke:  # readable, yet nothing: a vanished device (pyserial's words)
                raise serial.SerialException(
                    "device reports readiness to read but returned no data "
                    "(device disconnected or multiple access on port?)")
            woke = False
            pending += got
            if got < n:
                break  # the kernel had no more: back to waiting
        if pending:
            waiter = self._commit(pending) or waiter
        return waiter

    def _room_at(self, pending: int) -> tuple[int, int]:
        """Where the byte after ``pending`` uncommitted ones goes in the ring, and how many
        fit from there before the ring's end or the bytes not yet taken."""
        at = self._written + pending
        pos = at % self.limit
        free = self.limit - (at - self._taken)  # _taken only grows: safe to read unlocked
        return pos, min(free, self.limit - pos)

    def _read_into(self, pos: int, n: int) -> int:
        """Read up to ``n`` of the bytes the kernel holds into the ring at ``pos``; 0 if it
        holds none."""
        if self._fd is not None:
            try:
                # pyserial opens the port O_NONBLOCK (and VMIN 0): this returns what is
                # there, at once, 0 bytes if nothing
                return os.readv(self._fd, [self._view[pos:pos + n]])  # releases the GIL
            except BlockingIOError:
                return 0
        waiting = self._port.in_waiting
        data = self._port.read(min(n, waiting)) if waiting > 0 else b""
        self._ring[pos:pos + len(data)] = data
        return len(data)

    def _commit(self, n: int) -> asyncio.Future[None] | None:
        now = time.monotonic()
        with self._lock:
            self._written += n
            self._marks.append((self._written, now))
            held = self._written - self._taken
            self.peak = max(self.peak, held)
            if held >= self.limit:
                self._room.clear()
            waiter, self._waiter = self._waiter, None
        return waiter

    def _fail(self, err: BaseException) -> None:
        with self._lock:
            self._error = err

    def _end(self) -> asyncio.Future[None] | None:
        """Nothing more will be read; returns the waiting take to wake."""
        with self._lock:
            self._ended = True
            waiter, self._waiter = self._waiter, None
        return waiter

    def _wake(self, waiter: asyncio.Future[None] | None) -> None:
        if waiter is None:
            return
        try:
            self._loop.call_soon_threadsafe(resolve, waiter)
        except RuntimeError:  # the loop is closed: nobody is waiting any more
            pass

    # -- the event loop's side ----------------------------------------------------------------

    async def take(self) -> bytes:
        """The bytes read since the last call, oldest first, up to ``TAKE_LIMIT`` of them,
        waiting for at least one; ``b""`` once the
        reader has stopped.  Raises the thread's error (``SerialException``/``OSError``)
        after the bytes read before it.  Cancellation-safe: nothing is lost."""
        while True:
            with self._lock:
                if self._marks:
                    # whole reads, oldest first, up to TAKE_LIMIT bytes and never across the
                    # ring's end (a read never straddles it)
                    start = self._taken
                    pos = start % self.limit
                    end = start
                    marks = self._marks
                    while marks:
                        mark_end = marks[0][0]
                        if end > start and (mark_end - start > TAKE_LIMIT
                                            or (mark_end - start) + pos > self.limit):
                            break
                        end, self.arrival = marks.popleft()
                    piece = bytes(self._view[pos:pos + end - start])
                    self._taken = end
                    if (end - start and self._written - end < self.limit
                            and not self._room.is_set()):
                        self._room.set()
                        if self._fd is not None and not self._stopping and not self._ended:
                            self._watch()
                    return piece
                if self._error is not None:
                    err, self._error = self._error, None
                    raise err
                if self._ended:
                    return b""
                waiter = self._loop.create_future()
                self._waiter = waiter
            try:
                await waiter
            finally:
                with self._lock:
                    if self._waiter is waiter:
                        self._waiter = None

    def stop(self) -> None:
        """Stop reading (the read thread lets go within ~ms) and wake a pending :meth:`take`,
        which returns what was read and then ``b""``.  The port stays open: the caller closes
        it."""
        self._stopping = True
        self._room.set()
        if self._fd is not None:
            self._unwatch()
        if self._shared is not None:
            if not self._shared.remove(self, JOIN_TIMEOUT):
                log.warning("the read thread did not let go of %s within %g s",
                            self._port.port, JOIN_TIMEOUT)
            with self._lock:
                self._ended = True
        else:
            assert self._thread is not None
            try:
                self._port.cancel_read()
            except (OSError, serial.SerialException, AttributeError):
                pass  # the port is already closed: its read has failed or will
            self._thread.join(JOIN_TIMEOUT)
            if self._thread.is_alive():
                log.warning("reader thread of %s did not stop within %g s", self._port.port,
                            JOIN_TIMEOUT)
        with self._lock:
            waiter, self._waiter = self._waiter, None
        if waiter is not None:
            resolve(waiter)

    @property
    def held(self) -> int:
        """Bytes read and not yet taken by :meth:`take`, now."""
        return self._written - self._taken

    @property
    def alive(self) -> bool:
        """True while the port is read (until :meth:`stop` or its error)."""
        if self._fd is not None:
            return not self._ended and not self._stopping
        assert self._thread is not None
        return self._thread.is_alive()

"""A thread that empties a serial port's kernel buffer as soon as bytes arrive.

Why a thread, when asyncio can watch the descriptor (``loop.add_reader``)?  Because a tty
buffers little: a pseudo-terminal about 15 KB, a USB CDC-ACM port some 64 KB, that is 0.1 to
0.4 s of a finger streaming 1000 frames/s (152 KB/s).  Read in the event loop, every stall of
that loop longer than this loses frames at the device, and the loop also serves 50
WebSocket subscribers, runs garbage collection and waits for the CPU behind other processes:
the 10-minute soak (docs/reliability.md) saw it wake up to 1.5 s late and lose 1.5-4 % of
the frames on full ptys.  This thread does nothing but ``read``: it sleeps in ``select``
(without the GIL), is woken by the kernel as bytes arrive, takes the GIL for a few
microseconds to copy them into memory, and so drains the port whatever the loop is busy with
(it waits at most the interpreter's switch interval, 5 ms, for the GIL).  Decoding stays on
the loop, which takes everything read so far in one piece when it gets round to it.

The memory it holds is bounded (``limit`` bytes, 4 MiB by default: ~27 s of a 1 kHz
finger); at the limit it stops reading, so the kernel buffer fills and the device drops, as
it would with no thread at all.  What it holds goes to the loop in pieces of at most
``TAKE_LIMIT`` (64 KiB) per :meth:`PortReader.take`: after a stall of seconds the thread
holds a megabyte per port, and one piece that size, freed after decoding, left glibc's heap
grown by as much for good (its mmap threshold rises to the largest block freed, and the next
ones came from the heap: the service's RSS rose in steps with the long stalls of the 1-hour
soak, docs/reliability.md).  An error (the device unplugged) is handed to the consumer
after every byte read before it, so no good frame is lost to it.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections import deque

import serial

from tactiled_drivers.futures import resolve

log = logging.getLogger(__name__)

DEFAULT_LIMIT = 4 << 20  # bytes held before reading pauses
TAKE_LIMIT = 64 << 10  # bytes handed to the loop per take() (a larger read comes whole)
JOIN_TIMEOUT = 2.0  # seconds stop() waits for the thread


class PortReader:
    """Reads ``port`` in a thread of its own; :meth:`take` hands the bytes to the event loop.

    ``port`` must be open with ``timeout=None`` (blocking reads that :meth:`stop` interrupts
    with pyserial's ``cancel_read``).  Create it from the event loop's thread; :meth:`take`
    and :meth:`stop` are called from that thread too.
    """

    def __init__(self, port: serial.Serial, *, limit: int = DEFAULT_LIMIT) -> None:
        if limit < 1:
            raise ValueError(f"limit must be at least 1 byte, got {limit}")
        self._port = port
        self._loop = asyncio.get_running_loop()
        self.limit = limit
        self._lock = threading.Lock()
        self._chunks: deque[tuple[float, bytes]] = deque()  # (monotonic s read, bytes)
        self._held = 0
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
        self._thread = threading.Thread(target=self._run, daemon=True,
                                        name=f"tactiled-read {port.port}")
        self._thread.start()

    # -- the thread ---------------------------------------------------------------------------

    def _run(self) -> None:
        port = self._port
        try:
            while not self._stopping:
                if not self._room.is_set():  # at the limit: let the kernel buffer hold it
                    self._room.wait()
                    continue
                data = port.read(1)  # blocks in select() until a byte, or cancel_read()
                if not data:  # cancelled by stop()
                    continue
                waiting = port.in_waiting
                if waiting:
                    data += port.read(waiting)
                self._push(data)
        except (serial.SerialException, OSError) as err:  # the device went away
            if not self._stopping:
                self._fail(err)
        except Exception as err:  # a bug: report it to the consumer rather than die silently
            log.exception("reader of %s failed", port.port)
            self._fail(err)
        finally:
            self._finish()

    def _push(self, data: bytes) -> None:
        now = time.monotonic()
        with self._lock:
            self._chunks.append((now, data))
            self._held += len(data)
            self.peak = max(self.peak, self._held)
            if self._held >= self.limit:
                self._room.clear()
            waiter, self._waiter = self._waiter, None
        self._wake(waiter)

    def _fail(self, err: BaseException) -> None:
        with self._lock:
            self._error = err

    def _finish(self) -> None:
        with self._lock:
            self._ended = True
            waiter, self._waiter = self._waiter, None
        self._wake(waiter)

    def _wake(self, waiter: asyncio.Future[None] | None) -> None:
        if waiter is None:
            return
        try:
            self._loop.call_soon_threadsafe(resolve, waiter)
        except RuntimeError:  # the loop is closed: nobody is waiting any more
            pass

    # -- the event loop's side ----------------------------------------------------------------

    async def take(self) -> bytes:
        """The bytes read since the last call, oldest first, up to ``TAKE_LIMIT`` of them (a
        single read larger than that comes whole), waiting for at least one; ``b""`` once the
        reader has stopped.  Raises the thread's error (``SerialException``/``OSError``)
        after the bytes read before it.  Cancellation-safe: nothing is lost."""
        while True:
            with self._lock:
                if self._chunks:
                    pieces: list[bytes] = []
                    size = 0
                    chunks = self._chunks
                    while chunks and (not pieces or size + len(chunks[0][1]) <= TAKE_LIMIT):
                        self.arrival, piece = chunks.popleft()
                        pieces.append(piece)
                        size += len(piece)
                    self._held -= size
                    if self._held < self.limit:
                        self._room.set()
                    return pieces[0] if len(pieces) == 1 else b"".join(pieces)
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
        """End the thread (within ~ms) and wake a pending :meth:`take`, which returns what
        was read and then ``b""``.  The port stays open: the caller closes it."""
        self._stopping = True
        self._room.set()
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
        return self._held

    @property
    def alive(self) -> bool:
        """True while the thread runs."""
        return self._thread.is_alive()

"""The thread that stands guard over every serial port of the process (:class:`ReadThread`).

It looks at every port every ``GUARD_INTERVAL_S`` and reads, into the port's ring, any port the
event loop has not read for ``STALL_S``, so a held-up loop never leaves a device waiting.  The
loop itself does the reading otherwise.  A reader's reads are serialized by its read lock, so
its bytes keep their order.
"""
# Why a guard and not a reading thread: a PortReader with a descriptor is read by the loop
# (loop.add_reader) as soon as its port has bytes, with no thread in between.  The loop cannot
# read while held up (a long garbage collection, a CPU-starved process, an overrunning callback),
# and a pty buffers about 15 KB, 30 ms of a 16x16 palm at 1 kHz.  While the loop keeps up this
# thread reads nothing and takes the GIL 1 / GUARD_INTERVAL_S times a second whatever the number
# of ports.  A thread that read every port would take the GIL from the loop, wake it through its
# self-pipe at each wake, and let a frame wait up to its wake period in the kernel's buffer
# (docs/performance/hand.md).  An error (device unplugged) reaches the consumer after every byte
# read before it, whichever side read them.

from __future__ import annotations

import asyncio
import logging
import threading
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tactiled_drivers.plumbing.port_reader import PortReader

log = logging.getLogger(__name__)

#: The thread looks at the ports this often (s) ...
GUARD_INTERVAL_S = 0.004
#: ... and reads a port the event loop has not read for this long (s).
STALL_S = 0.004


def _resolve_all(futures: list[asyncio.Future[None]]) -> None:
    for f in futures:
        if not f.done():
            f.set_result(None)


class ReadThread:
    """Guards every registered port (see the module's doc).  A reader joins with
    :func:`register` and leaves with :meth:`remove` (from any thread).  The thread ends when
    its last port is removed (:func:`register` starts another)."""

    def __init__(self, interval: float = GUARD_INTERVAL_S) -> None:
        self.interval = interval
        self._lock = threading.Lock()
        self._readers: list[PortReader] = []
        self._exiting = False  # no port left: the thread has ended or is ending
        self._ending = threading.Event()
        #: times it looked at the ports, and ports it read because the loop had not
        self.wakes = 0
        self.drains = 0
        self._thread = threading.Thread(target=self._run, daemon=True, name="tactiled-read")
        self._thread.start()

    # -- any thread -----------------------------------------------------------------------------

    def add(self, reader: PortReader) -> bool:
        """Guard ``reader``'s port; False if the thread is ending (start another)."""
        with self._lock:
            if self._exiting:
                return False
            self._readers.append(reader)
        return True

    def remove(self, reader: PortReader, timeout: float) -> bool:
        """Stop guarding ``reader``'s port; True once the thread no longer touches it (False:
        a read of it did not end within ``timeout`` s)."""
        with self._lock:
            if reader in self._readers:
                self._readers.remove(reader)
            if not self._readers:
                self._exiting = True
                self._ending.set()
        if threading.current_thread() is self._thread:  # (a reader stopped by its own error)
            return True
        # a read of the port in progress holds its read lock: it is over once we get it
        if not reader.read_lock.acquire(timeout=timeout):
            return False
        reader.read_lock.release()
        if self._exiting:  # that was its last port: gone when this returns
            self._thread.join(timeout)
        return True

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    # -- the thread -----------------------------------------------------------------------------

    def _run(self) -> None:
        while not self._ending.wait(self.interval):
            with self._lock:
                readers = list(self._readers)
            self.wakes += 1
            now = time.monotonic()
            wake: dict[asyncio.AbstractEventLoop, list[asyncio.Future[None]]] = {}
            for reader in readers:
                if now - reader.last_read < STALL_S:
                    continue  # the loop keeps up with it
                try:
                    read, waiter = reader.guard_drain()
                except Exception as err:  # noqa: BLE001 (the device went away, or a bug)
                    self.remove(reader, 0.0)
                    read, waiter = 0, reader.failed(err)
                self.drains += read > 0
                if waiter is not None:
                    wake.setdefault(reader.loop, []).append(waiter)
            for loop, waiters in wake.items():
                try:
                    loop.call_soon_threadsafe(_resolve_all, waiters)
                except RuntimeError:  # the loop is closed: nobody is waiting any more
                    pass


_shared: ReadThread | None = None
_shared_lock = threading.Lock()


def register(reader: PortReader) -> ReadThread:
    """Guard ``reader``'s port in the process's read thread (starting it if none runs);
    returns the thread."""
    global _shared
    with _shared_lock:
        thread = _shared
        if thread is not None and not thread.alive and not thread._exiting:
            log.error("the serial read thread died: starting another")
        if thread is None or not thread.alive or not thread.add(reader):
            thread = _shared = ReadThread()
            thread.add(reader)
        return thread

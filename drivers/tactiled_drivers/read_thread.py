"""One thread that reads every serial port of the process (:class:`ReadThread`).

A :class:`~tactiled_drivers.port_reader.PortReader` with a file descriptor does not read in a
thread of its own: it registers with this thread, which sleeps in ``poll`` (without the GIL)
over every registered descriptor and, when any is readable, drains each ready port into its
reader's ring in one wake.  Then it waits until ``READ_INTERVAL_S`` has passed since that wake
began before it polls again.

Why one thread and an interval.  A hand is six arrays at 1 kHz: with a thread per port that
was 6000 wakes a second, each taking the GIL from the event loop for a few microseconds, and
each waking the loop through its self-pipe.  The handoffs, not the reads, were the cost (the
hand's runs against the code before this thread: docs/performance/hand.md).  One thread that
wakes at most every ``READ_INTERVAL_S`` takes the GIL at most 1000 times a second whatever the
number of ports, reads every port that has bytes in that wake, and wakes each event loop once
per wake.  The price is latency: a frame may wait
in the kernel's buffer up to ``READ_INTERVAL_S`` before it is read (and stamped: a frame's
``host_time`` is when it was read).

What does not change: the thread drains the ports whatever the loop is busy with, into rings
of bounded memory; a port whose ring is full is not polled until the loop takes from it (the
kernel buffer fills, and the device drops, as with no thread at all); an error reaches the
consumer after every byte read before it.
"""

from __future__ import annotations

import asyncio
import logging
import os
import select
import threading
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tactiled_drivers.port_reader import PortReader

log = logging.getLogger(__name__)

#: The thread polls again at least this long after a wake began (s): at most 1000 wakes a
#: second for every port together; a frame waits at most this long in the kernel's buffer.
READ_INTERVAL_S = 0.001

_READABLE = select.POLLIN | select.POLLPRI | select.POLLERR | select.POLLHUP


def _resolve_all(futures: list[asyncio.Future[None]]) -> None:
    for f in futures:
        if not f.done():
            f.set_result(None)


class ReadThread:
    """Reads every registered port (see the module's doc).  A reader joins with
    :func:`register`; :meth:`remove` and :meth:`resume` may be called from any thread.  The
    thread ends when its last port is removed (:func:`register` starts another)."""

    def __init__(self, interval: float = READ_INTERVAL_S) -> None:
        self.interval = interval
        self._lock = threading.Lock()
        #: requests for the thread: ("add" | "remove" | "resume", reader, done event or None)
        self._requests: list[tuple[str, PortReader, threading.Event | None]] = []
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._poll = select.poll()
        self._poll.register(self._wake_r, select.POLLIN)
        self._readers: dict[int, PortReader] = {}  # fd -> reader, polled or paused
        self._polled: set[int] = set()
        self._exiting = False  # no port left: the thread has ended or is ending
        #: wakes so far (each drained every ready port once)
        self.wakes = 0
        self._thread = threading.Thread(target=self._run, daemon=True, name="tactiled-read")
        self._thread.start()

    # -- any thread -----------------------------------------------------------------------------

    def resume(self, reader: PortReader) -> None:
        """``reader``'s ring has room again: poll its port again."""
        self._request("resume", reader, None)

    def remove(self, reader: PortReader, timeout: float) -> bool:
        """Stop reading ``reader``'s port; True once the thread no longer touches it (False:
        it did not answer within ``timeout`` s)."""
        if threading.current_thread() is self._thread:  # (a reader stopped by its own error)
            self._apply("remove", reader)
            return True
        done = threading.Event()
        if not self._request("remove", reader, done):
            return True  # the thread has ended: it reads nothing
        if not done.wait(timeout):
            return False
        if self._exiting:  # that was its last port: gone when this returns
            self._thread.join(timeout)
        return True

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def _request(self, what: str, reader: PortReader, done: threading.Event | None) -> bool:
        """Queue a request; False if the thread is ending (it reads no port any more)."""
        with self._lock:  # (the pipe is closed under it when the thread ends)
            if self._exiting:
                return False
            self._requests.append((what, reader, done))
            self._poke()
        return True

    def _poke(self) -> None:
        try:
            os.write(self._wake_w, b"\x00")
        except BlockingIOError:  # the pipe is full of wakes already: the thread will look
            pass

    # -- the thread -----------------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            events = self._wait()
            began = time.monotonic()
            self.wakes += 1
            wake: dict[asyncio.AbstractEventLoop, list[asyncio.Future[None]]] = {}
            for fd, _ev in events:
                if fd == self._wake_r:
                    if not self._take_requests():
                        with self._lock:
                            os.close(self._wake_r)
                            os.close(self._wake_w)
                        return  # no port left
                    continue
                reader = self._readers.get(fd)
                if reader is None or fd not in self._polled:
                    continue  # removed or paused by a request taken in this wake
                try:
                    waiter = reader.drain_ready()
                except Exception as err:  # noqa: BLE001 (the device went away, or a bug)
                    self._apply("remove", reader)
                    waiter = reader.failed(err)
                else:
                    if reader.full:
                        self._unpoll(fd)  # until take() makes room (resume)
                if waiter is not None:
                    wake.setdefault(reader.loop, []).append(waiter)
            for loop, waiters in wake.items():
                self._wake_loop(loop, waiters)
            self._pause(self.interval - (time.monotonic() - began))

    def _wait(self) -> list[tuple[int, int]]:
        """Sleep in ``poll`` (without the GIL) until a port has bytes or a request came."""
        return self._poll.poll()

    @staticmethod
    def _pause(seconds: float) -> None:
        """Sleep out the rest of the interval (the ports' bytes wait in the kernel)."""
        if seconds > 0.0:
            time.sleep(seconds)

    @staticmethod
    def _wake_loop(loop: asyncio.AbstractEventLoop, waiters: list[asyncio.Future[None]]) -> None:
        try:
            loop.call_soon_threadsafe(_resolve_all, waiters)
        except RuntimeError:  # the loop is closed: nobody is waiting any more
            pass

    def _take_requests(self) -> bool:
        """Apply the requests queued; False when no port is left (the thread ends)."""
        try:
            while os.read(self._wake_r, 4096):
                pass
        except BlockingIOError:
            pass
        with _shared_lock, self._lock:  # (register() cannot add a port meanwhile)
            requests, self._requests = self._requests, []
            for what, reader, _done in requests:
                self._apply(what, reader)
            self._exiting = not self._readers
        for _what, _reader, done in requests:
            if done is not None:
                done.set()
        return not self._exiting

    def _apply(self, what: str, reader: PortReader) -> None:
        fd = reader.fd
        if what == "add":
            self._readers[fd] = reader
            self._repoll(fd)
        elif what == "resume":
            if self._readers.get(fd) is reader and not reader.full:
                self._repoll(fd)
        elif self._readers.get(fd) is reader:  # remove
            self._unpoll(fd)
            del self._readers[fd]

    def _repoll(self, fd: int) -> None:
        if fd not in self._polled:
            self._poll.register(fd, _READABLE)
            self._polled.add(fd)

    def _unpoll(self, fd: int) -> None:
        if fd in self._polled:
            self._poll.unregister(fd)
            self._polled.discard(fd)


_shared: ReadThread | None = None
_shared_lock = threading.Lock()


def register(reader: PortReader) -> ReadThread:
    """Start reading ``reader``'s port in the process's read thread (starting it if none
    runs); returns the thread."""
    global _shared
    with _shared_lock:
        thread = _shared
        if thread is None or thread._exiting or not thread.alive:
            if thread is not None and not thread._exiting:
                log.error("the serial read thread died: starting another")
            thread = _shared = ReadThread()
        with thread._lock:
            thread._requests.append(("add", reader, None))
            thread._poke()
        return thread

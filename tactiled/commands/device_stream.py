"""Streaming a simulated device's frames: the pty it is reached by, a writer that never waits
on the device, and the loop that runs until SIGINT/SIGTERM.  Shared by ``tactiled simulate
--pty/--serial`` (:mod:`tactiled.commands.simulate`) and ``tactiled simulate --as``
(:mod:`tactiled.commands.simulate_as`).
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import tty
from collections.abc import Callable
from pathlib import Path

PENDING_LIMIT = 4096  # bytes held back when the device's buffer is full; beyond, frames drop
MAX_BATCH = 32  # frames written per wake-up when behind schedule
MAX_LAG_S = 1.0  # behind schedule by more than this (process starved): skip the stale frames

log = logging.getLogger(__name__)


class FrameWriter:
    """Writes encoded frames to a non-blocking device descriptor without ever waiting on it.

    A pty master with no reader, or a serial port slower than the stream, fills up; then up to
    :data:`PENDING_LIMIT` bytes are held back (so a frame cut by a partial write is finished,
    not garbled) and further frames are dropped and counted.  Write errors (EIO when a USB
    adapter is unplugged) are logged once and ride out the same way: the stream keeps its clock.
    """

    def __init__(self, fd: int, name: str) -> None:
        self.fd = fd
        self.name = name
        self.pending = bytearray()
        self.sent = 0  # frames queued for the device
        self.dropped = 0  # frames refused because the device was not taking them
        self.error = ""

    def send(self, data: bytes) -> None:
        if len(self.pending) >= PENDING_LIMIT:
            # A catch-up batch after a starved tick can exceed the limit on its own: offer
            # what is pending to the device first, and drop only if it really is full.
            self.flush()
        if len(self.pending) >= PENDING_LIMIT:
            self.dropped += 1
            return
        self.pending += data
        self.sent += 1

    def flush(self) -> None:
        while self.pending:
            try:
                n = os.write(self.fd, self.pending)
            except BlockingIOError:  # device buffer full: try again next tick
                return
            except InterruptedError:
                continue
            except OSError as err:
                if not self.error:
                    log.warning("writing to %s failed: %s; dropping frames until it recovers",
                                self.name, err)
                    print(f"tactiled simulate: {self.name}: {err}; dropping frames", file=sys.stderr)
                self.error = str(err)
                return
            if self.error:
                log.warning("%s is taking frames again", self.name)
                self.error = ""
            del self.pending[:n]


def make_pty(link: str | None) -> tuple[int, str]:
    """A pseudo-terminal in raw mode: ``(master fd, slave path)``; ``link`` points at it."""
    master, slave = os.openpty()
    try:
        tty.setraw(slave)  # no echo, no newline translation: binary frames pass untouched
        name = os.ttyname(slave)
    finally:
        os.close(slave)  # the reader opens its own; a master write with no reader just buffers
    os.set_blocking(master, False)
    if link:
        path = Path(link)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(name)
        tmp.replace(path)  # atomic: a reader never sees the link missing or half-made
    return master, name


def remove_link(link: str | None, target: str) -> None:
    """Remove ``link`` if it still points at ``target`` (another process may have re-pointed it)."""
    if link and os.path.islink(link) and os.readlink(link) == target:
        os.unlink(link)


def until_signal(serve: Callable[[list[int]], int]) -> int:
    """Run ``serve(stop)``, which streams until ``stop`` (a list SIGINT/SIGTERM append to) is
    non-empty.  Signals are caught first: whoever waits for the "pty:" line may stop us right
    after it."""
    stop: list[int] = []

    def on_signal(signum: int, _frame: object) -> None:
        stop.append(signum)

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        return serve(stop)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)

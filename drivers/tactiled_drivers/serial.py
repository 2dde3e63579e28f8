"""The fingertip on a serial port: ``serial:///dev/ttyACM0?baud=1000000``.

URL parameters: ``baud`` (bits/s, default 1000000; ignored by USB CDC-ACM devices and ptys),
``exclusive`` (default 1: an ``flock`` on the port so a second daemon cannot interleave reads).
Bytes are read as they arrive (:class:`~tactiled_drivers.plumbing.port_reader.PortReader`);
a vanishing device is closed and re-opened with backoff, at once when its node reappears.
POSIX only, which suits a daemon deployed with systemd and udev.
"""
# Reading: the event loop reads the port when it has bytes (loop.add_reader) into a bounded
# ring, and the process's read thread (tactiled_drivers.plumbing.read_thread) reads any port the
# loop has not read for a few milliseconds: a tty buffers 30 ms to 0.4 s of an array at 1 kHz,
# and the loop, which also serves the WebSocket subscribers, can stall longer under load.  The
# consumer awaits the bytes, so read timeouts and shutdown are ordinary cancellation.
#
# A vanishing device shows two ways: pyserial raises SerialException for EIO ("read failed"),
# or a descriptor polls readable but reads b"" (a Linux pty whose master closed, an unplugged
# USB serial adapter); OSError (e.g. EIO from the TIOCINQ ioctl behind in_waiting) is treated
# the same.  The reader hands the error over after the bytes read before it; the driver stops
# the reader, closes the port (its descriptor and pyserial's two abort pipes, so nothing leaks),
# sets connected = False and last_error, counts a disconnect, logs one warning and retries the
# same path with backoff: 0.1 s, doubling, capped at 2 s.  A re-open logs, counts a reconnect
# and resumes; the decoder's half-received frame is dropped.
#
# A device that comes back is tried at once: while waiting, the driver stats the device path
# every 50 ms, and when the node appears or changes (device number, inode, mode or owner:
# replugged, re-created by udev, given its permissions) the next attempt is immediate, so a
# device resumes within ~50 ms of its return.  No inotify: udev symlinks under /dev and ptys
# behind a symlink are covered alike.  retry_pause offers the same to the daemon, which retries
# a device absent at start-up.

from __future__ import annotations

import asyncio
import errno
import logging
import os
import time
from typing import ClassVar

import serial

from tactiled.errors import DeviceConnectionError
from tactiled.sources import FrameSource, Framer, SourceURL
from tactiled_drivers.plumbing.futures import resolve
from tactiled_drivers.plumbing.port_reader import PortReader

log = logging.getLogger(__name__)

DEFAULT_BAUD = 1_000_000


def _describe_open_error(path: str, err: serial.SerialException) -> str:
    """One clear line for a port that will not open."""
    code = err.errno
    if code in (errno.EAGAIN, errno.EWOULDBLOCK):
        return (f"serial port {path} is in use by another process "
                "(exclusive lock held; is another tactiled running?)")
    if code == errno.ENOENT:
        return f"serial port {path} does not exist (device unplugged?)"
    if code == errno.EACCES:
        return (f"permission denied opening serial port {path} "
                "(add the user to the dialout group or install the udev rule)")
    return f"cannot open serial port {path}: {err}"


class SerialSource(FrameSource):
    """Wire bytes from a serial device, surviving unplug/replug of the same path."""

    PARAMS: ClassVar[frozenset[str]] = frozenset({"baud", "exclusive"})
    #: Baud rate when the URL gives none (a vendor driver built on this one sets its own).
    DEFAULT_BAUD: ClassVar[int] = DEFAULT_BAUD

    #: Reconnect backoff, seconds: first retry after ``RETRY_MIN``, doubling to ``RETRY_MAX``.
    RETRY_MIN: ClassVar[float] = 0.1
    RETRY_MAX: ClassVar[float] = 2.0
    #: While waiting to retry, the device path is checked this often (seconds).
    WATCH_INTERVAL: ClassVar[float] = 0.05

    def __init__(self, url: str | SourceURL, *, decoder: Framer | None = None) -> None:
        super().__init__(url, decoder=decoder)
        if not self.url.location:
            raise ValueError(f"{self.url.url!r}: no device path; write e.g. "
                             "serial:///dev/ttyACM0")
        self.path: str = self.url.location
        self.baud: int = self.url.get_int("baud", self.DEFAULT_BAUD, minimum=1)
        self.exclusive: bool = self.url.get_bool("exclusive", True)
        self._port: serial.Serial | None = None
        self._reader: PortReader | None = None
        #: Most bytes the reader thread held for the loop at once, over every connection.
        self.read_backlog_peak = 0
        self._retry_delay = self.RETRY_MIN
        self._waiter: asyncio.Future[None] | None = None
        #: The device node as the latest open attempt saw it (see :meth:`_node`).
        self._node_at_attempt: tuple[int, ...] | None = None

    # -- open / close -----------------------------------------------------------------------

    def _node(self) -> tuple[int, ...] | None:
        """What identifies the device node behind the path now (None: no such path)."""
        try:
            st = os.stat(self.path)
        except (OSError, ValueError):
            return None
        return (st.st_dev, st.st_ino, st.st_rdev, st.st_mode, st.st_uid, st.st_gid)

    def _open_port(self) -> serial.Serial:
        self._node_at_attempt = self._node()
        # timeout=None: the reader thread's read() blocks until bytes arrive (stop() cancels
        # it); exclusive: flock(LOCK_EX | LOCK_NB), refused while another open file
        # description holds it, even in this process.
        try:
            return serial.Serial(self.path, baudrate=self.baud, timeout=None,
                                 exclusive=self.exclusive)
        except serial.SerialException as err:
            raise DeviceConnectionError(_describe_open_error(self.path, err)) from err
        except (OSError, ValueError) as err:  # e.g. termios on a non-tty, bad baud rate
            raise DeviceConnectionError(f"cannot open serial port {self.path}: {err}") from err

    def _attach(self, port: serial.Serial) -> None:
        self._port = port
        self._reader = PortReader(port)
        self._port_opened(port)

    def _port_opened(self, port: serial.Serial) -> None:
        """Called after every (re)open of the port, before any read: a device that must be
        told to start streaming (the Robotiq sensor's auto-send) is told here."""

    def _port_closing(self, port: serial.Serial) -> None:
        """Called before a deliberate close (not after an unplug): tell the device to stop."""

    async def _open_internal(self) -> None:
        self._attach(self._open_port())
        self._retry_delay = self.RETRY_MIN
        log.info("opened serial port %s at %d baud", self.path, self.baud)

    async def _close_internal(self) -> None:
        if self._port is not None:
            try:
                self._port_closing(self._port)
            except (OSError, serial.SerialException) as err:  # gone already: nothing to stop
                log.debug("stopping %s: %s", self.path, err)
        self._release_port()

    def _release_port(self) -> None:
        """Stop the reader thread, wake a pending read, and close the port."""
        reader, self._reader = self._reader, None
        if reader is not None:  # a read waiting in take() returns b"" and loops
            reader.stop()
            self.read_backlog_peak = max(self.read_backlog_peak, reader.peak)
        waiter, self._waiter = self._waiter, None
        if waiter is not None:  # a read waiting for the next retry: end it
            resolve(waiter)
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (OSError, serial.SerialException) as err:  # already gone: nothing to free
                log.debug("closing %s: %s", self.path, err)

    # -- reading ----------------------------------------------------------------------------

    async def _read_internal(self) -> bytes:
        while self.is_open:
            reader = self._reader
            if reader is None:
                await self._reconnect()
                continue
            try:
                data = await reader.take()
            except (serial.SerialException, OSError) as err:
                if self._reader is reader:
                    self._lost(err)
                continue
            if data:
                return data
            # b"": that reader was stopped (close, or replaced): look again
        return b""

    def _timestamp(self) -> float:
        # When the reader thread read the bytes, not when the loop took them: a frame's
        # latency then includes the time it waited for a busy loop.
        reader = self._reader
        return reader.arrival if reader is not None and reader.arrival else time.monotonic()

    @property
    def read_backlog_now(self) -> int:
        """Bytes the reader thread holds for the loop now."""
        reader = self._reader
        return reader.held if reader is not None else 0

    @property
    def read_backlog(self) -> int:
        """Most bytes read from the device but not yet taken by the loop, at once: how far
        the loop fell behind (bytes; 0 before the first read)."""
        live = self._reader.peak if self._reader is not None else 0
        return max(self.read_backlog_peak, live)

    async def retry_pause(self, delay: float) -> None:
        """Wait ``delay`` s before the next open attempt, or until the device node appears or
        changes since the last attempt (see the module docstring)."""
        await self._pause(delay, while_open=False)

    async def _pause(self, delay: float, *, while_open: bool) -> None:
        """Sleep ``delay`` s in ``WATCH_INTERVAL`` steps, returning early when the device node
        differs from what the latest open attempt saw, or (``while_open``) on :meth:`close`."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + delay
        while (left := deadline - loop.time()) > 0:
            await self._sleep(min(left, self.WATCH_INTERVAL))
            if while_open and not self.is_open:
                return
            node = self._node()
            if node is not None and node != self._node_at_attempt:
                return

    async def _sleep(self, delay: float) -> None:
        """Sleep ``delay`` seconds, or less if :meth:`close` wakes us (via ``_waiter``)."""
        loop = asyncio.get_running_loop()
        waiter: asyncio.Future[None] = loop.create_future()
        handle = loop.call_later(delay, resolve, waiter)
        self._waiter = waiter
        try:
            await waiter
        finally:
            handle.cancel()
            if self._waiter is waiter:
                self._waiter = None

    def _lost(self, err: BaseException) -> None:
        """The device vanished: report it once, free the port, start retrying."""
        self._release_port()
        self.connected = False
        self.disconnects += 1
        self.last_error = f"serial port {self.path} lost: {err}"
        self._retry_delay = self.RETRY_MIN
        log.warning("%s; retrying every %.1f..%.1f s", self.last_error,
                    self.RETRY_MIN, self.RETRY_MAX)

    async def _reconnect(self) -> None:
        """Wait one backoff step (less if the device reappears) and try to re-open once."""
        delay = self._retry_delay
        await self._pause(delay, while_open=True)
        if not self.is_open or self._port is not None:
            return
        try:
            port = self._open_port()
        except DeviceConnectionError as err:
            self._retry_delay = min(delay * 2.0, self.RETRY_MAX)
            if str(err) != self.last_error:
                log.info("%s", err)
            self.last_error = str(err)
            return
        self._attach(port)
        self._retry_delay = self.RETRY_MIN
        self.connected = True
        self.reconnects += 1
        # Bytes of a frame cut by the unplug must not be glued to the first bytes of the new
        # connection, and a replugged device may have restarted its sequence count.
        self.decoder.reset()
        log.warning("serial port %s is back (reconnect %d)", self.path, self.reconnects)

"""The systemd notification protocol (sd_notify(3)), without libsystemd."""

# A notification is one datagram to the ``AF_UNIX`` socket named by ``$NOTIFY_SOCKET``: an
# absolute path, or a Linux abstract-namespace name when it starts with ``@`` (the ``@`` becomes a
# leading NUL byte).  The payload is newline-separated ``NAME=value`` assignments with no
# trailing newline (``READY=1``, ``STATUS=...``, ``STOPPING=1``, ``WATCHDOG=1``).  Outside systemd
# the variable is unset and every call is a no-op, so the daemon calls these unconditionally.
#
# Watchdog: with ``WatchdogSec=`` systemd passes ``$WATCHDOG_USEC`` and ``$WATCHDOG_PID`` (the
# main process).  A process whose pid is not ``$WATCHDOG_PID`` (a child that inherited the
# environment) must not ping; the recommended ping period is half the timeout
# (sd_watchdog_enabled(3)).  systemd arms the watchdog when start-up completes (READY=1).
#
# Use in ``tactiled run``::
#
#     notifier = Notifier.from_env(unset_environment=True)   # before fit workers start
#     interval = watchdog_interval(unset_environment=True)
#     ...  # bind the port
#     notifier.ready(status="serving on 127.0.0.1:8765")
#     if interval is not None:
#         tasks.add(asyncio.create_task(watchdog_loop(notifier, WatchdogGate(progress), interval)))
#     ...  # on SIGTERM
#     notifier.stopping()

from __future__ import annotations

import asyncio
import logging
import os
import re
import socket
import threading
import time
from collections.abc import Callable, Mapping, MutableMapping

log = logging.getLogger(__name__)

#: systemd reads a notification into a buffer of this many bytes and drops longer ones.
MAX_DATAGRAM = 4096
#: STATUS= text is cut to this many characters (it is a one-line summary for systemctl status).
MAX_STATUS = 1024

_FIELD_RE = re.compile(r"^[A-Z_][A-Z0-9_]*$")
_USEC_INFINITY = 2**64 - 1  # systemd's "not set" timestamp


def _address(value: str) -> str | None:
    """``$NOTIFY_SOCKET`` as a Python AF_UNIX address; None if it is not a form we support
    (systemd also accepts ``vsock:``, which needs AF_VSOCK and only occurs inside VMs)."""
    if value.startswith("@"):
        return "\0" + value[1:]
    if value.startswith("/"):
        return value
    return None


def _format(fields: Mapping[str, object]) -> bytes:
    parts = []
    for name, value in fields.items():
        if not _FIELD_RE.match(name):
            raise ValueError(f"sd_notify field name {name!r}: must be upper case, e.g. READY")
        text = ("1" if value else "0") if isinstance(value, bool) else str(value)
        if "\n" in text or "\0" in text:
            raise ValueError(f"sd_notify field {name}: value must be one line, got {text!r}")
        parts.append(f"{name}={text}")
    if not parts:
        raise ValueError("sd_notify: no fields to send")
    data = "\n".join(parts).encode()
    if len(data) > MAX_DATAGRAM:
        raise ValueError(f"sd_notify: message of {len(data)} bytes exceeds {MAX_DATAGRAM}")
    return data


class Notifier:
    """Sends notifications to the service manager; a no-op without ``$NOTIFY_SOCKET``.

    Sending never raises: a failure (socket gone, queue full, unsupported address) is logged
    at WARNING once per run of failures and counted in :attr:`failures`; :attr:`sent` counts
    successes.  Bad field names or multi-line values are programming errors (``ValueError``).
    Thread-safe.
    """

    def __init__(self, notify_socket: str | None) -> None:
        #: ``$NOTIFY_SOCKET`` as given (None: notifications are disabled).
        self.notify_socket = notify_socket or None
        self.sent = 0
        self.failures = 0
        self._address = _address(self.notify_socket) if self.notify_socket else None
        self._sock: socket.socket | None = None
        self._lock = threading.Lock()
        self._failing = False

    @classmethod
    def from_env(cls, env: MutableMapping[str, str] = os.environ, *,
                 unset_environment: bool = False) -> Notifier:
        """The notifier for ``env["NOTIFY_SOCKET"]``.  ``unset_environment``: remove the
        variable from ``env`` (as sd_notify's flag does), so child processes -- the fit
        workers -- do not inherit it."""
        value = env.get("NOTIFY_SOCKET")
        if unset_environment:
            env.pop("NOTIFY_SOCKET", None)
        return cls(value)

    @property
    def enabled(self) -> bool:
        """True when running under a service manager that listens (``$NOTIFY_SOCKET`` set)."""
        return self.notify_socket is not None

    def send(self, **fields: object) -> bool:
        """Send ``NAME=value`` fields in one datagram (``send(READY=1, STATUS="up")``).
        True if it was sent; False if disabled or it failed."""
        data = _format(fields)
        if self.notify_socket is None:
            return False
        with self._lock:
            try:
                if self._address is None:
                    raise OSError(f"unsupported NOTIFY_SOCKET address {self.notify_socket!r}")
                if self._sock is None:
                    # Non-blocking: a busy service manager must never stall the event loop.
                    self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
                    self._sock.setblocking(False)
                self._sock.sendto(data, self._address)
            except OSError as err:
                self.failures += 1
                if not self._failing:
                    self._failing = True
                    log.warning("systemd notification to %s failed (further failures are "
                                "counted, not logged): %s", self.notify_socket, err)
                return False
            self._failing = False
            self.sent += 1
            return True

    def ready(self, status: str | None = None) -> bool:
        """Start-up is complete (READY=1); with Type=notify, ``systemctl start`` returns now."""
        return self.send(READY=1) if status is None else self.send(READY=1, STATUS=_line(status))

    def status(self, text: str) -> bool:
        """A one-line status shown by ``systemctl status`` (newlines become spaces)."""
        return self.send(STATUS=_line(text))

    def stopping(self, status: str | None = None) -> bool:
        """Shutdown has begun (STOPPING=1)."""
        return (self.send(STOPPING=1) if status is None
                else self.send(STOPPING=1, STATUS=_line(status)))

    def reloading(self) -> bool:
        """A configuration reload has begun (RELOADING=1 with MONOTONIC_USEC, as
        Type=notify-reload requires); send :meth:`ready` when it is done."""
        return self.send(RELOADING=1, MONOTONIC_USEC=time.monotonic_ns() // 1000)

    def watchdog(self) -> bool:
        """Keep-alive ping (WATCHDOG=1)."""
        return self.send(WATCHDOG=1)

    def extend_timeout(self, seconds: float) -> bool:
        """Ask for ``seconds`` more to finish start-up or shutdown (EXTEND_TIMEOUT_USEC)."""
        return self.send(EXTEND_TIMEOUT_USEC=max(0, int(seconds * 1e6)))

    def close(self) -> None:
        """Close the socket (sending later reopens it)."""
        with self._lock:
            if self._sock is not None:
                self._sock.close()
                self._sock = None


def _line(text: str) -> str:
    return " ".join(str(text).replace("\0", " ").split())[:MAX_STATUS]


def watchdog_interval(env: MutableMapping[str, str] = os.environ, *,
                      unset_environment: bool = False) -> float | None:
    """Seconds between WATCHDOG=1 pings: half of ``$WATCHDOG_USEC``.

    None when the watchdog is off: ``WATCHDOG_USEC`` unset, not a positive integer (or
    systemd's infinity), or ``WATCHDOG_PID`` set to another process (we inherited the
    variables).  ``unset_environment`` removes both variables from ``env``.
    """
    usec_text = env.get("WATCHDOG_USEC")
    pid_text = env.get("WATCHDOG_PID")
    if unset_environment:
        env.pop("WATCHDOG_USEC", None)
        env.pop("WATCHDOG_PID", None)
    if usec_text is None:
        return None
    try:
        usec = int(usec_text, 10)
    except ValueError:
        log.warning("ignoring WATCHDOG_USEC=%r: not an integer", usec_text)
        return None
    if usec <= 0 or usec >= _USEC_INFINITY:
        return None
    if pid_text is not None:
        try:
            pid = int(pid_text, 10)
        except ValueError:
            log.warning("ignoring the watchdog: WATCHDOG_PID=%r is not a pid", pid_text)
            return None
        if pid != os.getpid():
            return None
    return usec / 2e6


class WatchdogGate:
    """Lets a watchdog ping through only if the pipeline made progress since the last one.

    ``progress`` returns a counter that moves while work gets done (frames read, fits
    finished); a ping is :meth:`due` only when it differs from its value at the previous ping
    (or at construction).  A wedged pipeline thus stops the pings although the event loop that
    sends them still runs, and systemd restarts the daemon.
    """

    def __init__(self, progress: Callable[[], int]) -> None:
        self._progress = progress
        self._last = progress()
        #: Consecutive checks without progress (0 right after a ping).
        self.stalled_checks = 0

    def due(self) -> bool:
        """True (and remember the counter) if it changed since the last ping."""
        now = self._progress()
        if now == self._last:
            self.stalled_checks += 1
            return False
        self._last = now
        self.stalled_checks = 0
        return True


async def watchdog_loop(notifier: Notifier, gate: WatchdogGate, interval: float) -> None:
    """Every ``interval`` seconds send WATCHDOG=1 if ``gate`` says progress was made; runs
    until cancelled.  Logs once when it starts withholding pings."""
    while True:
        await asyncio.sleep(interval)
        try:
            due = gate.due()
        except Exception:  # a broken progress probe is no evidence of progress; keep looping
            log.exception("watchdog progress probe failed; withholding the ping")
            continue
        if due:
            notifier.watchdog()
        elif gate.stalled_checks == 1:
            log.warning("pipeline made no progress for %.1f s: withholding the systemd "
                        "watchdog ping (systemd restarts the daemon if this goes on)", interval)

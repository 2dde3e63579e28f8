"""Tunables of the service that are not part of ``tactiled.settings`` (limits, timeouts).

``tactiled run`` fills the few that have flags (``--max-subscribers``, ``--allow-origin``);
tests shrink the timeouts.  All times are in seconds, sizes in bytes.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ServiceOptions:
    """Limits and timeouts of the REST/WebSocket service."""

    #: WebSocket connections to /v1/stream accepted at once; one more is closed with 1013.
    max_subscribers: int = 64
    #: Items a subscriber may fall behind before the oldest are dropped (and counted).
    queue_size: int = 256
    #: A send that cannot complete within this (the peer stopped reading) closes it with 1013.
    send_timeout_s: float = 2.0
    #: Largest incoming WebSocket message; beyond it the connection is closed with 1009.
    max_message_bytes: int = 64 * 1024
    #: How long a closing handshake may take before the connection is cut (also how long the
    #: close frame of a stalled subscriber waits behind its backlog before the socket is
    #: aborted).
    close_timeout_s: float = 2.0
    #: TCP_USER_TIMEOUT of every accepted socket: the kernel gives up on a connection whose
    #: data stays unacknowledged this long (a peer that stopped reading), so an aborted
    #: socket cannot linger as an orphan.
    tcp_user_timeout_s: float = 10.0
    #: SO_SNDBUF of every accepted socket (bytes; the kernel doubles it; 0: its autotuning).
    #: Bounds what a subscriber that stopped reading can hold in kernel memory (autotuning
    #: would let it take megabytes, on loopback especially) and so how much is sent to it
    #: before it is noticed; a reading subscriber, even over a network, needs far less.
    socket_send_buffer: int = 128 * 1024
    #: A connection must deliver its request's headers within this long (from opening, or
    #: from the previous answer), and a request body the endpoint reads within this long from
    #: its headers; else 408 and the connection closes (slow-drip clients).
    read_timeout_s: float = 10.0
    #: Browser origins allowed to open the stream besides the server's own (same-origin).
    allowed_origins: tuple[str, ...] = ()
    #: A connected sensor with no frame for this long is ERROR ("silent").
    silent_after_s: float = 0.5
    #: A sensor whose frames arrive but whose last estimate is older than this is STALE.
    stale_after_s: float = 1.0
    #: Counter increases (CRC errors, lost frames, worker restarts...) within this window
    #: make a sensor WARN.
    warn_window_s: float = 10.0
    #: After start, a sensor may take this long to deliver its first frame before it is ERROR.
    startup_grace_s: float = 3.0
    #: Graceful shutdown budget; the process exits by then whatever is left.
    shutdown_timeout_s: float = 4.5
    #: Maximum messages per second per sensor and stream a client may ask for (``max_rate``).
    max_rate_hz: float = 1000.0

    def __post_init__(self) -> None:
        if isinstance(self.socket_send_buffer, bool) or not isinstance(
                self.socket_send_buffer, int) or self.socket_send_buffer < 0:
            raise ValueError("socket_send_buffer must be a byte count >= 0, got "
                             f"{self.socket_send_buffer!r}")
        for name in ("max_subscribers", "queue_size", "max_message_bytes"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        for name in ("send_timeout_s", "close_timeout_s", "tcp_user_timeout_s", "read_timeout_s",
                     "silent_after_s", "stale_after_s", "warn_window_s", "shutdown_timeout_s",
                     "max_rate_hz"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value > 0):
                raise ValueError(f"{name} must be a positive number of seconds, got {value!r}")

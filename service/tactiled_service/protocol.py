"""uvicorn's WebSocket protocol, plus a way to close a connection whose peer stopped reading
and a faster way to send many messages; and uvicorn's h11 HTTP protocol with a read deadline
(:func:`http_protocol_class`).
"""
# Why a forced close: ASGI can only close a WebSocket by send({"type": "websocket.close"}), and
# uvicorn makes every send wait until the transport is writable again, which it never is when
# the peer has stopped reading: the close would wait for ever.  This subclass hands the app, as
# the scope extension FORCE_CLOSE, a function that queues the close frame behind the backlog
# without waiting, closes the transport (it still flushes if the peer resumes reading), and
# linger seconds later resets the connection (SO_LINGER 0: RST, nothing left in the kernel).
# Connections that end otherwise are bounded by the listening socket's TCP_USER_TIMEOUT (see
# tactiled_service.server).
# Why a read deadline: uvicorn's keep-alive timeout only runs between requests, and any byte
# resets it.  A connection must deliver its request's headers within read_timeout of opening, or
# of the end of the previous response, or it is answered 408 (if it sent anything) and closed;
# a client still sending a body after its answer (413, 401, a body the endpoint does not read)
# is disconnected rather than read to the end.  A body the endpoint reads has its own deadline
# (tactiled_service.inbound.read_body).

from __future__ import annotations

import asyncio
import socket
import struct
from typing import Any

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol
from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol

from tactiled_service.inbound import HttpStats

#: Scope extension: ``scope["extensions"][FORCE_CLOSE]["close"](code, reason, linger_s)``;
#: ``...["closing"]()`` is True once the transport is closing or lost (writes would be
#: dropped); ``...["write_texts"](texts)`` and ``...["writable"]`` (an ``asyncio.Event``) are
#: the fan-out's fast path.
FORCE_CLOSE = "tactiled.force_close"


def protocol_class(close_timeout: float) -> type[asyncio.Protocol]:
    """The protocol class to give uvicorn (``Config(ws=...)``), with its closing handshake
    limited to ``close_timeout`` seconds (uvicorn's default is 10)."""

    class StreamProtocol(WebSocketsSansIOProtocol):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self.close_timeout = close_timeout

        def handle_connect(self, event: Any) -> None:
            super().handle_connect(event)
            scope = getattr(self, "scope", None)
            if scope is not None and not self.close_sent:
                scope["extensions"][FORCE_CLOSE] = {
                    "close": self.force_close,
                    "closing": self.transport.is_closing,
                    "write_texts": self.write_texts,
                    "writable": self.writable,
                }

        async def send(self, message: Any) -> None:
            await super().send(message)
            if (message["type"] == "websocket.http.response.body"
                    and not message.get("more_body", False)):
                # A refused handshake is complete: without this uvicorn logs an error
                # ("returned without completing handshake") for every refusal.
                self.handshake_complete = True

        def write_texts(self, texts: list[str]) -> bool:
            """Frame ``texts`` and hand them to the transport in one write, now; False (nothing
            written) while the transport is over its high-water mark (wait for ``writable``).

            The fan-out's fast path: one call and one syscall per batch instead of one ASGI
            send per message.  Raises ``ConnectionResetError`` once the connection is closing.
            """
            if self.close_sent or self.disconnected or self.transport.is_closing():
                raise ConnectionResetError("connection closing")
            if not self.writable.is_set():
                return False
            try:
                for text in texts:
                    self.conn.send_text(text.encode())
            except Exception as err:  # the protocol state no longer allows data
                raise ConnectionResetError(str(err)) from err
            self.transport.write(b"".join(self.conn.data_to_send()))
            return True

        def force_close(self, code: int, reason: str, linger: float) -> None:
            """Queue a close frame without waiting for the transport, then cut the connection
            after ``linger`` seconds at most (s)."""
            if self.disconnected or self.transport.is_closing():
                return
            self.stop_keepalive()
            if not self.close_sent:
                try:
                    self.conn.send_close(code, reason)
                    self.transport.write(b"".join(self.conn.data_to_send()))
                except Exception:  # the protocol state forbids it: just cut
                    pass
                self.close_sent = True
                self.queue.put_nowait({"type": "websocket.disconnect", "code": code,
                                       "reason": reason})
            # close() still delivers the backlog and the close frame to a peer that resumes
            # reading; the reset is the bound for one that never does.
            self.transport.close()
            self.loop.call_later(linger, self.reset)

        def reset(self) -> None:
            """Cut the connection with a TCP reset if it is still flushing: no FIN_WAIT orphan
            keeps the unread backlog in kernel memory, and the peer learns at once."""
            if self.disconnected:
                return
            sock = self.transport.get_extra_info("socket")
            if sock is not None:
                try:
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                except OSError:
                    pass
            self.transport.abort()

    StreamProtocol.__name__ = StreamProtocol.__qualname__ = "StreamProtocol"
    return StreamProtocol


def _timeout_response(read_timeout: float) -> bytes:
    body = (f'{{"detail":"request not received within {read_timeout:g} s '
            f'(server.read_timeout)"}}').encode()
    return (b"HTTP/1.1 408 Request Timeout\r\ncontent-type: application/json\r\n"
            b"content-length: " + str(len(body)).encode() + b"\r\nconnection: close\r\n\r\n"
            + body)


def http_protocol_class(read_timeout: float,
                        stats: HttpStats | None = None) -> type[asyncio.Protocol]:
    """The HTTP protocol class to give uvicorn (``Config(http=...)``): h11 with the request
    read deadline of the module docstring, ``read_timeout`` seconds; timeouts are counted and
    logged (at most once a minute) by ``stats``."""

    class HttpProtocol(H11Protocol):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self._read_deadline: asyncio.TimerHandle | None = None

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            self._arm()

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm()
            super().connection_lost(exc)

        def _arm(self) -> None:
            self._disarm()
            self._read_deadline = self.loop.call_later(read_timeout, self._timed_out)

        def _disarm(self) -> None:
            if self._read_deadline is not None:
                self._read_deadline.cancel()
                self._read_deadline = None

        def handle_events(self) -> None:
            super().handle_events()
            if self.conn.their_state is not h11.IDLE:  # the headers are in (or an upgrade)
                self._disarm()

        def on_response_complete(self) -> None:
            unread_body = self.conn.their_state is h11.SEND_BODY
            super().on_response_complete()
            if self.transport.is_closing():
                return
            if unread_body:
                # Answered while the client still sends: reading a body nobody wants (150 MB,
                # or a byte a second) would only cost time; the answer is already out.
                self.transport.close()
            elif self.conn.their_state is h11.IDLE:
                self._arm()

        def _timed_out(self) -> None:
            self._read_deadline = None
            if self.transport.is_closing() or self.conn.their_state is not h11.IDLE:
                return
            started = bool(self.conn.trailing_data[0])
            if stats is not None:
                peer = "%s:%d" % self.client if self.client else "?"
                stats.timed_out(peer, "its request's headers" if started else "a request",
                                read_timeout)
            if started:
                self.transport.write(_timeout_response(read_timeout))
            self.transport.close()

    HttpProtocol.__name__ = HttpProtocol.__qualname__ = "HttpProtocol"
    return HttpProtocol

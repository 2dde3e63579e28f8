"""uvicorn's WebSocket protocol, plus a way to close a connection whose peer stopped reading
and a faster way to send many messages.

ASGI can only close a WebSocket by ``send({"type": "websocket.close"})``, and uvicorn makes
every send wait until the transport is writable again, which it never is when the peer has
stopped reading: the close would wait for ever.  This subclass hands the app, as the scope
extension :data:`FORCE_CLOSE`, a function that queues the close frame behind the backlog
without waiting, closes the transport (it still flushes if the peer resumes reading), and
``linger`` seconds later resets the connection (SO_LINGER 0: RST, nothing left in the kernel).
Connections that end otherwise are bounded by the listening socket's TCP_USER_TIMEOUT (see
:mod:`tactiled_service.server`).
"""

from __future__ import annotations

import asyncio
import socket
import struct
from typing import Any

from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol

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

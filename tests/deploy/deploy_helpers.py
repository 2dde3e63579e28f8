"""Helpers for tests/deploy: a stand-in for systemd's notification socket, a real AF_UNIX
datagram socket that records each message with the sender's pid (SO_PASSCRED: systemd uses the
sender's credentials to enforce NotifyAccess=)."""

from __future__ import annotations

import socket
import struct
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


@dataclass
class Message:
    data: bytes
    pid: int | None  # sender pid from SCM_CREDENTIALS
    at: float  # time.monotonic() when received


class NotifySocket:
    """Bound to a path or an abstract name; ``address`` is what goes into $NOTIFY_SOCKET."""

    def __init__(self, address: str) -> None:
        self.address = address
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_PASSCRED, 1)
        self.sock.bind("\0" + address[1:] if address.startswith("@") else address)

    def recv(self, timeout: float = 2.0) -> Message | None:
        """The next message, or None after ``timeout`` seconds."""
        self.sock.settimeout(timeout)
        try:
            data, anc, _flags, _addr = self.sock.recvmsg(4096, socket.CMSG_SPACE(12))
        except (TimeoutError, socket.timeout):
            return None
        pid = None
        for level, kind, payload in anc:
            if level == socket.SOL_SOCKET and kind == socket.SCM_CREDENTIALS:
                pid, _uid, _gid = struct.unpack("iII", payload[:12])
        return Message(data, pid, time.monotonic())

    def close(self) -> None:
        self.sock.close()

"""What clients send: one JSON decoder for every request body and WebSocket message, request
bodies read within their size limit and deadline, and the HTTP counters ``/metrics`` shows.

:func:`decode_json` is the one path from a client's bytes to Python values: it refuses, with a
:class:`BadJson` naming the key, what the daemon could not represent or echo back.
:func:`read_body` answers 413 the moment a body passes its limit and 408 past its deadline.
"""
# decode_json refuses: bytes that are not UTF-8; a lone UTF-16 surrogate ("\ud800": a legal
# JSON escape, but not Unicode, so no UTF-8 encoder can write it back); NaN, Infinity, -Infinity
# (not JSON, though Python's parser takes them) and numbers beyond a double (1e999); integers
# longer than Python's int-string limit (4300 digits: converting one raises); nesting deeper than
# MAX_DEPTH.  Whatever it echoes goes through shown (repr: a surrogate or control character comes
# out as its escape), so the reply always encodes.
# read_body counts a body's bytes as they arrive and answers 413 without reading the rest (the
# connection then closes), so a chunked body with no Content-Length costs at most the limit; a
# body not in within timeout_s is 408.  A client that leaves mid-body raises ClientGone:
# counted, logged at most once a minute (HttpStats), never a traceback.

from __future__ import annotations

import asyncio
import json
import logging
import math
import re
import sys
import time
from collections.abc import Iterator
from typing import Any

from starlette.exceptions import HTTPException
from starlette.requests import ClientDisconnect, Request

log = logging.getLogger(__name__)

#: Deepest nesting of objects and arrays accepted (a config patch needs 3).
MAX_DEPTH = 64
#: Longest integer literal accepted, digits: Python's int-string limit (``int()`` of a longer
#: one raises ValueError), 4300 unless the interpreter was told otherwise.
MAX_INT_DIGITS = sys.get_int_max_str_digits() or 4300
#: A log line about clients that went away (or dripped bytes) at most this often, s.
LOG_EVERY_S = 60.0
#: Response headers that end the connection after a refusal whose body was not read whole.
CLOSE = {"Connection": "close"}

_BARE_KEY = re.compile(r"[A-Za-z0-9_.\-]{1,64}")


def shown(text: str, limit: int = 40) -> str:
    """``text`` quoted for an error message or a log line, ``repr``-escaped (a lone surrogate
    or a control character appears as its escape, so the message always encodes) and
    shortened to ``limit`` characters."""
    return repr(text if len(text) <= limit else text[:limit] + "...")


def encodable(text: str) -> str:
    """``text`` with anything UTF-8 cannot encode (lone surrogates) written as its escape:
    the last guard of every error reply."""
    return text.encode("utf-8", "backslashreplace").decode("utf-8")


class BadJson(ValueError):
    """Client JSON refused: ``where`` (the key path, or the root's name) and ``problem``;
    ``str()`` is ``"where: problem"``."""

    def __init__(self, where: str, problem: str) -> None:
        super().__init__(f"{where}: {problem}")
        self.where = where
        self.problem = problem


class _Refused:
    """A number the parser met but refuses: reported with its key once the key is known."""

    __slots__ = ("problem",)

    def __init__(self, problem: str) -> None:
        self.problem = problem


def _constant(name: str) -> _Refused:
    return _Refused(f"{name} is not a JSON number (numbers must be finite)")


def _integer(text: str) -> int | _Refused:
    digits = len(text) - text.startswith("-")
    if digits > MAX_INT_DIGITS:
        return _Refused(f"an integer of {digits} digits (at most {MAX_INT_DIGITS})")
    return int(text)


def _real(text: str) -> float | _Refused:
    value = float(text)
    if not math.isfinite(value):
        return _Refused(f"{shown(text, 24)} is beyond the range of a double (numbers must be "
                        "finite)")
    return value


def _real_or_integer(text: str) -> int | float | _Refused:
    """A number written with a fraction or exponent, as an int when integral: JSON has one
    number type and JSON Schema's ``integer`` includes ``185.0``, so a ``window`` of 185.0 is
    185 (the daemon's checks want an int there, and take ints for float keys)."""
    value = _real(text)
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value


def _path(parts: tuple[str | int, ...], root: str) -> str:
    """``sensors.finger0.window`` (keys of other characters quoted by :func:`shown`); the
    root's name for the value itself."""
    if not parts:
        return root
    return ".".join(str(p) if isinstance(p, int) or _BARE_KEY.fullmatch(p) else shown(p)
                    for p in parts)


def _surrogate(text: str) -> str | None:
    """The first lone surrogate of ``text`` as its escape, or None."""
    if text.isascii():
        return None
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as err:
        return f"\\u{ord(text[err.start]):04x}"
    return None


def _walk(value: Any, root: str) -> Iterator[tuple[tuple[str | int, ...], Any, bool]]:
    """``(path, item, is_key)`` for every key and value under ``value``, depth first in
    document order; :class:`BadJson` past :data:`MAX_DEPTH`."""
    stack: list[tuple[tuple[str | int, ...], Any]] = [((), value)]
    while stack:
        path, node = stack.pop()
        yield path, node, False
        if isinstance(node, (dict, list)):
            if len(path) >= MAX_DEPTH:
                raise BadJson(root, f"nested deeper than {MAX_DEPTH} levels")
            if isinstance(node, dict):
                children = list(node.items())
                for key, _ in children:
                    yield path, key, True
            else:
                children = list(enumerate(node))
            stack.extend((path + (k,), v) for k, v in reversed(children))


def decode_json(data: bytes | str, root: str = "body", *, integral_floats: bool = False) -> Any:
    """The value of the JSON text ``data`` (bytes must be UTF-8); :class:`BadJson` for
    anything the module docstring lists, naming the key where it sits (``root`` when it is
    the value itself, or the text is not JSON at all).

    ``integral_floats``: a number written with a fraction or exponent that is whole (``4.0``,
    ``1e3``) is an int (the config keys' schema).
    """
    if isinstance(data, (bytes, bytearray)):
        try:
            text = bytes(data).decode("utf-8")
        except UnicodeDecodeError as err:
            raise BadJson(root, f"not UTF-8: byte 0x{data[err.start]:02x} at offset "
                                f"{err.start}") from None
    else:
        text = data
    try:
        value = json.loads(text, parse_constant=_constant, parse_int=_integer,
                           parse_float=_real_or_integer if integral_floats else _real)
    except json.JSONDecodeError as err:
        raise BadJson(root, f"not valid JSON: {err.msg} at line {err.lineno} column "
                            f"{err.colno}") from None
    except RecursionError:
        raise BadJson(root, "not valid JSON: nested too deeply") from None
    for path, item, is_key in _walk(value, root):
        if isinstance(item, _Refused):
            raise BadJson(_path(path, root), item.problem)
        if isinstance(item, str):
            bad = _surrogate(item)
            if bad is not None:
                what = f"the key {shown(item)}" if is_key else shown(item)
                raise BadJson(_path(path, root), f"{what} holds a lone UTF-16 surrogate "
                                                 f"({bad}), which is not Unicode text")
    return value


class ClientGone(Exception):
    """The client closed its connection before its request's body had arrived."""


class HttpStats:
    """The HTTP front end's counters (``/metrics``: ``tactiled_http_*``) and its rate-limited
    log lines: a client that leaves mid-body, or drips its request, is worth a line a minute,
    not one each time (any local client could flood the journal)."""

    REASONS = ("too_large", "read_timeout", "bad_json")

    def __init__(self, log_every_s: float = LOG_EVERY_S) -> None:
        self.log_every_s = log_every_s
        self.disconnects = 0  # clients gone before their body arrived whole
        self.refused = dict.fromkeys(self.REASONS, 0)
        self._last_log: dict[str, float] = {}
        self._unlogged: dict[str, int] = {}

    def note(self, kind: str, message: str) -> None:
        """Log ``message`` (WARNING) unless a line of this ``kind`` went out within the last
        ``log_every_s``; the next line says how many were held back."""
        now = time.monotonic()
        last = self._last_log.get(kind)
        if last is not None and now - last < self.log_every_s:
            self._unlogged[kind] = self._unlogged.get(kind, 0) + 1
            return
        held = self._unlogged.pop(kind, 0)
        self._last_log[kind] = now
        log.warning("%s%s", message, f" (and {held} more like it in the last "
                                     f"{self.log_every_s:g} s)" if held else "")

    def client_left(self, scope: dict[str, Any]) -> None:
        self.disconnects += 1
        self.note("disconnect", f"client {_peer(scope)} left before sending the whole body of "
                                f"{scope.get('method', '?')} {shown(scope.get('path', '?'))} "
                                "(counted in tactiled_http_client_disconnects_total)")

    def timed_out(self, peer: str, what: str, timeout_s: float) -> None:
        self.refused["read_timeout"] += 1
        self.note("read_timeout", f"client {peer} did not send {what} within {timeout_s:g} s: "
                                  "connection closed (server.read_timeout)")


def _peer(scope: dict[str, Any]) -> str:
    client = scope.get("client")
    return f"{client[0]}:{client[1]}" if client else "?"


async def read_body(request: Request, limit: int, timeout_s: float, stats: HttpStats) -> bytes:
    """The body of ``request``, at most ``limit`` bytes, counted as it arrives: 413 at once
    when ``Content-Length`` or the bytes so far exceed ``limit`` (the rest is never read; the
    answer closes the connection), 408 when it is not in within ``timeout_s`` s,
    :class:`ClientGone` when the client leaves first."""
    length = request.headers.get("content-length", "")
    if length.isdigit() and (len(length) > 18 or int(length) > limit):
        stats.refused["too_large"] += 1
        raise HTTPException(413, f"body larger than {limit} bytes", CLOSE)
    body = bytearray()
    try:
        async with asyncio.timeout(timeout_s):
            async for chunk in request.stream():
                if len(body) + len(chunk) > limit:
                    stats.refused["too_large"] += 1
                    raise HTTPException(413, f"body larger than {limit} bytes", CLOSE)
                body += chunk
    except ClientDisconnect:
        stats.client_left(request.scope)
        raise ClientGone from None
    except TimeoutError:
        stats.timed_out(_peer(request.scope), "the request's body", timeout_s)
        raise HTTPException(408, f"body not received within {timeout_s:g} s "
                                 "(server.read_timeout)", CLOSE) from None
    return bytes(body)

"""Client-side helpers of the service tests: real WebSocket and HTTP clients."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable
from typing import Any

import httpx
from procs import block_until
from websockets.asyncio.client import ClientConnection, connect

from tactiled.fit.result import FitResult
from tactiled.settings import Settings, load_settings

SIM = "sim://?scene=demo&seed={seed}&sensor_id={sid}"

#: The keys of a `tactiled fit` line (what the pinned contract promises in every estimate).
FIT_LINE_KEYS = frozenset(FitResult(contact=False).to_json_dict())


def sim_settings(sensors: int = 2, *, rate_hz: float | None = None, **extra: Any) -> Settings:
    """Settings with ``sensors`` simulated fingers (finger0, finger1...), one fit worker,
    port 0 on 127.0.0.1, plus ``extra`` dotted overrides.  ``rate_hz``: the fingers' frame
    rate (the simulator's default, 1 kHz, if None); a test about what a server answers, not
    about the frame path, can ask for fewer frames: the in-process server's frame path shares
    the test's interpreter (and its lock), 1 kHz per finger costs about half a core."""
    overrides: dict[str, Any] = {"server.host": "127.0.0.1", "server.port": 0,
                                 "fit.workers": 1}
    for i in range(sensors):
        overrides[f"sensor[{i}].url"] = SIM.format(seed=i + 1, sid=i) + (
            "" if rate_hz is None else f"&rate={rate_hz:g}")
        overrides[f"sensor[{i}].name"] = f"finger{i}"
    overrides.update(extra)
    return load_settings(None, {}, overrides)


def ws_connect(url: str, **kwargs: Any) -> Any:
    """``websockets`` client connection (no compression unless asked).  Its closing handshake
    waits at most 2 s (websockets' default: 10): a client that stops reading a 1 kHz stream
    leaves the server's close frame behind a backlog, and what these tests check is done by
    then (a test of the close itself reads its code, not the handshake's end)."""
    kwargs.setdefault("compression", None)
    kwargs.setdefault("open_timeout", 10)
    kwargs.setdefault("close_timeout", 2)
    kwargs.setdefault("max_size", 2**22)
    return connect(url, **kwargs)


async def recv_json(ws: ClientConnection, timeout: float = 10.0) -> dict[str, Any]:
    return json.loads(await asyncio.wait_for(ws.recv(), timeout))


async def recv_until(ws: ClientConnection, done: Callable[[list[dict[str, Any]]], bool],
                     timeout: float = 15.0) -> list[dict[str, Any]]:
    """Receive messages until ``done(messages)``; fail after ``timeout`` s."""
    got: list[dict[str, Any]] = []
    deadline = time.monotonic() + timeout
    while not done(got):
        left = deadline - time.monotonic()
        if left <= 0:
            kinds = sorted({m.get("type", "?") for m in got})
            raise AssertionError(f"condition not met within {timeout} s; got {len(got)} "
                                 f"message(s) of types {kinds}")
        got.append(await recv_json(ws, left))
    return got


async def subscribe(ws: ClientConnection, **fields: Any) -> dict[str, Any]:
    """Read the version message, subscribe, and return the server's confirmation."""
    version = await recv_json(ws)
    assert version["type"] == "version", version
    await ws.send(json.dumps({"type": "subscribe", **fields}))
    reply = await recv_json(ws)
    assert reply["type"] == "subscribed", reply
    return reply


def http(base: str, method: str, path: str, **kwargs: Any) -> httpx.Response:
    """One HTTP request (a fresh client, so cookies never leak between calls)."""
    with httpx.Client(base_url=base, timeout=10.0) as client:
        return client.request(method, path, **kwargs)


def wait_for(condition: Callable[[], bool], timeout: float, poll: float = 0.05,
             what: str = "condition") -> float:
    """Poll ``condition`` until true; seconds taken, or AssertionError after ``timeout``."""
    return block_until(condition, timeout, what, poll)

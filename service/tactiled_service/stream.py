"""The WebSocket stream ``/v1/stream``: handshake checks, subscriptions, fan-out, slow peers.

A connection: handshake (Host, Origin, token; 401/403 before accept) -> subscriber limit
(closed 1013) -> ``version`` -> the client's ``subscribe`` (gpsd's WATCH) -> estimate / frame
messages.  Fan-out never waits for a subscriber: each session owns one bounded
:class:`~tactiled.pipeline.Subscription` (newest wins; drops counted), paced by
:class:`PaceGroup` when it asks for ``max_rate``.
"""
# Without max_rate a session's subscription is the hub's own (every item offered).  With
# max_rate the hub offers nothing to it directly; the manager's single hub listener passes it at
# most one item per 1/max_rate s per sensor and stream, so a 30 Hz dashboard costs 30 wake-ups a
# second, not the sensor's 1000.  Sessions with the same subscription share one pacing decision
# per item (and so the same items, encoded once): the cost per published item does not grow with
# the number of paced subscribers.
# A session's sender drains its queue; a batch of sends that cannot complete within
# send_timeout_s (the peer stopped reading, socket buffers full) ends the session with close
# code 1013, through tactiled_service.protocol since an ordinary close would wait for the same
# full buffers.  Other subscribers never notice.

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import logging
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from pydantic import ValidationError

from tactiled import __version__
from tactiled.pipeline import Daemon, Estimate, Subscription, SubscriptionClosed, ZeroedFrame
from tactiled_service.auth import AuthPolicy, Denial
from tactiled_service.inbound import BadJson, decode_json, shown
from tactiled_service.json_messages import STREAM_KINDS, Encoder, control, dumps, error
from tactiled_service.options import ServiceOptions
from tactiled_service.protocol import FORCE_CLOSE
from tactiled_service.schemas import SubscribeRequest, format_validation_error

log = logging.getLogger(__name__)

Item = Estimate | ZeroedFrame
Receive = Callable[[], Awaitable[dict[str, Any]]]
Send = Callable[[dict[str, Any]], Awaitable[None]]

CLOSE_NORMAL = 1000
CLOSE_GOING_AWAY = 1001  # server shutting down
CLOSE_TRY_AGAIN = 1013  # too many subscribers; subscriber too slow
MAX_BATCH = 64  # items sent per wake-up of a sender
FLUSH_TICK_S = 0.01  # how often held (rate-limited) items are checked
FLUSH_GRACE_S = 0.01  # a held item is flushed once its slot is this late (the stream paused)


class Stalled(Exception):
    """A send did not complete within the send timeout."""


@dataclass(frozen=True)
class Spec:
    """What a session subscribed to (``sensors`` None: all)."""

    sensors: frozenset[str] | None
    kinds: frozenset[str]
    max_rate: float | None

    def describe(self, all_sensors: list[str]) -> dict[str, Any]:
        return {
            "sensors": sorted(self.sensors) if self.sensors is not None else list(all_sensors),
            "streams": sorted(s for s, k in STREAM_KINDS.items() if k in self.kinds),
            "max_rate": self.max_rate,
        }


class PaceGroup:
    """Pacing shared by the sessions with one subscription: at most one item per ``period`` s
    per (sensor, kind), the newest wins, offered to every member's queue.

    An item arriving when its slot is free is passed at once (no added latency); one arriving
    early is held, replaced by newer ones, and passed by :meth:`flush` if nothing newer comes
    within the slot plus a grace, so the last state before a pause is never lost.
    """

    def __init__(self, spec: Spec) -> None:
        assert spec.max_rate is not None
        self.spec = spec
        self.period = 1.0 / spec.max_rate
        self.members: list[Subscription] = []
        self.next_due: dict[tuple[str, str], float] = {}
        self.held: dict[tuple[str, str], Item] = {}
        self.coalesced = 0  # items skipped by the rate limit (not a loss: newer ones went)

    def _pass(self, item: Item) -> None:
        for sub in self.members:
            sub.offer(item)

    def offer(self, item: Item, now: float) -> None:
        if item.kind == "slip":  # an event, not a state: never paced, never coalesced
            self._pass(item)
            return
        key = (item.sensor, item.kind)
        due = self.next_due.get(key, 0.0)
        if now >= due:
            if self.held.pop(key, None) is not None:
                self.coalesced += 1
            self._pass(item)
            # Keep the average rate at max_rate despite arrival jitter, without bursting
            # after a pause.
            self.next_due[key] = due + self.period if now - due < self.period else now + self.period
        else:
            if key in self.held:
                self.coalesced += 1
            self.held[key] = item

    def flush(self, now: float) -> None:
        for key in [k for k in self.held if now >= self.next_due[k] + FLUSH_GRACE_S]:
            self._pass(self.held.pop(key))
            self.next_due[key] = now + self.period


class Session:
    """One WebSocket connection to the stream."""

    def __init__(self, manager: StreamManager, sid: int, scope: dict[str, Any],
                 receive: Receive, send: Send) -> None:
        self.manager = manager
        self.id = sid
        self.receive = receive
        self.send = send
        self.scope = scope
        client = scope.get("client")
        self.peer = f"{client[0]}:{client[1]}" if client else "?"
        self.connected_at = time.monotonic()
        self.spec: Spec | None = None
        self.subscription: Subscription | None = None
        self.group: PaceGroup | None = None
        self._coalesced_at_join = 0
        self.sent = 0  # messages sent (all types)
        self.errors = 0  # error messages sent
        self._dropped_before = 0  # drops of earlier subscriptions of this session
        self._coalesced_before = 0
        self._changed = asyncio.Event()
        self._stop = asyncio.Event()
        self.close_code: int | None = None
        self.close_reason = ""
        #: The protocol's extras (:mod:`tactiled_service.protocol`), None on another server.
        self.ext: dict[str, Any] | None = scope.get("extensions", {}).get(FORCE_CLOSE)

    # -- counters -------------------------------------------------------------------------------

    @property
    def dropped(self) -> int:
        """Items lost because this subscriber fell ``queue_size`` behind."""
        current = self.subscription.dropped if self.subscription is not None else 0
        return self._dropped_before + current

    @property
    def coalesced(self) -> int:
        """Items skipped because of the subscriber's own ``max_rate``."""
        current = (self.group.coalesced - self._coalesced_at_join
                   if self.group is not None else 0)
        return self._coalesced_before + current

    def stats(self) -> dict[str, Any]:
        spec = self.spec.describe(self.manager.sensor_names) if self.spec else None
        return {
            "id": self.id,
            "peer": self.peer,
            "connected_s": round(time.monotonic() - self.connected_at, 3),
            "subscription": spec,
            "sent": self.sent,
            "queued": self.subscription.qsize() if self.subscription is not None else 0,
            "dropped": self.dropped,
            "coalesced": self.coalesced,
        }

    # -- control --------------------------------------------------------------------------------

    def request_close(self, code: int, reason: str) -> None:
        """Ask the session to close with ``code`` (from any task of the loop)."""
        if self.close_code is None:
            self.close_code, self.close_reason = code, reason
        self._stop.set()

    def _unsubscribe(self) -> None:
        sub, self.subscription = self.subscription, None
        group, self.group = self.group, None
        if sub is not None:
            self._dropped_before += sub.dropped
            sub.close()
        if group is not None:
            self._coalesced_before += group.coalesced - self._coalesced_at_join
            if sub is not None:
                self.manager.leave(group, sub)
        self.spec = None
        self._changed.set()

    def _subscribe(self, spec: Spec) -> None:
        self._unsubscribe()
        hub = self.manager.daemon.hub
        size = self.manager.options.queue_size
        if spec.max_rate is None:
            sub = hub.subscribe(spec.sensors, spec.kinds, maxsize=size)
        else:
            # Fed by the manager's pacing, not by the hub (see the module docstring).
            sub = Subscription(None, spec.sensors, spec.kinds, size)
            self.group = self.manager.join(spec, sub)
            self._coalesced_at_join = self.group.coalesced
        self.subscription = sub
        self.spec = spec
        self._changed.set()

    # -- sending --------------------------------------------------------------------------------

    async def send_texts(self, texts: list[str], sub: Subscription | None = None) -> None:
        """Send ``texts`` in order; :class:`Stalled` if they cannot all go within the send
        timeout.  With ``sub``, stop early once it is no longer the session's subscription
        (nothing of an old subscription may follow the reply to a new one)."""
        ext = self.ext
        try:
            async with asyncio.timeout(self.manager.options.send_timeout_s):
                if ext is not None:
                    # Fast path: the whole batch in one write once the transport takes data.
                    while True:
                        if sub is not None and sub is not self.subscription:
                            return
                        if ext["write_texts"](texts):
                            break
                        await ext["writable"].wait()
                    self.sent += len(texts)
                    return
                for text in texts:
                    if sub is not None and sub is not self.subscription:
                        return
                    await self.send({"type": "websocket.send", "text": text})
                    self.sent += 1
        except TimeoutError:
            raise Stalled from None

    async def send_message(self, msg: dict[str, Any]) -> None:
        await self.send_texts([dumps(msg)])

    async def pump(self) -> None:
        """Forward subscribed items until the subscription is closed under us (hub closed)."""
        encoder = self.manager.encoder
        while True:
            sub = self.subscription
            if sub is None:
                self._changed.clear()
                await self._changed.wait()
                continue
            try:
                item = await sub.get()
            except SubscriptionClosed:
                if sub is self.subscription:  # not a re-subscription: the hub closed
                    self.request_close(CLOSE_GOING_AWAY, "server shutting down")
                    return
                continue
            batch = [item]
            while len(batch) < MAX_BATCH:
                try:
                    more = sub.get_nowait()
                except SubscriptionClosed:
                    break
                if more is None:
                    break
                batch.append(more)
            await self.send_texts([encoder.text(it) for it in batch], sub)

    # -- receiving ------------------------------------------------------------------------------

    async def read(self) -> None:
        """Handle client messages until the client disconnects."""
        while True:
            msg = await self.receive()
            kind = msg.get("type")
            if kind == "websocket.disconnect":
                return
            if kind != "websocket.receive":
                continue
            text = msg.get("text")
            if text is None:
                await self._error("bad_message", "binary messages are not understood: send a "
                                                 "JSON object as a text message")
                continue
            await self.handle(text)

    async def _error(self, code: str, message: str, request: str | None = None) -> None:
        self.errors += 1
        await self.send_message(error(code, message, request))

    async def handle(self, text: str) -> None:
        """One client message (a JSON object with a ``type``)."""
        try:
            msg = decode_json(text, "message")
        except BadJson as err:  # not JSON, or what no reply could echo (NaN, "\ud800", ...)
            await self._error("bad_message", str(err))
            return
        if not isinstance(msg, dict):
            await self._error("bad_message", "a message must be a JSON object with a \"type\", "
                                             f"got {type(msg).__name__}")
            return
        kind = msg.get("type")
        if kind == "subscribe":
            await self._on_subscribe(msg)
        elif kind == "unsubscribe":
            self._unsubscribe()
            await self.send_message(control("unsubscribed"))
        elif kind == "ping":
            await self.send_message(control("pong", id=msg.get("id")))
        elif kind is None:
            await self._error("bad_message", "missing \"type\" (one of: subscribe, "
                                             "unsubscribe, ping)")
        else:
            text = kind if isinstance(kind, str) else json.dumps(kind)
            await self._error("bad_message", f"unknown message type {shown(text)} (known: "
                                             "subscribe, unsubscribe, ping)",
                              text[:64] if isinstance(kind, str) else None)

    async def _on_subscribe(self, msg: dict[str, Any]) -> None:
        try:
            req = SubscribeRequest.model_validate(msg)
        except ValidationError as err:
            await self._error("bad_message", format_validation_error(err), "subscribe")
            return
        names = self.manager.sensor_names
        sensors = None
        if req.sensors is not None:
            unknown = sorted(set(req.sensors) - set(names))
            if unknown:
                await self._error("unknown_sensor",
                                  f"unknown sensor(s) {', '.join(map(repr, unknown))}; "
                                  f"known: {', '.join(names)}", "subscribe")
                return
            sensors = frozenset(req.sensors)
        if req.max_rate is not None and req.max_rate > self.manager.options.max_rate_hz:
            await self._error("bad_message", f"max_rate: at most "
                                             f"{self.manager.options.max_rate_hz:g} Hz, got "
                                             f"{req.max_rate:g}", "subscribe")
            return
        spec = Spec(sensors, frozenset(STREAM_KINDS[s] for s in req.streams), req.max_rate)
        # Reply first, then subscribe: the first data message follows the confirmation.
        self._unsubscribe()
        await self.send_message(control("subscribed", **spec.describe(names)))
        self._subscribe(spec)


class StreamManager:
    """All stream sessions of one server: limits, the rate-limited fan-out, shutdown."""

    def __init__(self, daemon: Daemon, options: ServiceOptions, auth: AuthPolicy,
                 encoder: Encoder) -> None:
        self.daemon = daemon
        self.options = options
        self.auth = auth
        self.encoder = encoder
        self.sensor_names = list(daemon.sensors)
        self.sessions: dict[int, Session] = {}
        self.groups: dict[Spec, PaceGroup] = {}
        #: (sensor, kind) -> the groups that want such items: the per-item lookup.
        self._index: dict[tuple[str, str], list[PaceGroup]] = {}
        self.closing = False
        self.refused = {"auth": 0, "limit": 0, "closing": 0}
        self.stalled = 0  # sessions closed because they stopped reading
        self._ids = itertools.count(1)
        self._remove_listener: Callable[[], None] | None = None
        self._flusher: asyncio.Task[None] | None = None
        self._idle = asyncio.Event()
        self._idle.set()

    # -- fan-out to rate-limited sessions ------------------------------------------------------

    def start(self) -> None:
        """Attach to the hub (call on the loop that runs the daemon)."""
        if self._remove_listener is None:
            self._remove_listener = self.daemon.hub.add_listener(self._on_item, events=True)
            self._flusher = asyncio.create_task(self._flush_loop(), name="tactiled-ws-flush")

    def join(self, spec: Spec, sub: Subscription) -> PaceGroup:
        """Add ``sub`` to the pacing group of ``spec`` (made if needed)."""
        group = self.groups.get(spec)
        if group is None:
            group = self.groups[spec] = PaceGroup(spec)
            for key in self._keys(spec):
                self._index.setdefault(key, []).append(group)
        group.members.append(sub)
        return group

    def leave(self, group: PaceGroup, sub: Subscription) -> None:
        """Remove ``sub``; an empty group goes."""
        if sub in group.members:
            group.members.remove(sub)
        if not group.members and self.groups.get(group.spec) is group:
            del self.groups[group.spec]
            for key in self._keys(group.spec):
                groups = self._index.get(key, [])
                if group in groups:
                    groups.remove(group)
                if not groups:
                    self._index.pop(key, None)

    def _keys(self, spec: Spec) -> list[tuple[str, str]]:
        sensors = self.sensor_names if spec.sensors is None else sorted(spec.sensors)
        return [(s, k) for s in sensors for k in spec.kinds]

    def _on_item(self, item: Item) -> None:
        groups = self._index.get((item.sensor, item.kind))
        if groups:
            now = time.monotonic()
            for group in groups:
                group.offer(item, now)

    async def _flush_loop(self) -> None:
        while True:
            await asyncio.sleep(FLUSH_TICK_S)
            if self.groups:
                now = time.monotonic()
                for group in list(self.groups.values()):
                    if group.held:
                        group.flush(now)

    # -- sessions -------------------------------------------------------------------------------

    def stats(self) -> dict[str, Any]:
        return {
            "count": len(self.sessions),
            "limit": self.options.max_subscribers,
            "refused": dict(self.refused),
            "stalled": self.stalled,
            "clients": [s.stats() for s in self.sessions.values()],
        }

    async def serve(self, scope: dict[str, Any], receive: Receive, send: Send) -> None:
        """The ASGI WebSocket handler."""
        first = await receive()
        if first.get("type") != "websocket.connect":
            return
        denial = self.auth.check_host(scope) or self.auth.check_stream(scope)
        if denial is not None:
            self.refused["auth"] += 1
            await deny(scope, send, denial)
            return
        if self.closing:
            self.refused["closing"] += 1
            await deny(scope, send, Denial(503, "server shutting down"))
            return
        await send({"type": "websocket.accept"})
        if len(self.sessions) >= self.options.max_subscribers:
            self.refused["limit"] += 1
            await _close(send, CLOSE_TRY_AGAIN, f"too many subscribers (limit "
                                                f"{self.options.max_subscribers})")
            return
        session = Session(self, next(self._ids), scope, receive, send)
        self.sessions[session.id] = session
        self._idle.clear()
        try:
            await self._run(session)
        finally:
            session._unsubscribe()
            self.sessions.pop(session.id, None)
            if not self.sessions:
                self._idle.set()

    async def _run(self, session: Session) -> None:
        tasks: list[asyncio.Task[Any]] = []
        outcome = "closed"
        try:
            await session.send_message(control(
                "version", release=__version__, proto="tactiled-stream",
                sensors=self.sensor_names, streams=list(STREAM_KINDS),
                max_message_bytes=self.options.max_message_bytes))
            reader = asyncio.create_task(session.read(), name=f"tactiled-ws{session.id}-read")
            pump = asyncio.create_task(session.pump(), name=f"tactiled-ws{session.id}-pump")
            stop = asyncio.create_task(session._stop.wait(), name=f"tactiled-ws{session.id}-stop")
            tasks = [reader, pump, stop]
            done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            # Judge the pump first: a stalled send matters more than a reader that ended at
            # the same moment.
            for task in (pump, reader):
                if task not in done:
                    continue
                exc = task.exception()
                if isinstance(exc, Stalled):
                    outcome = "stalled"
                    break
                if exc is not None and not isinstance(exc, OSError):
                    log.error("stream session %d failed: %r", session.id, exc)
                    outcome = "failed"
                    break
                if task is reader:
                    outcome = "disconnected"
        except Stalled:
            outcome = "stalled"
        finally:
            for task in tasks:
                task.cancel()
            if tasks:
                await asyncio.gather(*tasks, return_exceptions=True)
        if outcome == "disconnected":
            return
        if outcome == "stalled":
            self.stalled += 1
            timeout = self.options.send_timeout_s
            log.warning("subscriber %d (%s) stopped reading: closed after %g s (1013)",
                        session.id, session.peer, timeout)
            self._force_close(session, CLOSE_TRY_AGAIN,
                              f"subscriber too slow: a send was stuck for {timeout:g} s")
            return
        if outcome == "failed":
            session.request_close(1011, "internal error")
        await self._close_session(session)

    async def _close_session(self, session: Session) -> None:
        code = session.close_code or CLOSE_NORMAL
        try:
            async with asyncio.timeout(self.options.close_timeout_s):
                await _close(session.send, code, session.close_reason)
        except TimeoutError:  # stuck behind a full buffer: cut it
            self._force_close(session, code, session.close_reason)
        except Exception:  # already gone
            pass

    def _force_close(self, session: Session, code: int, reason: str) -> None:
        ext = session.scope.get("extensions", {}).get(FORCE_CLOSE)
        if ext is not None:
            ext["close"](code, reason, self.options.close_timeout_s)
        # Without the extension (another server), returning lets the server close the
        # transport; TCP_USER_TIMEOUT still bounds how long the socket can linger.

    async def shutdown(self, timeout: float) -> None:
        """Close every session with 1001 and wait up to ``timeout`` s for them to end."""
        self.closing = True
        for session in list(self.sessions.values()):
            session.request_close(CLOSE_GOING_AWAY, "server shutting down")
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(timeout):
                await self._idle.wait()
        if self._remove_listener is not None:
            self._remove_listener()
            self._remove_listener = None
        if self._flusher is not None:
            self._flusher.cancel()
            await asyncio.gather(self._flusher, return_exceptions=True)
            self._flusher = None


async def _close(send: Send, code: int, reason: str) -> None:
    await send({"type": "websocket.close", "code": code, "reason": reason[:120]})


async def deny(scope: dict[str, Any], send: Send, denial: Denial) -> None:
    """Refuse a WebSocket handshake with an HTTP response (before accept)."""
    body = dumps({"detail": denial.message}).encode()
    if "websocket.http.response" in scope.get("extensions", {}):
        headers = [(b"content-type", b"application/json"),
                   (b"content-length", str(len(body)).encode())]
        headers += [(k.lower().encode("latin-1"), v.encode("latin-1"))
                    for k, v in denial.headers]
        await send({"type": "websocket.http.response.start", "status": denial.status,
                    "headers": headers})
        await send({"type": "websocket.http.response.body", "body": body})
    else:  # the server answers 403 without a body
        await send({"type": "websocket.close", "code": 1008})


class StreamEndpoint:
    """The raw ASGI app mounted at ``/v1/stream`` (a class, so Starlette treats it as ASGI)."""

    def __init__(self, manager_getter: Callable[[], StreamManager]) -> None:
        self._manager = manager_getter

    async def __call__(self, scope: dict[str, Any], receive: Receive, send: Send) -> None:
        await self._manager().serve(scope, receive, send)

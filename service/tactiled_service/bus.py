"""Zenoh: a second front end beside the web server, fed by the same hub (``docs/howto/zenoh.md``).

Loaded only when ``[zenoh] enabled`` (the ``zenoh`` extra).  Publishes every estimate, paced
frames, slip events and health under ``zenoh.prefix``, answers ``latest`` and ``health``
queries, and holds a liveliness token; payloads are the WebSocket stream's JSON texts.
Publishing never blocks the event loop (:class:`Sender`).  The reading side, for
``tactiled watch --zenoh``: :func:`watch` and :func:`list_daemons`.
"""
# Keys, with P = zenoh.prefix (default tactiled/<hostname>):
# * P/<sensor>/estimate: every estimate, the stream's estimate message;
# * P/<sensor>/frame: zeroed frames, at most zenoh.frame_rate_hz per sensor (0: none);
# * P/<sensor>/slip: a 3-axis array's slip events (the stream's slip message), every one, never
#   paced (a controller may subscribe to this key alone);
# * P/health: the GET /v1/health document, once a second and on every status change;
# queries on P/<sensor>/latest (the newest estimate) and P/health; liveliness token P.
# Payloads: one shared json_messages.Encoder, UTF-8, encoding application/json.
#
# Congestion control (``zenoh.reliable``): by default everything is put with DROP: a subscriber
# that stalls, a slow network or a full link costs the others nothing, but every Zenoh node on the
# way (this daemon, each router) drops a message for a link whose queue (two 64 KB batches) stays
# full for wait_before_drop (1 ms), silently; a CPU-starved machine does that to healthy links
# (measured: runs of 1-100 estimates lost per 3 s, at the daemon and at the router, three CPU hogs
# on 2 cores).  With ``reliable`` estimates and slip events are put with BLOCK (they wait for room;
# the congestion control travels with each sample and routers honour it), frames and health stay
# on DROP.  BLOCK makes put wait, so a subscriber that stopped reading holds up this daemon's other
# links until Zenoh closes its link (blocked for wait_before_close, 5 s by default; a zenoh.config
# file may shorten it, at the risk of closing a slow but healthy link: 1 s did, under load); the
# sender's queue is then RELIABLE_QUEUE_SIZE, more than 5 s of three 1 kHz sensors, so the others
# see a pause, not a gap.
#
# Why a sender thread: Publisher.put is synchronous (BLOCK: until there is room, at most
# wait_before_close; DROP: at most wait_before_drop), so the loop only queues the text and Sender
# calls put.  Its queue is bounded; when full the oldest item is dropped and counted (zenoh.dropped
# in the health document).  Estimates of a key no subscriber matches are not even encoded.
# Queries arrive on Zenoh's threads; the answer is built on the event loop (daemon and encoder
# are not thread-safe) and sent from the query's thread.  Opening and closing the session run on
# threads of their own, so a slow network never stalls acquisition; a client whose router cannot
# be reached keeps retrying in the background.

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any, TextIO

import zenoh

from tactiled.errors import ConfigError
from tactiled.pipeline import Daemon, Estimate, ZeroedFrame
from tactiled.pipeline.shear_track import SlipItem
from tactiled.settings import ZenohSettings
from tactiled_service.json_messages import Encoder, dumps
from tactiled_service.sender import QUEUE_SIZE, Sender

log = logging.getLogger(__name__)

JSON = zenoh.Encoding.APPLICATION_JSON
HEALTH_PERIOD_S = 1.0  # s between health publications when nothing changes
HEALTH_TICK_S = 0.1  # s between status checks (a change is published within this)
QUERY_TIMEOUT_S = 2.0  # s a query waits for the event loop before it is answered with an error
CLOSE_TIMEOUT_S = 2.0  # s closing the session may take before it is abandoned
RETRY_MIN_S, RETRY_MAX_S = 0.5, 4.0  # s between attempts to reach a client's router
#: Items the bus's sender may fall behind with ``zenoh.reliable``: more than Zenoh's
#: wait_before_close (5 s) of three 1 kHz sensors, the longest an estimate's put waits for a
#: stalled link.
RELIABLE_QUEUE_SIZE = 16384


def congestion(kind: str, reliable: bool) -> Any:
    """Zenoh's congestion control for a publication of ``kind`` (``estimate``, ``slip``,
    ``frame``, ``health``): BLOCK for estimates and slip events with ``zenoh.reliable``, DROP
    otherwise (module comment)."""
    if reliable and kind in ("estimate", "slip"):
        return zenoh.CongestionControl.BLOCK
    return zenoh.CongestionControl.DROP


# --------------------------------------------------------------------------------------------
# Configuration


def session_config(settings: ZenohSettings, *, listen: bool = True) -> zenoh.Config:
    """The Zenoh configuration of ``settings``: the ``config`` file if any, then the tactiled
    keys over it (``mode``, multicast scouting, and ``connect`` / ``listen`` when not empty).

    Every endpoint also goes through Zenoh's own parser here, so one it refuses is a
    :class:`ConfigError` naming the key (``zenoh.connect[1]: ...``) before anything starts.
    ``listen`` False: never listen (the reading side of ``tactiled watch``).
    """
    if settings.config is not None:
        try:
            cfg = zenoh.Config.from_file(settings.config)
        except Exception as err:  # zenoh.ZError, with the parser's own words
            raise ConfigError(f"zenoh.config: {settings.config}: {describe_error(err)}") from None
    else:
        cfg = zenoh.Config()
    _insert(cfg, "mode", settings.mode, "zenoh.mode")
    _insert(cfg, "scouting/multicast/enabled", settings.scouting, "zenoh.multicast_scouting")
    for name, endpoints in (("connect", settings.connect),
                            ("listen", settings.listen if listen else ())):
        for i, endpoint in enumerate(endpoints):
            _insert(zenoh.Config(), f"{name}/endpoints", [endpoint], f"zenoh.{name}[{i}]")
        if endpoints:
            _insert(cfg, f"{name}/endpoints", list(endpoints), f"zenoh.{name}")
    if not listen:
        _insert(cfg, "listen/endpoints", [], "zenoh.listen")
    return cfg


def _insert(cfg: zenoh.Config, path: str, value: Any, key: str) -> None:
    try:
        cfg.insert_json5(path, json.dumps(value))
    except Exception as err:
        raise ConfigError(f"{key}: {describe_error(err)}") from None


def describe_error(err: BaseException) -> str:
    """Zenoh's message without the Rust source locations it appends."""
    text = str(err)
    for marker in (" at /", " at src/"):
        text = text.split(marker, 1)[0]
    if text.startswith("Json5Err(Message { msg: \""):
        text = text[len("Json5Err(Message { msg: \""):].split("\", location", 1)[0]
    if text.count("[") > text.count("]"):  # the cut took a closing bracket with it
        text = text.replace(": [", ": ", 1)
    return text.strip().rstrip(".") or type(err).__name__


async def _in_thread(fn: Callable[[], Any], name: str, timeout: float | None = None,
                     orphan: Callable[[Any], None] | None = None) -> Any:
    """``fn()`` on a daemon thread of its own (a hung Zenoh call must not hold the process at
    exit, as the default executor's threads would); TimeoutError after ``timeout`` s.  If the
    caller gives up (timeout, cancellation), ``orphan`` gets the result when it comes (a
    session opened for no one is closed)."""
    loop = asyncio.get_running_loop()
    fut: asyncio.Future[Any] = loop.create_future()

    def run() -> None:
        try:
            result = fn()
        except BaseException as err:
            loop.call_soon_threadsafe(_settle, fut, None, err)
        else:
            loop.call_soon_threadsafe(_settle, fut, result, None)

    threading.Thread(target=run, name=name, daemon=True).start()
    try:
        return await asyncio.wait_for(asyncio.shield(fut), timeout)
    except BaseException:
        if orphan is not None:
            def late(f: asyncio.Future[Any]) -> None:
                if not f.cancelled() and f.exception() is None:
                    orphan(f.result())

            fut.add_done_callback(late)
        raise


def _close_later(session: Any) -> None:
    """Close a session nobody will use, off the event loop."""
    threading.Thread(target=session.close, name="tactiled-zenoh-close", daemon=True).start()


def check_key(key: str) -> None:
    """Raise ValueError (Zenoh's words) unless ``key`` is a valid key expression."""
    try:
        zenoh.KeyExpr(key)
    except Exception as err:
        raise ValueError(describe_error(err)) from None


def _settle(fut: asyncio.Future[Any], result: Any, err: BaseException | None) -> None:
    if fut.done():
        return
    if err is not None:
        fut.set_exception(err)
    else:
        fut.set_result(result)


# --------------------------------------------------------------------------------------------
# Publishing


class Bus:
    """The Zenoh front end of one daemon (see the module docstring).

    ``health`` is the service's :class:`~tactiled_service.health.HealthMonitor`, whose
    ``report()`` is published and answered.  Call :meth:`start` and :meth:`stop` on the event
    loop that runs ``daemon``.
    """

    def __init__(self, settings: ZenohSettings, daemon: Daemon, encoder: Encoder,
                 health: Any, queue_size: int | None = None) -> None:
        self.settings = settings
        self.daemon = daemon
        self.encoder = encoder
        self.health = health
        self.prefix = settings.prefix
        self.config = session_config(settings)
        if queue_size is None:
            queue_size = RELIABLE_QUEUE_SIZE if settings.reliable else QUEUE_SIZE
        self.sender = Sender(queue_size, kinds=("estimate", "frame", "slip", "health"))
        self.session: zenoh.Session | None = None
        self.state = "new"  # new, connecting (a client retrying its router), open, closed
        self.queries = 0
        self.query_errors = 0
        self.health_key = f"{self.prefix}/health"
        self._estimate_pubs: dict[str, Any] = {}
        self._frame_pubs: dict[str, Any] = {}
        self._slip_pubs: dict[str, Any] = {}
        self._health_pub: Any = None
        #: key -> a subscriber matches it (kept by Zenoh's matching listeners).
        self._matching: dict[str, bool] = {}
        self._declared: list[Any] = []  # queryables, listeners, the token: undeclared at stop
        #: Other front ends sharing this session (the ROS 2 node, tactiled_service.ros2): each
        #: has ``declare(session) -> list`` (what to undeclare at stop), ``stop()``, and
        #: ``name`` and ``stats()`` (their section of :meth:`stats`).
        self.fronts: list[Any] = []
        self._frame_period = (1.0 / settings.frame_rate_hz if settings.frame_rate_hz > 0
                              else None)
        self._frame_due: dict[str, float] = {}
        self._remove_listener: Callable[[], None] | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._last_health: tuple[Any, ...] | None = None
        self._last_health_at = 0.0
        self._put_max_1s = 0.0
        self._open_error = ""

    # -- lifecycle ------------------------------------------------------------------------------

    async def start(self) -> None:
        """Open the session and declare everything; from then on every published item goes
        out.  A peer opens even with its ``connect`` peers absent (Zenoh keeps trying); a
        client that cannot reach its router keeps trying in the background.  Raises
        :class:`ConfigError` when the session cannot be opened at all (a ``listen`` endpoint
        that cannot be bound)."""
        self._loop = asyncio.get_running_loop()
        self.sender.start()
        self.state = "connecting"
        try:
            session = await _in_thread(lambda: zenoh.open(self.config), "tactiled-zenoh-open",
                                       orphan=_close_later)
        except Exception as err:
            if self.settings.mode != "client":
                self.sender.stop()
                self.state = "closed"
                text = describe_error(err)
                key = "zenoh.listen" if "listener" in text.lower() else "zenoh"
                raise ConfigError(f"{key}: cannot open a session: {text}") from None
            self._open_error = describe_error(err)
            log.warning("zenoh: cannot reach a router (%s); retrying in the background",
                        self._open_error)
            self._tasks.append(asyncio.create_task(self._retry_open(), name="tactiled-zenoh-open"))
        else:
            await self._declare(session)
        self._tasks.append(asyncio.create_task(self._health_loop(), name="tactiled-zenoh-health"))

    async def _retry_open(self) -> None:
        delay = RETRY_MIN_S
        while True:
            await asyncio.sleep(delay)
            try:
                session = await _in_thread(lambda: zenoh.open(self.config),
                                           "tactiled-zenoh-open", orphan=_close_later)
            except Exception as err:
                self._open_error = describe_error(err)
                delay = min(RETRY_MAX_S, delay * 2)
                continue
            log.info("zenoh: reached a router")
            await self._declare(session)
            return

    async def _declare(self, session: zenoh.Session) -> None:
        """Publishers, queryables, the token (declarations are quick: done on the loop)."""
        if self.state == "closed":  # stopped while opening
            await _in_thread(session.close, "tactiled-zenoh-close", CLOSE_TIMEOUT_S)
            return
        self.session = session
        for name in self.daemon.sensors:
            for kind, pubs in (("estimate", self._estimate_pubs), ("frame", self._frame_pubs),
                               ("slip", self._slip_pubs)):
                if kind == "frame" and self._frame_period is None:
                    continue
                if kind == "slip" and getattr(self.daemon.sensors[name], "shear", None) is None:
                    continue  # a 1-axis array has no slip events
                key = f"{self.prefix}/{name}/{kind}"
                pub = session.declare_publisher(
                    key, encoding=JSON, congestion_control=congestion(kind, self.settings.reliable))
                pubs[name] = pub
                self._matching[key] = False
                self._declared.append(pub.declare_matching_listener(
                    zenoh.handlers.Callback(self._matcher(key))))
            self._declared.append(session.declare_queryable(
                f"{self.prefix}/{name}/latest",
                zenoh.handlers.Callback(self._latest_handler(name)), complete=True))
        self._health_pub = session.declare_publisher(
            self.health_key, encoding=JSON, congestion_control=congestion("health", False))
        self._declared.append(session.declare_queryable(
            self.health_key, zenoh.handlers.Callback(self._on_health_query), complete=True))
        self._declared.append(session.liveliness().declare_token(self.prefix))
        for front in self.fronts:
            self._declared.extend(front.declare(session))
        self._remove_listener = self.daemon.hub.add_listener(self._on_item, events=True)
        self.state = "open"
        self._open_error = ""
        self._last_health = None  # publish the health at once
        log.info("zenoh: publishing under %s/ (%s, session %s)", self.prefix,
                 self.settings.mode, session.zid())

    async def stop(self) -> None:
        """Withdraw the token, stop publishing and close the session (idempotent)."""
        if self.state == "closed":
            return
        self.state = "closed"
        if self._remove_listener is not None:
            self._remove_listener()
            self._remove_listener = None
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks.clear()
        for front in self.fronts:
            front.stop()
        self.sender.stop()
        session, self.session = self.session, None
        if session is None:
            return
        declared, self._declared = self._declared, []

        def close() -> None:
            # Undeclaring waits for running query callbacks, which may wait for this loop:
            # hence a thread.  The token goes first, so others see the daemon leave at once.
            for obj in reversed(declared):
                with contextlib.suppress(Exception):
                    obj.undeclare()
            session.close()

        try:
            await _in_thread(close, "tactiled-zenoh-close", CLOSE_TIMEOUT_S)
        except TimeoutError:
            log.warning("zenoh: the session did not close within %g s", CLOSE_TIMEOUT_S)
        except Exception as err:
            log.warning("zenoh: closing the session: %s", describe_error(err))

    # -- publishing -----------------------------------------------------------------------------

    def _matcher(self, key: str) -> Callable[[Any], None]:
        def on_status(status: Any) -> None:  # a Zenoh thread: one assignment, atomic
            self._matching[key] = bool(status.matching)

        return on_status

    def _on_item(self, item: Estimate | ZeroedFrame | SlipItem) -> None:
        """The hub's listener (the event loop's thread): queue the item's text, never wait."""
        if item.kind == "estimate":
            pub = self._estimate_pubs.get(item.sensor)
        elif item.kind == "slip":  # an event: every one goes out
            pub = self._slip_pubs.get(item.sensor)
        else:
            if self._frame_period is None:
                return
            now = time.monotonic()
            due = self._frame_due.get(item.sensor, 0.0)
            if now < due:
                return
            # Average rate frame_rate_hz despite jitter; no burst after a pause.
            period = self._frame_period
            self._frame_due[item.sensor] = due + period if now - due < period else now + period
            pub = self._frame_pubs.get(item.sensor)
        if pub is None or not self._matching.get(f"{self.prefix}/{item.sensor}/{item.kind}"):
            return
        self.sender.offer(pub, item.kind, self.encoder.text(item))

    async def _health_loop(self) -> None:
        """Publish the health document every second, and within a tick of a status change."""
        next_window = time.monotonic() + 1.0
        while True:
            try:
                now = time.monotonic()
                if now >= next_window:
                    self._put_max_1s = self.sender.take_max()
                    next_window = now + 1.0
                if self._health_pub is not None:
                    report = self.health.report()
                    summary = (report["status"], tuple((name, s["status"]) for name, s in
                                                       report["sensors"].items()))
                    if (summary != self._last_health
                            or now - self._last_health_at >= HEALTH_PERIOD_S):
                        self._last_health, self._last_health_at = summary, now
                        self.sender.offer(self._health_pub, "health", dumps(report))
            except Exception:  # a health glitch must not stop publishing it
                log.exception("zenoh: health publication failed")
            await asyncio.sleep(HEALTH_TICK_S)

    # -- queries --------------------------------------------------------------------------------

    def _latest_handler(self, sensor: str) -> Callable[[Any], None]:
        key = f"{self.prefix}/{sensor}/latest"

        def build() -> tuple[str | None, str]:
            est = self.daemon.hub.latest_estimate(sensor)
            if est is None:
                return None, f"no estimate published yet for sensor {sensor!r}"
            return self.encoder.text(est), ""

        return lambda query: self._answer(query, key, build)

    def _on_health_query(self, query: Any) -> None:
        self._answer(query, self.health_key, lambda: (dumps(self.health.report()), ""))

    def _answer(self, query: Any, key: str, build: Callable[[], tuple[str | None, str]]) -> None:
        """Answer ``query`` (a Zenoh thread) with what ``build`` makes on the event loop."""
        self.queries += 1
        with query:
            loop = self._loop
            fut: concurrent.futures.Future[tuple[str | None, str]] = concurrent.futures.Future()

            def run() -> None:
                try:
                    fut.set_result(build())
                except BaseException as err:
                    fut.set_exception(err)

            try:
                if loop is None or self.state != "open":
                    raise RuntimeError("the daemon is stopping")
                loop.call_soon_threadsafe(run)
                text, problem = fut.result(QUERY_TIMEOUT_S)
            except concurrent.futures.TimeoutError:
                text, problem = None, f"the daemon did not answer within {QUERY_TIMEOUT_S:g} s"
            except Exception as err:
                text, problem = None, str(err) or type(err).__name__
            try:
                if text is None:
                    self.query_errors += 1
                    query.reply_err(dumps({"detail": problem}), encoding=JSON)
                else:
                    query.reply(key, text, encoding=JSON)
            except Exception as err:  # the querier left, the session is closing
                log.debug("zenoh: reply on %s failed: %s", key, describe_error(err))

    # -- health ---------------------------------------------------------------------------------

    def stats(self) -> dict[str, Any]:
        """The ``zenoh`` section of the health document."""
        s = self.sender
        session = self.session
        peers = routers = 0
        zid = None
        if session is not None and self.state == "open":
            with contextlib.suppress(Exception):
                info = session.info
                zid = str(info.zid())
                peers, routers = len(info.peers_zid()), len(info.routers_zid())
        sent = dict(s.sent)
        puts = sum(sent.values())
        fronts = {front.name: front.stats() for front in self.fronts}
        return {
            "state": self.state,
            "mode": self.settings.mode,
            "prefix": self.prefix,
            "zid": zid,
            "peers": peers,
            "routers": routers,
            "published": sent,
            "dropped": s.dropped,
            "queued": len(s.items),
            "queue_size": s.maxsize,
            "put_errors": s.errors,
            "put_ms": {"mean": round(1e3 * s.put_s / puts, 4) if puts else None,
                       "max_1s": round(1e3 * max(self._put_max_1s, s.put_max_s), 4)},
            "queries": self.queries,
            "query_errors": self.query_errors,
            "last_error": self._open_error or s.last_error,
            **fronts,
        }


# --------------------------------------------------------------------------------------------
# Reading the bus: tactiled watch --zenoh


def prefix_of(key: str) -> tuple[str, str, str]:
    """``(prefix, sensor, kind)`` of a published key: ``P/<sensor>/estimate``, ``.../frame``
    or ``.../slip`` -> (P, sensor, kind); ``P/health`` -> (P, "", "health"); anything else
    -> ("", "", "")."""
    parts = key.rsplit("/", 2)
    if len(parts) == 3 and parts[2] in ("estimate", "frame", "slip"):
        return parts[0], parts[1], parts[2]
    if key.endswith("/health"):
        return key[: -len("/health")], "", "health"
    return "", "", ""


def tagged(prefix: str, text: str) -> str:
    """The message ``text`` with ``"prefix"`` as its first key (the rest byte for byte)."""
    return '{"prefix":' + json.dumps(prefix) + ("," + text[1:] if text != "{}" else "}")


def open_reader(settings: ZenohSettings) -> zenoh.Session:
    """A session for reading (never listens); ConfigError for bad settings."""
    return zenoh.open(session_config(settings, listen=False))


def watch(settings: ZenohSettings, key: str, out: TextIO, *, kinds: Iterable[str] = ("estimate",),
          sensors: Iterable[str] | None = None, count: int | None = None,
          stop: threading.Event | None = None) -> int:
    """Print every estimate (and frame or slip event, with ``kinds``) published under ``key``, one JSON
    object per line tagged with its daemon's ``prefix``, until ``count`` lines or ``stop``.
    Returns the exit code."""
    wanted_kinds = frozenset(kinds)
    wanted_sensors = None if sensors is None else frozenset(sensors)
    stop = stop or threading.Event()
    printed = 0
    lock = threading.Lock()

    def on_sample(sample: Any) -> None:
        nonlocal printed
        prefix, sensor, kind = prefix_of(str(sample.key_expr))
        if kind not in wanted_kinds or (wanted_sensors is not None
                                        and sensor not in wanted_sensors):
            return
        try:
            text = sample.payload.to_string()
        except ValueError:
            return
        with lock:
            if stop.is_set():
                return
            out.write(tagged(prefix, text) + "\n")
            out.flush()
            printed += 1
            if count is not None and printed >= count:
                stop.set()

    return listen_until(settings, key, on_sample, stop)


def listen_until(settings: ZenohSettings, key: str, on_sample: Callable[[Any], None],
                 stop: threading.Event) -> int:
    """Call ``on_sample`` for every sample published under ``key`` on a reader session until
    ``stop`` is set (the ``watch`` commands' loop); returns the exit code 0."""
    session = open_reader(settings)
    try:
        sub = session.declare_subscriber(key, zenoh.handlers.Callback(on_sample))
        try:
            while not stop.wait(0.2):
                pass
        finally:
            sub.undeclare()
    finally:
        session.close()
    return 0


def list_daemons(settings: ZenohSettings, key: str, timeout: float = 2.0) -> list[dict[str, Any]]:
    """The daemons whose liveliness token matches ``key``, each with its health summary:
    ``{"prefix", "status", "sensors": {name: status}}`` (status and sensors None when its
    health query went unanswered)."""
    session = open_reader(settings)
    try:
        # Peers found by scouting or gossip need a moment before their tokens are visible.
        time.sleep(min(timeout, 0.5))
        prefixes = sorted({str(reply.ok.key_expr) for reply in
                           session.liveliness().get(key, timeout=timeout) if reply.ok})
        out = []
        for prefix in prefixes:
            entry: dict[str, Any] = {"prefix": prefix, "status": None, "sensors": None}
            for reply in session.get(f"{prefix}/health", timeout=timeout):
                if reply.ok is None:
                    continue
                try:
                    doc = json.loads(reply.ok.payload.to_bytes())
                except ValueError:
                    continue
                entry["status"] = doc.get("status")
                entry["sensors"] = {name: s.get("status")
                                    for name, s in doc.get("sensors", {}).items()}
            out.append(entry)
        return out
    finally:
        session.close()

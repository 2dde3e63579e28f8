"""In-process fan-out of estimates and zeroed frames; the latest of each per sensor (REST cache).

Publishing never waits for a subscriber: each :class:`Subscription` has a bounded queue, and
when it is full the *oldest* item is dropped (and counted in ``sub.dropped``) to make room for
the new one, so a slow WebSocket client lags or loses old estimates but never holds up the
acquisition loop or the other subscribers.  All methods must be called from the event loop's
thread (the pipeline publishes from there).
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections import deque
from collections.abc import Callable, Iterable
from typing import Union

import numpy as np

from tactiled.errors import TactiledError
from tactiled.pipeline.estimate import Estimate, ZeroedFrame, zeroed_frame

log = logging.getLogger(__name__)

Item = Union[Estimate, ZeroedFrame]
KINDS = frozenset({"estimate", "frame", "slip"})
#: Items a listener sees unless it asks for the events too (``add_listener(..., events=True)``).
_STATE_KINDS = frozenset({"estimate", "frame"})


class SubscriptionClosed(TactiledError):
    """``Subscription.get()`` on a closed subscription with nothing left to deliver."""


class Subscription:
    """One subscriber's bounded queue; iterate it or ``await sub.get()``.

    ``sensors`` (None: all) and ``kinds`` filter what it receives.  ``dropped`` counts items
    thrown away because the subscriber fell ``maxsize`` behind; ``delivered`` those queued.
    After :meth:`close` (or the hub closing) the queued items can still be read, then
    ``get()`` raises :class:`SubscriptionClosed` and iteration stops.
    """

    def __init__(self, hub: Hub | None, sensors: frozenset[str] | None,
                 kinds: frozenset[str], maxsize: int) -> None:
        self._hub = hub
        self.sensors = sensors
        self.kinds = kinds
        self.maxsize = maxsize
        self.dropped = 0
        self.delivered = 0
        self.closed = False
        self._items: deque[Item] = deque()
        self._waiter: asyncio.Future[None] | None = None

    def wants(self, item: Item) -> bool:
        return item.kind in self.kinds and (self.sensors is None or item.sensor in self.sensors)

    def offer(self, item: Item) -> None:
        """Queue ``item`` without ever blocking (the hub's side); drops the oldest when full."""
        if self.closed:
            return
        if len(self._items) >= self.maxsize:
            self._items.popleft()
            self.dropped += 1
        self._items.append(item)
        self.delivered += 1
        self._wake()

    def _wake(self) -> None:
        waiter, self._waiter = self._waiter, None
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def qsize(self) -> int:
        """Items waiting to be read."""
        return len(self._items)

    def get_nowait(self) -> Item | None:
        """The oldest queued item, or None if there is none (raises if closed and empty)."""
        if self._items:
            return self._items.popleft()
        if self.closed:
            raise SubscriptionClosed("subscription closed")
        return None

    async def get(self) -> Item:
        """Wait for the next item; :class:`SubscriptionClosed` once closed and drained."""
        while not self._items:
            if self.closed:
                raise SubscriptionClosed("subscription closed")
            if self._waiter is None or self._waiter.done():
                self._waiter = asyncio.get_running_loop().create_future()
            await self._waiter  # a cancelled getter cancels it; the next get makes a new one
        return self._items.popleft()

    def close(self) -> None:
        """Stop receiving; wakes a pending :meth:`get`.  Idempotent."""
        if self.closed:
            return
        self.closed = True
        if self._hub is not None:
            self._hub._remove(self)
            self._hub = None
        self._wake()

    def __aiter__(self) -> Subscription:
        return self

    async def __anext__(self) -> Item:
        try:
            return await self.get()
        except SubscriptionClosed:
            raise StopAsyncIteration from None

    def __repr__(self) -> str:
        state = "closed" if self.closed else "open"
        return (f"<Subscription {state} sensors={sorted(self.sensors) if self.sensors else 'all'} "
                f"kinds={sorted(self.kinds)} queued={len(self._items)} dropped={self.dropped}>")


class Hub:
    """Fan-out of published items to subscribers, plus the latest item of each kind per sensor.

    ``sensor_names``, if given, is the set of valid sensor names: subscribing to another
    is a ``ValueError`` (a typo in a client's filter must not silently deliver nothing).
    """

    def __init__(self, sensor_names: Iterable[str] | None = None) -> None:
        self.sensor_names: frozenset[str] | None = (
            None if sensor_names is None else frozenset(sensor_names))
        self._subs: list[Subscription] = []
        self._listeners: list[Callable[[Item], None]] = []
        self._event_listeners: list[Callable[[Item], None]] = []
        self._latest_estimate: dict[str, Estimate] = {}
        #: a sensor's latest frame: its record, or the record's fields while nobody takes
        #: frames (:meth:`publish_frame`: built when :meth:`latest_frame` asks)
        self._latest_frame: dict[str, ZeroedFrame | tuple] = {}
        self._frame_takers = False  # a listener, or a subscription to frames
        self.published = {"estimate": 0, "frame": 0, "slip": 0}
        self.closed = False

    # -- subscribing ------------------------------------------------------------------------

    def subscribe(self, sensors: set[str] | frozenset[str] | None = None,
                  kinds: set[str] | frozenset[str] = frozenset({"estimate"}),
                  maxsize: int = 100) -> Subscription:
        """A new subscription to ``kinds`` ("estimate", "frame", "slip") of ``sensors`` (None:
        all); "slip" items are a 3-axis array's slip events (:mod:`tactiled.pipeline.shear_track`).

        ``maxsize`` (>= 1) bounds its queue; when full the oldest item is dropped.
        """
        kind_set = frozenset(kinds)
        if not kind_set or not kind_set <= KINDS:
            raise ValueError(f"kinds must be a non-empty subset of {sorted(KINDS)}, got "
                             f"{sorted(kind_set)}")
        if isinstance(maxsize, bool) or not isinstance(maxsize, int) or maxsize < 1:
            raise ValueError(f"maxsize must be a positive integer, got {maxsize!r}")
        sensor_set = None if sensors is None else frozenset(sensors)
        if sensor_set is not None and self.sensor_names is not None:
            unknown = sorted(sensor_set - self.sensor_names)
            if unknown:
                raise ValueError(f"unknown sensor(s) {', '.join(map(repr, unknown))}; known: "
                                 f"{', '.join(sorted(self.sensor_names))}")
        sub = Subscription(None if self.closed else self, sensor_set, kind_set, maxsize)
        if self.closed:
            sub.close()
        else:
            self._subs.append(sub)
            self._recount()
        return sub

    def _remove(self, sub: Subscription) -> None:
        try:
            self._subs.remove(sub)
        except ValueError:
            pass
        self._recount()

    def _recount(self) -> None:
        """Whether anyone takes zeroed frames as they are published (:meth:`publish_frame`)."""
        self._frame_takers = bool(self._listeners or self._event_listeners
                                  or any("frame" in s.kinds for s in self._subs))

    @property
    def subscriptions(self) -> tuple[Subscription, ...]:
        return tuple(self._subs)

    def add_listener(self, callback: Callable[[Item], None], *,
                     events: bool = False) -> Callable[[], None]:
        """Call ``callback(item)`` synchronously for every estimate and frame published (and
        every slip event with ``events``); returns a function that removes it.  For the CLI and
        tests, which must see every item: the callback runs inside the pipeline's loop, so it
        must be quick and must not raise (errors are logged).
        """
        listeners = self._event_listeners if events else self._listeners
        listeners.append(callback)
        self._recount()

        def remove() -> None:
            if callback in listeners:
                listeners.remove(callback)
                self._recount()

        return remove

    # -- publishing -------------------------------------------------------------------------

    def publish(self, item: Item) -> None:
        """Record ``item`` as the latest of its kind and sensor, and offer it to every
        interested subscriber.  Never blocks, never awaits."""
        if isinstance(item, Estimate):
            self._latest_estimate[item.sensor] = item
        elif isinstance(item, ZeroedFrame):
            self._latest_frame[item.sensor] = item
        self.published[item.kind] += 1
        for sub in self._subs:
            if sub.wants(item):
                sub.offer(item)
        if not (self._listeners or self._event_listeners):
            return
        for listeners in ((self._listeners, self._event_listeners)
                          if item.kind in _STATE_KINDS else (self._event_listeners,)):
            for callback in listeners:
                try:
                    callback(item)
                except Exception:  # a broken listener must not stop the pipeline
                    log.exception("hub listener %r failed", callback)

    def publish_frame(self, sensor: str, sensor_id: int, seq: int, device_time_us: int,
                      host_time: float, contact: bool, statistic: float, strain: np.ndarray,
                      stamp: float = math.nan, taxels: np.ndarray | None = None) -> None:
        """Publish a zeroed frame of these fields (:class:`ZeroedFrame`'s, in order): as
        ``publish(ZeroedFrame(...))``, but while no listener and no subscription takes frames,
        the record is built only if :meth:`latest_frame` asks for it (a frame path publishes
        up to 6000 a second, most of them read by nobody)."""
        if self._frame_takers:
            self.publish(zeroed_frame(sensor, sensor_id, seq, device_time_us, host_time, contact,
                                      statistic, strain, stamp, taxels))
            return
        self._latest_frame[sensor] = (sensor, sensor_id, seq, device_time_us, host_time, contact,
                                      statistic, strain, stamp, taxels)
        self.published["frame"] += 1

    def latest_estimate(self, sensor: str) -> Estimate | None:
        """The last estimate published for ``sensor`` (None before the first)."""
        return self._latest_estimate.get(sensor)

    def latest_frame(self, sensor: str) -> ZeroedFrame | None:
        """The last zeroed frame published for ``sensor`` (None before the first)."""
        item = self._latest_frame.get(sensor)
        if type(item) is tuple:  # (publish_frame's fields: the record, now)
            item = self._latest_frame[sensor] = zeroed_frame(*item)
        return item  # type: ignore[return-value]

    def stats(self) -> dict[str, object]:
        """Published counts and each subscription's queue and drops."""
        return {
            "published": dict(self.published),
            "subscribers": [
                {"sensors": None if s.sensors is None else sorted(s.sensors),
                 "kinds": sorted(s.kinds), "maxsize": s.maxsize, "queued": s.qsize(),
                 "delivered": s.delivered, "dropped": s.dropped}
                for s in self._subs
            ],
        }

    def close(self) -> None:
        """Close every subscription (their readers finish what is queued, then stop)."""
        self.closed = True
        for sub in list(self._subs):
            sub.close()
        self._subs.clear()

"""A thread that calls ``put`` for queued items, in order, so the event loop never waits.

The Zenoh front ends (:mod:`tactiled_service.bus`, :mod:`tactiled_service.ros2.node`) and the
MCAP recorder hand their items to one each: its queue is bounded, and when it is full the
oldest item is dropped and counted.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import deque
from typing import Any

#: Items the sender may fall behind before the oldest are dropped: 1/3 s of three 1 kHz
#: sensors, far more than a put ever stalls (1 ms before Zenoh drops, 50 ms for a fragment).
QUEUE_SIZE = 1024


class Sender:
    """A thread that calls ``put`` for the queued ``(publisher, text)`` pairs, in order.

    :meth:`offer` never blocks: beyond ``maxsize`` queued items it drops the oldest and
    counts it in ``dropped``.  Counters are written by one thread each and read anywhere
    (plain ints under the GIL: a reader may see a value one update old).
    """

    def __init__(self, maxsize: int = QUEUE_SIZE,
                 kinds: tuple[str, ...] = ("estimate", "frame", "health"),
                 name: str = "tactiled-zenoh-send") -> None:
        self.maxsize = maxsize
        self.items: deque[tuple[Any, str, Any]] = deque()
        self.dropped = 0  # by the event loop's thread
        self.sent: dict[str, int] = dict.fromkeys(kinds, 0)  # by the sender
        self.errors = 0
        self.last_error = ""
        self.put_s = 0.0  # total time in put, s
        self.put_max_s = 0.0  # longest put since the last :meth:`take_max`, s
        self._wake = threading.Event()
        self._stop = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def offer(self, publisher: Any, kind: str, text: Any) -> None:
        """Queue one ``publisher.put(text)`` (from the event loop's thread); ``text`` is
        whatever the publisher puts (the JSON text, or an item it converts on this thread)."""
        items = self.items
        items.append((publisher, kind, text))
        if len(items) > self.maxsize:
            # Dropping here rather than with deque(maxlen) counts exactly what is lost; if the
            # sender took one meanwhile, this still removes one item that was never sent.
            with contextlib.suppress(IndexError):
                items.popleft()
                self.dropped += 1
        if not self._wake.is_set():
            self._wake.set()

    def _run(self) -> None:
        items, wake, clock = self.items, self._wake, time.perf_counter
        while True:
            wake.wait()
            wake.clear()  # before draining: an offer after the last popleft sets it again
            if self._stop:
                return
            while items:
                try:
                    publisher, kind, text = items.popleft()
                except IndexError:
                    break
                t0 = clock()
                try:
                    publisher.put(text)
                except Exception as err:  # a closed session, an undeclared publisher
                    self.errors += 1
                    self.last_error = f"{type(err).__name__}: {err}"
                    continue
                dt = clock() - t0
                self.put_s += dt
                if dt > self.put_max_s:
                    self.put_max_s = dt
                self.sent[kind] = self.sent.get(kind, 0) + 1  # a kind not listed counts too
                if self._stop:
                    return

    def take_max(self) -> float:
        """The longest put since the last call (s), and start a new window."""
        longest, self.put_max_s = self.put_max_s, 0.0
        return longest

    def stop(self, timeout: float = 2.0) -> None:
        """Stop after the put in progress; what is still queued is not sent."""
        self._stop = True
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(timeout)
        self.items.clear()

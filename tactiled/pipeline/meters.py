"""Sliding-window meters for the stats: event rates and mean values over the last second."""

from __future__ import annotations

from collections import deque


class RateMeter:
    """Events per second over the last ``window`` seconds (monotonic timestamps)."""

    def __init__(self, window: float = 1.0) -> None:
        self.window = window
        self._times: deque[float] = deque()

    def tick(self, now: float) -> None:
        """Count one event at ``now`` (s)."""
        self._times.append(now)
        self._prune(now)

    def _prune(self, now: float) -> None:
        edge = now - self.window
        times = self._times
        while times and times[0] <= edge:
            times.popleft()

    def rate(self, now: float) -> float:
        """Events per second in ``(now - window, now]``."""
        self._prune(now)
        return len(self._times) / self.window


class WindowMean:
    """Mean and maximum of values recorded in the last ``window`` seconds; ``last`` value."""

    def __init__(self, window: float = 1.0) -> None:
        self.window = window
        self.last: float | None = None
        self._items: deque[tuple[float, float]] = deque()
        self._sum = 0.0

    def add(self, now: float, value: float) -> None:
        self.last = value
        self._items.append((now, value))
        self._sum += value
        self._prune(now)

    def _prune(self, now: float) -> None:
        edge = now - self.window
        items = self._items
        while items and items[0][0] <= edge:
            self._sum -= items.popleft()[1]
        if not items:
            self._sum = 0.0  # no drift from float cancellation

    def mean(self, now: float) -> float | None:
        self._prune(now)
        return self._sum / len(self._items) if self._items else None

    def max(self, now: float) -> float | None:
        self._prune(now)
        return max(v for _, v in self._items) if self._items else None

    def summary(self, now: float, digits: int = 3) -> dict[str, float | None]:
        """``{"last", "mean_1s", "max_1s"}`` rounded to ``digits``."""
        def r(x: float | None) -> float | None:
            return None if x is None else round(x, digits)

        return {"last": r(self.last), "mean_1s": r(self.mean(now)), "max_1s": r(self.max(now))}

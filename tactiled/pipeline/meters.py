"""Meters for the stats: event rates and mean values over the last second (sliding windows),
and cumulative latency histograms (for the metrics endpoint)."""

from __future__ import annotations

import bisect
import math
from collections import deque


class RateMeter:
    """Events per second over the last ``window`` seconds (monotonic timestamps)."""

    def __init__(self, window: float = 1.0) -> None:
        self.window = window
        self._times: deque[float] = deque()

    def tick(self, now: float) -> None:
        """Count one event at ``now`` (s)."""
        times = self._times
        times.append(now)
        edge = now - self.window  # _prune, inlined: this runs for every frame
        while times and times[0] <= edge:
            times.popleft()

    def tick_many(self, now: float, n: int) -> None:
        """Count ``n`` events at ``now`` (s): the frames of one read."""
        times = self._times
        if n == 1:
            times.append(now)
        else:
            times.extend([now] * n)
        edge = now - self.window
        while times and times[0] <= edge:
            times.popleft()

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
        items = self._items
        items.append((now, value))
        self._sum += value
        if items[0][0] <= now - self.window:  # (checked here: this runs for every estimate)
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


#: Upper bounds (s) of the latency histograms' buckets: 0.1 ms to 2.5 s, roughly x2.5 apart
#: (a fit takes ~1 ms, a gated estimate ~0.1 ms; ``fit.timeout`` is 1 s by default).
LATENCY_BUCKETS_S = (0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1,
                     0.25, 0.5, 1.0, 2.5)


class Histogram:
    """Counts of values at or below each bucket bound (the last bucket is +Inf), their sum and
    count: what a Prometheus histogram exposes, kept by the pipeline without depending on a
    metrics library (the service turns it into ``*_bucket``, ``*_sum``, ``*_count``).  Never
    reset; ``observe`` costs one bisection."""

    def __init__(self, bounds: tuple[float, ...] = LATENCY_BUCKETS_S) -> None:
        if list(bounds) != sorted(set(bounds)) or not bounds:
            raise ValueError(f"bucket bounds must be increasing, got {bounds!r}")
        self.bounds = tuple(float(b) for b in bounds)
        self._counts = [0] * (len(self.bounds) + 1)  # per bucket, the last one +Inf
        self.sum = 0.0
        self.count = 0

    def observe(self, value: float) -> None:
        self._counts[bisect.bisect_left(self.bounds, value)] += 1
        self.sum += value
        self.count += 1

    def cumulative(self) -> list[tuple[float, int]]:
        """``[(upper bound, observations <= it), ..., (inf, count)]``."""
        out, total = [], 0
        for bound, n in zip((*self.bounds, math.inf), self._counts):
            total += n
            out.append((bound, total))
        return out

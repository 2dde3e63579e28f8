"""Progress of a long job on stderr, never on stdout (which carries the machine-readable
output): a bar redrawn in place on a terminal, plain lines now and then elsewhere (a log file
gets a readable line every ``interval`` seconds, not a stream of carriage returns).  No
dependency."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """``step(n)`` after each ``n`` units of ``total`` are done; ``enabled`` None means "when
    the stream is a terminal".  On a terminal the bar is redrawn at most 5 times a second; on
    anything else a line is written every ``interval`` seconds (so a job shorter than that
    writes nothing until :meth:`finish`)."""

    def __init__(self, total: int, label: str, enabled: bool | None = None, *,
                 unit: str = "", interval: float = 10.0, stream: TextIO | None = None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.enabled = self.tty if enabled is None else enabled
        self.total, self.label, self.unit, self.done = max(total, 1), label, unit, 0
        self.interval = interval
        self._t0 = time.monotonic()
        self._last = self._t0 if not self.tty else 0.0  # a log's first line after ``interval``

    def elapsed(self) -> float:
        """Seconds since the start."""
        return time.monotonic() - self._t0

    def step(self, n: int = 1) -> None:
        self.done += n
        if not self.enabled:
            return
        now = time.monotonic()
        if self.tty:
            if now - self._last > 0.2 or self.done >= self.total:
                self._last = now
                frac = min(self.done / self.total, 1.0)
                eta = (now - self._t0) / frac * (1 - frac) if frac > 0 else 0.0
                bar = "#" * int(30 * frac)
                self.stream.write(f"\r{self.label:<40.40} [{bar:<30}] {100 * frac:5.1f} % eta {eta:5.0f} s")
                if self.done >= self.total:
                    self.stream.write("\n")
                self.stream.flush()
        elif now - self._last >= self.interval and self.done < self.total:
            self._last = now
            self.stream.write(f"{self.label}: {self.status(now)}\n")
            self.stream.flush()

    def status(self, now: float | None = None) -> str:
        """``done/total (pct %), rate unit/s, eta`` as a phrase."""
        elapsed = (time.monotonic() if now is None else now) - self._t0
        rate = self.done / elapsed if elapsed > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else 0.0
        unit = f" {self.unit}" if self.unit else ""
        return (f"{self.done}/{self.total}{unit} ({100 * self.done / self.total:.0f} %), "
                f"{rate:,.0f}{unit}/s, eta {eta:.0f} s")

    def finish(self, message: str) -> None:
        """A last line (when enabled), e.g. the totals."""
        if self.enabled:
            self.stream.write(f"{self.label}: {message}\n")
            self.stream.flush()

"""``GET /v1/health``: one status per sensor, one overall, with the counters behind them.

A sensor is, worst first, ERROR (source down or silent, no first frame, daemon not running),
STALE (frames but no estimate for ``stale_after_s``), DEGRADED (below its nominal rate),
WARN (connecting, or error counters grew lately) or OK; the overall ``status`` is the worst
sensor's.  The report also gives each sensor's read backlog and the resident memory of the
daemon and of every fit worker.
"""
# The rules in full:
# * ERROR: the source is down, ended, or connected but silent for silent_after_s (0.5 s by
#   default, so a device that stops talking shows within a second); or no first frame
#   startup_grace_s after start; or the daemon is not running;
# * STALE: frames arrive but no estimate was published for stale_after_s (every worker busy,
#   hung or restarting), so what clients see is old;
# * DEGRADED: the sensor has a nominal rate (rate_hz) and delivered less than RATE_TOLERANCE
#   (0.9) of it over the last second, for more than RATE_GRACE_S (2 s) on end;
# * WARN: connecting (the source's first open under way; a driver's open times out into an
#   error); or data flows but error counters (CRC and other rejected chunks, lost or duplicated
#   frames, fit errors, lost fits, worker restarts, source errors) grew within warn_window_s.
# Counter growth, and the share of frames superseded over SHARE_WINDOW_S, are judged against
# samples kept by HealthMonitor.sample, which the server calls every second.

from __future__ import annotations

import math
import os
import time
from collections import deque
from typing import Any

from tactiled import __version__
from tactiled.heapstats import rss_mb
from tactiled.pipeline import Daemon
from tactiled_service.options import ServiceOptions

#: Wire chunks the decoder rejects, by its counter name (parse_errors: the vendor formats').
REJECTED_KEYS = ("crc_errors", "length_errors", "version_errors", "cobs_errors", "truncated",
                 "oversize", "parse_errors")
from tactiled_service.stream import StreamManager

SEVERITY = {"OK": 0, "WARN": 1, "DEGRADED": 2, "STALE": 3, "ERROR": 4}

#: A sensor is DEGRADED when its frame rate over the last second stays below this fraction of
#: its nominal ``rate_hz`` ...
RATE_TOLERANCE = 0.9
#: ... for longer than this (s).  The margin keeps a sensor at its nominal rate from flickering
#: (a 1 s count of a 1 kHz stream varies by a frame or two); the grace rides out a hiccup.
RATE_GRACE_S = 2.0
#: The share of frames superseded (replaced while waiting for a fit) is over this window (s).
SHARE_WINDOW_S = 10.0
#: Counters remembered by the samples besides the warn counters.
_SHARE_COUNTERS = ("frames", "superseded_frames")

#: Counters whose growth means trouble, with the words used to report it.
WARN_COUNTERS = {
    "crc_errors": "CRC errors",
    "rejected_chunks": "corrupt chunks",
    "lost_frames": "lost frames",
    "duplicated_frames": "duplicated frames",
    "fit_errors": "fit errors",
    "fits_lost": "lost fits",
    "worker_restarts": "worker restarts",
    "source_errors": "source errors",
    "pipeline_errors": "pipeline errors",
    "wrong_sensor": "frames from the wrong sensor",
}


def _rnd(x: float | None, digits: int = 3) -> float | None:
    return None if x is None else round(x, digits)


def _mb(pid: int | None) -> float | None:
    return None if pid is None else _rnd(rss_mb(pid))


class HealthMonitor:
    """Builds health reports for ``daemon`` and the stream ``manager``."""

    def __init__(self, daemon: Daemon, manager: StreamManager, options: ServiceOptions) -> None:
        self.daemon = daemon
        self.manager = manager
        self.options = options
        #: The Zenoh front end (tactiled_service.bus.Bus), set by the server when enabled.
        self.bus: Any = None
        self._history: deque[tuple[float, dict[str, dict[str, int]]]] = deque()
        self._below_since: dict[str, float] = {}  # sensor -> since when it is under its rate

    # -- counters -------------------------------------------------------------------------------

    def counters(self, name: str) -> dict[str, Any]:
        """The counters and rates of sensor ``name``, flattened and renamed for the API."""
        st = self.daemon.sensor_stats(name)
        est = self.daemon.hub.latest_estimate(name)
        now = time.monotonic()
        return {
            "connected": st.connected,
            "finished": st.finished,
            "last_error": st.last_error,
            "frame_rate_hz": float(st.frame_rate_hz),
            "fit_rate_hz": float(st.fit_rate_hz),
            "tracked_rate_hz": float(st.tracked_rate_hz),
            "frames": st.frames,
            "crc_errors": st.decoded("crc_errors"),
            "rejected_chunks": sum(st.decoded(k) for k in REJECTED_KEYS),
            "lost_frames": st.decoded("lost"),
            "duplicated_frames": st.decoded("duplicated"),
            "device_restarts": st.decoded("restarts"),
            "superseded_frames": st.superseded,
            "published": st.published,
            "fitted": st.fitted,
            "fit_errors": st.fit_errors,
            "fits_lost": st.fit_failed,
            "stale_dropped": st.stale_dropped,
            "tracked": st.tracked,
            "predicted": st.predicted,
            "track_resets": st.track_resets,
            "track_skipped": st.track_skipped,
            "worker_restarts": st.worker_restarts,
            "source_errors": st.source_errors,
            "reconnects": st.reconnects,
            "pipeline_errors": st.errors,
            "wrong_sensor": st.wrong_sensor,
            "last_frame_age_s": _rnd(st.last_frame_age_s),
            "read_backlog_bytes": st.read_backlog_bytes,
            "read_backlog_peak_bytes": st.read_backlog_peak_bytes,
            "rate_hz": st.rate_hz,
            "last_estimate_age_s": None if est is None else _rnd(now - est.published_time),
            "latency_ms": st.latency_ms,
            "worker_ms": st.worker_ms,
            "model": st.model,
            "in_contact": st.in_contact,
        }

    def sample(self) -> None:
        """Remember the warn counters, frames and superseded frames now (the server calls this
        every second), and follow each sensor's rate against its nominal one."""
        now = time.monotonic()
        snap = {}
        for name in self.daemon.sensors:
            c = self.counters(name)
            self._track_rate(name, c, now)
            snap[name] = {k: int(c[k]) for k in (*WARN_COUNTERS, *_SHARE_COUNTERS)}
        self._history.append((now, snap))
        edge = now - max(self.options.warn_window_s, SHARE_WINDOW_S)
        while len(self._history) > 1 and self._history[1][0] <= edge:
            self._history.popleft()

    def _baseline(self, name: str, window: float, now: float) -> dict[str, int] | None:
        """The sample at the start of the last ``window`` s (the newest one at or before its
        edge, else the oldest kept), None before the first sample."""
        if not self._history:
            return None
        edge = now - window
        chosen = self._history[0][1]
        for t, snap in self._history:
            if t > edge:
                break
            chosen = snap
        return chosen.get(name, {})

    def _growth(self, name: str, current: dict[str, Any]) -> dict[str, int]:
        before = self._baseline(name, self.options.warn_window_s, time.monotonic())
        if before is None:
            return {}
        return {k: current[k] - before.get(k, 0) for k in WARN_COUNTERS
                if current[k] > before.get(k, 0)}

    def superseded_share(self, name: str, current: dict[str, Any]) -> float | None:
        """Share of the frames of the last ``SHARE_WINDOW_S`` that were superseded while
        waiting for a fit (latest frame wins), None without frames in the window."""
        before = self._baseline(name, SHARE_WINDOW_S, time.monotonic())
        if before is None or "frames" not in before:
            return None
        frames = current["frames"] - before["frames"]
        if frames <= 0:
            return None
        return round(max(0, current["superseded_frames"] - before["superseded_frames"])
                     / frames, 4)

    def _track_rate(self, name: str, c: dict[str, Any], now: float) -> None:
        """Note since when the sensor delivers under ``RATE_TOLERANCE`` of its nominal rate."""
        nominal = c.get("rate_hz")
        if nominal and c["frame_rate_hz"] < RATE_TOLERANCE * nominal:
            self._below_since.setdefault(name, now)
        else:
            self._below_since.pop(name, None)

    # -- status ---------------------------------------------------------------------------------

    def sensor_status(self, name: str, c: dict[str, Any]) -> tuple[str, str]:
        """(status, reason) of one sensor from its counters ``c``."""
        o = self.options
        daemon = self.daemon
        if daemon.state != "running":
            return "ERROR", f"daemon {daemon.state}"
        if c["finished"]:
            return "ERROR", "source ended" + (f": {c['last_error']}" if c["last_error"] else "")
        if not c["connected"]:
            if not c["last_error"] and c["last_frame_age_s"] is None:
                # its first open is under way (a driver's open times out into an error)
                return "WARN", "connecting"
            return "ERROR", "disconnected" + (f": {c['last_error']}" if c["last_error"] else "")
        age = c["last_frame_age_s"]
        if age is None:
            up = 0.0 if daemon.started_at is None else time.monotonic() - daemon.started_at
            if up < o.startup_grace_s:
                return "WARN", "waiting for the first frame"
            return "ERROR", f"connected but no frame received in {up:.1f} s"
        if age > o.silent_after_s:
            return "ERROR", f"connected but silent: no frame for {age:.1f} s"
        est_age = c["last_estimate_age_s"]
        if est_age is None or est_age > o.stale_after_s:
            shown = "none yet" if est_age is None else f"the last is {est_age:.1f} s old"
            return "STALE", f"frames arrive but no estimate is published ({shown})"
        below = self._below_since.get(name)
        held = None if below is None else time.monotonic() - below
        if held is not None and held > RATE_GRACE_S:
            # Shown truncated, not rounded: 1.96 s must not read as the 2 s grace.
            return "DEGRADED", (
                f"frame rate {c['frame_rate_hz']:.0f} Hz, below the nominal {c['rate_hz']:g} "
                f"Hz (under {RATE_TOLERANCE:.0%} of it) for {math.floor(held * 10) / 10:.1f} s")
        growth = self._growth(name, c)
        if growth:
            words = ", ".join(f"{n} {WARN_COUNTERS[k]}" for k, n in growth.items())
            return "WARN", f"{words} in the last {o.warn_window_s:g} s"
        return "OK", ""

    def report(self) -> dict[str, Any]:
        """The ``GET /v1/health`` document (schema: ``schemas.HealthResponse``)."""
        sensors: dict[str, dict[str, Any]] = {}
        worst = "OK"
        now = time.monotonic()
        for name in self.daemon.sensors:
            c = self.counters(name)
            self._track_rate(name, c, now)
            status, reason = self.sensor_status(name, c)
            if SEVERITY[status] > SEVERITY[worst]:
                worst = status
            sensors[name] = {"status": status, "reason": reason, **c,
                             "superseded_share_10s": self.superseded_share(name, c)}
        if not sensors:
            worst = "ERROR"
        stats = self.daemon.stats()
        workers = stats["workers"]
        return {
            "status": worst,
            "version": __version__,
            "state": self.daemon.state,
            "uptime_s": _rnd(stats["uptime_s"]),
            "sensors": sensors,
            "workers": {
                "size": workers.get("size"),
                "restarts": workers.get("restarts"),
                "restarts_by_reason": workers.get("restarts_by_reason"),
                "recycles": workers.get("recycles", 0),
                "fits": workers.get("fits"),
                "states": [w.get("state") for w in workers.get("workers", [])],
                "processes": [{"slot": w.get("slot"), "pid": w.get("pid"),
                               "state": w.get("state"), "fits": w.get("fits"),
                               "rss_mb": _mb(w.get("pid"))}
                              for w in workers.get("workers", [])],
            },
            "process": {"pid": os.getpid(), "rss_mb": _mb(os.getpid())},
            "subscribers": self.manager.stats(),
            "zenoh": None if self.bus is None else self.bus.stats(),
        }

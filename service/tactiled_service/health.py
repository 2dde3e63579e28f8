"""``GET /v1/health``: one status per sensor, one overall, with the counters behind them.

A sensor is, worst first:

* ``ERROR``: its source is down, ended, or connected but silent for ``silent_after_s``
  (0.5 s by default, so a device that stops talking shows within a second); or no first frame
  ``startup_grace_s`` after start; or the daemon is not running;
* ``STALE``: frames arrive but no estimate was published for ``stale_after_s`` (fits are not
  coming back: every worker busy, hung or restarting), so what clients see is old;
* ``WARN``: data flows, but error counters (CRC and other rejected chunks, lost or duplicated
  frames, fit errors, lost fits, worker restarts, source errors) grew within the last
  ``warn_window_s``;
* ``OK`` otherwise.

The overall ``status`` is the worst sensor's.  Counter growth is judged against samples kept
by :meth:`HealthMonitor.sample`, which the server calls every second.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Any

from tactiled import __version__
from tactiled.pipeline import Daemon
from tactiled_service.options import ServiceOptions
from tactiled_service.stream import StreamManager

SEVERITY = {"OK": 0, "WARN": 1, "STALE": 2, "ERROR": 3}

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


class HealthMonitor:
    """Builds health reports for ``daemon`` and the stream ``manager``."""

    def __init__(self, daemon: Daemon, manager: StreamManager, options: ServiceOptions) -> None:
        self.daemon = daemon
        self.manager = manager
        self.options = options
        #: The Zenoh front end (tactiled_service.bus.Bus), set by the server when enabled.
        self.bus: Any = None
        self._history: deque[tuple[float, dict[str, dict[str, int]]]] = deque()

    # -- counters -------------------------------------------------------------------------------

    def counters(self, name: str) -> dict[str, Any]:
        """The counters and rates of sensor ``name``, flattened and renamed for the API."""
        st = self.daemon.stats(name)
        dec = st.get("decoder", {})
        rejected = sum(int(dec.get(k, 0)) for k in ("crc_errors", "length_errors",
                                                    "version_errors", "cobs_errors",
                                                    "truncated", "oversize"))
        est = self.daemon.hub.latest_estimate(name)
        now = time.monotonic()
        return {
            "connected": bool(st["connected"]),
            "finished": bool(st["finished"]),
            "last_error": st.get("last_error") or "",
            "frame_rate_hz": float(st["frame_rate_hz"]),
            "fit_rate_hz": float(st["fit_rate_hz"]),
            "frames": int(st["frames"]),
            "crc_errors": int(dec.get("crc_errors", 0)),
            "rejected_chunks": rejected,
            "lost_frames": int(dec.get("lost", 0)),
            "duplicated_frames": int(dec.get("duplicated", 0)),
            "device_restarts": int(dec.get("restarts", 0)),
            "superseded_frames": int(st["superseded"]),
            "published": int(st["published"]),
            "fitted": int(st["fitted"]),
            "fit_errors": int(st["fit_errors"]),
            "fits_lost": int(st["fit_failed"]),
            "stale_dropped": int(st["stale_dropped"]),
            "worker_restarts": int(st["worker_restarts"]),
            "source_errors": int(st["source_errors"]),
            "reconnects": int(st["reconnects"]),
            "pipeline_errors": int(st["errors"]),
            "wrong_sensor": int(st["wrong_sensor"]),
            "last_frame_age_s": _rnd(st["last_frame_age_s"]),
            "last_estimate_age_s": None if est is None else _rnd(now - est.published_time),
            "latency_ms": st.get("latency_ms"),
            "worker_ms": st.get("worker_ms"),
            "model": st.get("model"),
            "in_contact": bool(st.get("in_contact")),
        }

    def sample(self) -> None:
        """Remember the warn counters now (the server calls this every second)."""
        now = time.monotonic()
        snap = {name: {k: int(self.counters(name)[k]) for k in WARN_COUNTERS}
                for name in self.daemon.sensors}
        self._history.append((now, snap))
        edge = now - self.options.warn_window_s
        while len(self._history) > 1 and self._history[1][0] <= edge:
            self._history.popleft()

    def _growth(self, name: str, current: dict[str, Any]) -> dict[str, int]:
        if not self._history:
            return {}
        _, oldest = self._history[0]
        before = oldest.get(name, {})
        return {k: current[k] - before.get(k, 0) for k in WARN_COUNTERS
                if current[k] > before.get(k, 0)}

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
        growth = self._growth(name, c)
        if growth:
            words = ", ".join(f"{n} {WARN_COUNTERS[k]}" for k, n in growth.items())
            return "WARN", f"{words} in the last {o.warn_window_s:g} s"
        return "OK", ""

    def report(self) -> dict[str, Any]:
        """The ``GET /v1/health`` document (schema: ``schemas.HealthResponse``)."""
        sensors: dict[str, dict[str, Any]] = {}
        worst = "OK"
        for name in self.daemon.sensors:
            c = self.counters(name)
            status, reason = self.sensor_status(name, c)
            if SEVERITY[status] > SEVERITY[worst]:
                worst = status
            sensors[name] = {"status": status, "reason": reason, **c}
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
                "fits": workers.get("fits"),
                "states": [w.get("state") for w in workers.get("workers", [])],
            },
            "subscribers": self.manager.stats(),
            "zenoh": None if self.bus is None else self.bus.stats(),
        }

"""The health rules (OK / WARN / STALE / ERROR) on made-up counters: each rule in isolation."""

from __future__ import annotations

import dataclasses
import time
from types import SimpleNamespace
from typing import Any

import pytest

from tactiled.pipeline.sensor_stats import SensorStats
from tactiled_service.health import HealthMonitor
from tactiled_service.options import ServiceOptions


def sensor_stats(**changes: Any) -> dict[str, Any]:
    """A sensor's stats' fields: every counter at rest but those ``changes`` sets."""
    st: dict[str, Any] = {
        "sensor": "f", "sensor_id": 1, "url": "sim://", "disconnects": 0,
        "tracked_rate_hz": 0.0, "read_backlog_bytes": 0, "read_backlog_peak_bytes": 0,
        "fits_budget_spent": 0, "learned_state": {}, "skipped": {}, "reuse_refused": 0, "track": True,
        "tracked": 0, "track_resets": 0, "track_skipped": 0, "predicted": 0,
        "relinearized": 0, "relinearize_lost": 0, "drift_followed": 0, "pressed_elsewhere": 0,
        "hysteresis": None, "pending": 0, "in_hand": 0, "bad_shape": 0, "nonfinite_frames": 0,
        "waiting": False, "in_flight": False, "rate_hz": None, "recorded": 0,
        "record_errors": 0, "shear": None,
        "connected": True, "finished": False, "last_error": "", "frame_rate_hz": 1000.0,
        "fit_rate_hz": 30.0, "frames": 5000, "superseded": 10, "published": 4990,
        "fitted": 100, "fit_errors": 0, "fit_failed": 0, "stale_dropped": 0,
        "worker_restarts": 0, "source_errors": 0, "reconnects": 0, "errors": 0,
        "wrong_sensor": 0, "last_frame_age_s": 0.001, "latency_ms": {}, "worker_ms": {},
        "model": "auto", "in_contact": False,
        "decoder": {"crc_errors": 0, "length_errors": 0, "version_errors": 0,
                    "cobs_errors": 0, "truncated": 0, "oversize": 0, "lost": 0,
                    "duplicated": 0, "restarts": 0},
    }
    decoder = changes.pop("decoder", {})
    st.update(changes)
    st["decoder"] = {**st["decoder"], **decoder}
    return st


class FakeDaemon:
    def __init__(self, estimate_age: float | None = 0.001, state: str = "running",
                 uptime: float = 100.0, **stats: Any) -> None:
        self.state = state
        self.started_at = time.monotonic() - uptime
        self.sensors = {"f": None}
        self._stats = sensor_stats(**stats)
        est = (None if estimate_age is None
               else SimpleNamespace(published_time=time.monotonic() - estimate_age))
        self.hub = SimpleNamespace(latest_estimate=lambda name: est)

    def sensor_stats(self, name: str) -> SensorStats:
        # a mock daemon: a counter the rules do not read is 0
        return SensorStats(**{f.name: self._stats.get(f.name, 0)
                              for f in dataclasses.fields(SensorStats)})

    def stats(self) -> dict[str, Any]:
        return {"uptime_s": 100.0, "workers": {"size": 1, "restarts": 0, "workers": []}}


class FakeManager:
    def stats(self) -> dict[str, Any]:
        return {"count": 0, "limit": 64, "refused": {}, "stalled": 0, "clients": []}


def status(daemon: FakeDaemon, **options: Any) -> tuple[str, str, str]:
    mon = HealthMonitor(daemon, FakeManager(), ServiceOptions(**options))  # type: ignore[arg-type]
    report = mon.report()
    s = report["sensors"]["f"]
    return report["status"], s["status"], s["reason"]


def test_ok():
    assert status(FakeDaemon()) == ("OK", "OK", "")


@pytest.mark.parametrize("daemon,words", [
    (FakeDaemon(connected=False, last_error="port vanished"), "disconnected: port vanished"),
    (FakeDaemon(finished=True), "source ended"),
    (FakeDaemon(last_frame_age_s=0.6), "silent"),
    (FakeDaemon(state="stopping"), "daemon stopping"),
    (FakeDaemon(last_frame_age_s=None, uptime=10.0, frames=0), "no frame received"),
])
def test_error(daemon, words):
    overall, st, reason = status(daemon)
    assert (overall, st) == ("ERROR", "ERROR") and words in reason


def test_first_frame_grace_is_warn():
    overall, st, reason = status(FakeDaemon(last_frame_age_s=None, uptime=0.5, frames=0))
    assert st == "WARN" and "first frame" in reason


def test_stale_when_frames_arrive_but_estimates_do_not():
    overall, st, reason = status(FakeDaemon(estimate_age=1.5))
    assert (overall, st) == ("STALE", "STALE") and "1.5 s old" in reason


def test_warn_when_error_counters_grow_within_the_window():
    daemon = FakeDaemon()
    mon = HealthMonitor(daemon, FakeManager(),  # type: ignore[arg-type]
                        ServiceOptions(warn_window_s=10))
    mon.sample()
    daemon._stats["decoder"]["crc_errors"] = 3
    daemon._stats["worker_restarts"] = 1
    report = mon.report()
    s = report["sensors"]["f"]
    assert report["status"] == "WARN" and s["status"] == "WARN"
    assert "3 CRC errors" in s["reason"] and "1 worker restarts" in s["reason"]
    assert s["crc_errors"] == 3 and s["rejected_chunks"] == 3
    # Old news once the window has passed: samples older than it are forgotten.
    mon.options = ServiceOptions(warn_window_s=0.05)
    mon.sample()
    time.sleep(0.1)
    mon.sample()
    assert mon.report()["sensors"]["f"]["status"] == "OK"


def test_degraded_below_the_nominal_rate_only_after_the_grace():
    daemon = FakeDaemon(rate_hz=1000.0, frame_rate_hz=850.0)
    mon = HealthMonitor(daemon, FakeManager(), ServiceOptions())  # type: ignore[arg-type]
    s = mon.report()["sensors"]["f"]
    assert s["status"] == "OK"  # just went under: within the 2 s grace
    mon._below_since["f"] -= 2.5  # as if it had been under for 2.5 s
    report = mon.report()
    s = report["sensors"]["f"]
    assert report["status"] == s["status"] == "DEGRADED"
    assert "frame rate 850 Hz, below the nominal 1000 Hz" in s["reason"]
    # At 0.9 of the nominal rate or above it is fine again, and the clock restarts.
    daemon._stats["frame_rate_hz"] = 905.0
    assert mon.report()["sensors"]["f"]["status"] == "OK"
    daemon._stats["frame_rate_hz"] = 850.0
    assert mon.report()["sensors"]["f"]["status"] == "OK"


def test_no_nominal_rate_no_judgement():
    assert status(FakeDaemon(frame_rate_hz=3.0))[1] == "OK"


def test_superseded_share_over_the_window():
    daemon = FakeDaemon(frames=1000, superseded=100)
    mon = HealthMonitor(daemon, FakeManager(), ServiceOptions())  # type: ignore[arg-type]
    assert mon.report()["sensors"]["f"]["superseded_share_10s"] is None  # no sample yet
    mon.sample()
    daemon._stats.update(frames=2000, superseded=350)
    assert mon.report()["sensors"]["f"]["superseded_share_10s"] == 0.25

"""The REST endpoints against a real server: health, sensors, latest estimate and frame, tare,
config, version, OpenAPI, and precise 4xx answers."""

from __future__ import annotations

import asyncio
import json
import time
from typing import ClassVar

import pytest
from svc_helpers import FIT_LINE_KEYS, http, sim_settings, wait_for

from tactiled_drivers.sim import SimSource


def test_health_reports_status_rates_and_counters(shared_server):
    def ok() -> bool:
        h = http(shared_server.url, "GET", "/v1/health").json()
        return h["status"] == "OK" and h["uptime_s"] > 1.5

    wait_for(ok, 15, what="health OK")
    h = http(shared_server.url, "GET", "/v1/health").json()
    assert set(h["sensors"]) == {"finger0", "finger1"}
    for s in h["sensors"].values():
        assert s["status"] == "OK" and s["reason"] == "" and s["connected"] is True
        assert 100 < s["frame_rate_hz"] < 1500  # 1 kHz, on a machine that may be busy
        for key in ("frames", "crc_errors", "lost_frames", "duplicated_frames",
                    "superseded_frames", "worker_restarts", "fit_rate_hz", "published"):
            assert isinstance(s[key], (int, float)) and s[key] >= 0, key
        assert s["frames"] > 0
    subs = h["subscribers"]
    assert {"count", "limit", "clients", "refused", "stalled"} <= set(subs)
    assert h["workers"]["size"] == 1 and h["version"]


def test_health_counts_subscribers_and_their_drops(shared_server, arun):
    from svc_helpers import subscribe, ws_connect

    async def main() -> dict:
        async with ws_connect(shared_server.ws_url) as ws:
            await subscribe(ws, streams=["estimates"], max_rate=5)
            await asyncio.sleep(0.3)
            return await asyncio.to_thread(
                lambda: http(shared_server.url, "GET", "/v1/health").json())

    h = arun(main())
    clients = h["subscribers"]["clients"]
    assert h["subscribers"]["count"] == len(clients) >= 1
    mine = [c for c in clients if c["subscription"] and c["subscription"]["max_rate"] == 5]
    assert mine and mine[0]["subscription"]["streams"] == ["estimates"]
    for key in ("sent", "dropped", "queued", "coalesced"):
        assert mine[0][key] >= 0
    assert mine[0]["coalesced"] > 0  # 5 Hz of a ~1 kHz stream


def test_sensors_list_geometry_and_calibration(shared_server):
    r = http(shared_server.url, "GET", "/v1/sensors")
    assert r.status_code == 200
    sensors = r.json()["sensors"]
    assert [s["name"] for s in sensors] == ["finger0", "finger1"]
    for s in sensors:
        assert (s["rows"], s["cols"]) == (8, 8)
        assert s["dx_mm"] > 0 and s["dy_mm"] > 0 and s["finger_radius_mm"] > 0
        # the description's own keys, as its file gives them (the paper's finger)
        assert (s["description"], s["pitch_x_mm"], s["pitch_y_mm"], s["surface_radius_mm"]) == (
            "fearing1988", 3.3, 3.9, 12.7)
        assert s["calibration"]["id"] == "nominal"
        assert s["url"].startswith("sim://")


def test_latest_estimate_and_frame(shared_server):
    est = http(shared_server.url, "GET", "/v1/sensors/finger1/estimate")
    assert est.status_code == 200, est.text
    body = est.json()
    assert body["type"] == "estimate" and body["sensor"] == "finger1"
    assert FIT_LINE_KEYS <= set(body) and "ellipse" in body
    fr = http(shared_server.url, "GET", "/v1/sensors/finger0/frame").json()
    assert fr["type"] == "frame" and len(fr["strain"]) == 8
    later = http(shared_server.url, "GET", "/v1/sensors/finger0/frame").json()
    assert later["seq"] > fr["seq"]


@pytest.mark.parametrize("method,path", [
    ("GET", "/v1/sensors/thumb/estimate"),
    ("GET", "/v1/sensors/thumb/frame"),
    ("POST", "/v1/sensors/thumb/tare"),
])
def test_unknown_sensor_is_404_naming_it(shared_server, method, path):
    r = http(shared_server.url, method, path)
    assert r.status_code == 404
    assert r.json() == {"detail": "unknown sensor 'thumb'; known: finger0, finger1"}


def test_tare(shared_server):
    r = http(shared_server.url, "POST", "/v1/sensors/finger0/tare")
    assert r.status_code == 200, r.text
    assert r.json()["sensor"] == "finger0" and r.json()["status"] == "scheduled"
    assert http(shared_server.url, "GET", "/v1/sensors/finger0/tare").status_code == 405


def test_config_get_and_patch(shared_server):
    base = http(shared_server.url, "GET", "/v1/config").json()
    assert base["sensors"]["finger0"]["model"] == "auto"
    assert "timeout" in base["fit"]
    r = http(shared_server.url, "PATCH", "/v1/config",
             json={"sensors": {"finger1": {"model": "sphere", "unchanged_z": 4.0}}})
    assert r.status_code == 200, r.text
    assert r.json()["sensors"]["finger1"]["model"] == "sphere"
    assert http(shared_server.url, "GET", "/v1/config").json()["sensors"]["finger1"][
        "unchanged_z"] == 4.0
    r = http(shared_server.url, "PATCH", "/v1/config",
             json={"sensors": {"finger1": {"model": "auto", "unchanged_z": 3.0}}})
    assert r.status_code == 200


@pytest.mark.parametrize("body,status,words", [
    ({"sensors": {"finger0": {"model": "banana"}}}, 422, "sensors.finger0.model: must be one of"),
    ({"sensors": {"finger0": {"window": 1}}}, 422, "sensors.finger0.window"),
    ({"sensors": {"finger0": {"url": "sim://"}}}, 422,
     "sensors.finger0.url: cannot be changed at run time"),
    ({"sensors": {"finger7": {"model": "sphere"}}}, 422, "sensors.finger7: unknown sensor"),
    ({"fit": {"timeout": -1}}, 422, "fit.timeout"),
    ({"server": {"port": 1}}, 422, "server: not changeable"),
    ([1, 2], 422, "expected a JSON object"),
])
def test_config_patch_validation_names_the_key(shared_server, body, status, words):
    before = http(shared_server.url, "GET", "/v1/config").json()
    r = http(shared_server.url, "PATCH", "/v1/config", json=body)
    assert r.status_code == status, r.text
    assert words in r.json()["detail"]
    assert http(shared_server.url, "GET", "/v1/config").json() == before  # all or nothing


def test_config_patch_malformed_requests(shared_server):
    r = http(shared_server.url, "PATCH", "/v1/config", content=b"{nope",
             headers={"content-type": "application/json"})
    assert r.status_code == 400 and "not valid JSON" in r.json()["detail"]
    r = http(shared_server.url, "PATCH", "/v1/config", content=b"model=sphere",
             headers={"content-type": "application/x-www-form-urlencoded"})
    assert r.status_code == 415 and "Content-Type" in r.json()["detail"]
    r = http(shared_server.url, "PATCH", "/v1/config", content=b"x" * (70 * 1024),
             headers={"content-type": "application/json"})
    assert r.status_code == 413


def test_version_and_openapi(shared_server):
    v = http(shared_server.url, "GET", "/v1/version").json()
    assert v["name"] == "tactiled" and v["api"] == "v1" and v["schema_version"] >= 1
    spec = http(shared_server.url, "GET", "/v1/openapi.json").json()
    for path in ("/v1/health", "/v1/sensors", "/v1/sensors/{name}/estimate",
                 "/v1/sensors/{name}/frame", "/v1/sensors/{name}/tare", "/v1/config",
                 "/v1/version"):
        assert path in spec["paths"], path
    assert "patch" in spec["paths"]["/v1/config"]


def test_unknown_path_and_method_are_4xx(shared_server):
    assert http(shared_server.url, "GET", "/v2/health").status_code == 404
    assert http(shared_server.url, "DELETE", "/v1/config").status_code == 405


class MutableSim(SimSource):
    """The simulated finger, with a switch that makes it go silent while staying connected."""

    PARAMS: ClassVar[frozenset[str]] = SimSource.PARAMS
    silent = False

    async def _read_internal(self) -> bytes:
        while self.silent and self.is_open:
            await asyncio.sleep(0.01)
        return await super()._read_internal()


class RecordingNotifier:
    """Records sd_notify calls (name, monotonic time) instead of sending them."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, float]] = []

    def _rec(self, name: str) -> bool:
        self.calls.append((name, time.monotonic()))
        return True

    def ready(self, status: str | None = None) -> bool:
        return self._rec("ready")

    def status(self, text: str) -> bool:
        return self._rec("status")

    def stopping(self, status: str | None = None) -> bool:
        return self._rec("stopping")

    def watchdog(self) -> bool:
        return self._rec("watchdog")

    def pings(self, since: float = 0.0) -> int:
        return sum(1 for name, t in self.calls if name == "watchdog" and t >= since)


def test_silent_connected_device_is_error_within_a_second(live_server, monkeypatch):
    """...and the systemd watchdog pings stop while no frame arrives, and resume after."""
    monkeypatch.setenv("WATCHDOG_USEC", "100000")  # a ping every 0.05 s
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    notifier = RecordingNotifier()
    source = MutableSim("sim://?scene=demo&seed=3")
    server = live_server(sim_settings(1), sources=lambda: {"finger0": source},
                         notifier=notifier)
    assert notifier.calls[0][0] == "ready"
    wait_for(lambda: http(server.url, "GET", "/v1/health").json()["status"] == "OK", 15,
             what="health OK")
    server.call(lambda: setattr(source, "silent", True))
    t0 = time.monotonic()
    taken = wait_for(lambda: http(server.url, "GET", "/v1/health").json()["sensors"][
        "finger0"]["status"] == "ERROR", 5, poll=0.02, what="ERROR")
    assert taken < 1.0, f"took {taken:.2f} s"
    h = http(server.url, "GET", "/v1/health").json()
    assert h["status"] == "ERROR" and h["sensors"]["finger0"]["connected"] is True
    assert "silent" in h["sensors"]["finger0"]["reason"]
    assert time.monotonic() - t0 < 5
    quiet_from = time.monotonic() + 0.2  # a ping already decided may still land
    time.sleep(0.6)
    assert notifier.pings(quiet_from) == 0, "watchdog pinged while no frame arrived"
    server.call(lambda: setattr(source, "silent", False))
    wait_for(lambda: http(server.url, "GET", "/v1/health").json()["sensors"]["finger0"][
        "status"] in ("OK", "WARN"), 10, what="recovery")
    resumed = time.monotonic()
    wait_for(lambda: notifier.pings(resumed) >= 2, 5, what="watchdog pings again")


def test_health_json_is_strict(shared_server):
    text = http(shared_server.url, "GET", "/v1/health").text
    json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))

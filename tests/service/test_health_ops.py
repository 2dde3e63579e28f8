"""What an operator needs from ``GET /v1/health``, through the real service: a sensor slower
than its nominal ``rate_hz`` turns DEGRADED (with the reason) after 2 s, one at its rate does
not; the serial driver's read backlog; the share of frames superseded over the last 10 s; the
resident memory of the daemon and of each fit worker.  The rules alone, on made-up counters,
are in test_health_rules.py."""

from __future__ import annotations

import threading
import time
from urllib.parse import quote

from svc_helpers import http, sim_settings, wait_for

from tactiled.frames import encode_frame
from tactiled.sim import FingerSimulator


def health(server) -> dict:
    return http(server.url, "GET", "/v1/health").json()


def test_a_sensor_below_its_nominal_rate_is_degraded_with_the_reason(live_server):
    # finger0 streams 200 frames/s but is declared at 1000 Hz; finger1 streams 200 and is
    # declared at 200.
    settings = sim_settings(2, **{
        "sensor[0].url": "sim://?scene=demo&seed=1&sensor_id=0&rate=200",
        "sensor[0].rate_hz": 1000,
        "sensor[1].url": "sim://?scene=demo&seed=2&sensor_id=1&rate=200",
        "sensor[1].rate_hz": 200})
    server = live_server(settings)
    wait_for(lambda: health(server)["sensors"]["finger0"]["status"] == "DEGRADED", 15,
             what="finger0 DEGRADED")
    h = health(server)
    slow, fine = h["sensors"]["finger0"], h["sensors"]["finger1"]
    assert h["status"] == "DEGRADED"
    assert "below the nominal 1000 Hz" in slow["reason"] and slow["rate_hz"] == 1000.0
    assert fine["status"] != "DEGRADED" and fine["rate_hz"] == 200.0
    # The grace: it was not DEGRADED before 2 s under the rate (the rule's own clock says when;
    # the reason truncates to 0.1 s, so 2.0 here means at least 2 s).
    seconds = float(slow["reason"].rsplit(" for ", 1)[1].split(" s")[0])
    assert seconds >= 2.0
    metrics = http(server.url, "GET", "/metrics").text
    assert 'tactiled_sensor_status{sensor="finger0",status="DEGRADED"} 1.0' in metrics
    assert 'tactiled_frame_rate_nominal_hertz{sensor="finger0"} 1000.0' in metrics


def test_superseded_share_and_every_process_memory(live_server):
    server = live_server(sim_settings(1))
    wait_for(lambda: health(server)["sensors"]["finger0"]["superseded_share_10s"] is not None,
             15, what="a superseded share")
    h = health(server)
    s = h["sensors"]["finger0"]
    assert 0.0 <= s["superseded_share_10s"] <= 1.0
    stats = server.call(lambda: server.service.daemon.stats("finger0"))
    assert stats["superseded"] >= 0 and s["read_backlog_bytes"] == 0  # a sim source: no thread
    processes = h["workers"]["processes"]
    assert [p["pid"] for p in processes] == server.worker_pids()
    assert all(p["rss_mb"] > 10 for p in processes), processes
    assert h["process"]["rss_mb"] > 10


def test_the_read_backlog_of_a_serial_sensor(live_server, pty_device):
    """While the event loop is held up, the serial driver's reader thread keeps reading: the
    bytes it holds show as the sensor's read backlog, and its peak stays in the health."""
    settings = sim_settings(1, **{"sensor[0].url": f"serial://{quote(pty_device.path)}",
                                  "sensor[0].wire_id": 0})
    server = live_server(settings)
    sim = FingerSimulator(scene="demo", seed=1, rate_hz=1000.0, sensor_id=0)
    wire = b"".join(encode_frame(sim.next_frame()) for _ in range(400))  # ~60 KB
    wait_for(lambda: server.call(lambda: server.service.daemon.sensors["finger0"].source
                                 .connected), 10, what="port open")
    blocked = threading.Event()

    def hold_the_loop() -> None:
        blocked.set()
        time.sleep(0.8)  # the loop cannot take the bytes meanwhile

    loop_thread = threading.Thread(
        target=lambda: server.call(hold_the_loop, timeout=10), daemon=True)
    loop_thread.start()
    blocked.wait(5)
    for start in range(0, len(wire), 4096):  # a device writing while the loop is stuck
        piece = wire[start:start + 4096]
        while piece:
            try:
                pty_device.write(piece)
                piece = b""
            except BlockingIOError:
                time.sleep(0.002)
    loop_thread.join(10)
    wait_for(lambda: health(server)["sensors"]["finger0"]["frames"] >= 400, 10,
             what="every frame decoded")
    s = health(server)["sensors"]["finger0"]
    assert s["read_backlog_peak_bytes"] > 4096, s  # more than one tty read's worth was held
    assert s["read_backlog_bytes"] == 0  # all taken since

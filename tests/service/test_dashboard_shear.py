"""The dashboard on a 3-axis array in a real browser: a simulated XELA server pushes a sphere
sideways (`tactiled simulate --as xela --scene push`); the page draws each contact's tangential
arrow along the estimate's (fx, fy) and shows the shear and slip readouts."""

from __future__ import annotations

import math

import numpy as np
import pytest
from dash_helpers import wait_numeric_seq
from svc_helpers import sim_settings, wait_for
from test_shear_live import start_pull_device


@pytest.mark.slow  # the fit worker builds the 4x4 array's start table on first use
def test_the_dashboard_draws_the_tangential_arrow(browser_page, live_server):
    device, line = start_pull_device("push")
    try:
        addr = line.removeprefix("xela: ws://")
        settings = sim_settings(1, **{"sensor[0].name": "xela",
                                      "sensor[0].description": "xela_uskin_4x4",
                                      "sensor[0].url": f"xela://{addr}?sensor=1",
                                      "fit.startup_timeout": 300.0})
        server = live_server(settings)
        page, errors = browser_page
        page.goto(server.url + "/")
        wait_numeric_seq(page, "xela")
        found = page.wait_for_function(
            "() => { const d = JSON.parse(document.querySelector('#sensor-xela canvas.overlay')"
            "?.dataset.contacts || '[]').find(d => d.shear && Math.hypot(d.shear.dx, d.shear.dy) > 15);"
            " return d ? d.shear : false; }", timeout=300_000)
        arrow = found.json_value()
        # x to the right, y up on screen: the arrow's direction is (fx, fy)'s
        drawn_deg = math.degrees(math.atan2(-arrow["dy"], arrow["dx"]))
        force_deg = math.degrees(math.atan2(arrow["fy_n"], arrow["fx_n"]))
        assert abs((drawn_deg - force_deg + 180) % 360 - 180) < 2.0, (arrow, drawn_deg, force_deg)
        assert arrow["state"] in ("stick", "partial", "slip")
        # the followed (strongest) contact's readouts: its tangential force, torsion, slip state
        page.wait_for_function(
            "() => { const q = k => document.querySelector(`#follow-panel [data-k=${k}]`).textContent;"
            " return /^-?\\d+\\.\\d{3}, -?\\d+\\.\\d{3} N; -?\\d+\\.\\d{2} N·mm$/.test(q('shear'))"
            " && ['stick', 'partial', 'slip'].includes(q('slip')); }", timeout=60_000)
        assert not errors, errors
    finally:
        device.terminate()
        device.wait(30)


def test_the_dashboard_draws_each_taxels_in_plane_reading(browser_page, live_server):
    """A simulated 3-axis XELA patch (``sim://`` playing its pull scene): over the heat map the
    page draws every taxel's in-plane reading (x, y) as a tick from its centre, x to the right
    and y up, one scale for the frame (data-taxels).  Checked against the frames a WebSocket
    client of the same server received, by seq: the ticks' directions are the readings', their
    lengths in proportion.  The fit workers are not awaited (frames do not need them)."""
    import json
    import threading

    from websockets.sync.client import connect

    settings = sim_settings(1, **{"sensor[0].name": "xela", "sensor[0].description": "xela_uskin_4x4",
                                  "sensor[0].url": "sim://?sensor=xela_uskin_4x4&scene=pull&seed=2&rate=200",
                                  "fit.startup_timeout": 0.5})
    server = live_server(settings)
    received: dict[int, list] = {}
    stop = threading.Event()

    def collect() -> None:  # every frame, unpaced
        with connect(server.url.replace("http://", "ws://") + "/v1/stream", open_timeout=10,
                     max_size=2**22) as ws:
            ws.send(json.dumps({"type": "subscribe", "streams": ["frames"]}))
            while not stop.is_set():
                try:
                    msg = json.loads(ws.recv(timeout=0.5))
                except TimeoutError:
                    continue
                if msg.get("type") == "frame" and "taxels" in msg:
                    received[msg["seq"]] = msg["taxels"]

    reader = threading.Thread(target=collect, daemon=True)
    reader.start()
    try:
        page, errors = browser_page
        page.goto(server.url + "/")
        # a drawn frame whose largest tick is a visible fraction of a pitch, that the client got
        drawn = page.wait_for_function(
            "seen => { const t = document.querySelector('#sensor-xela canvas.map')?.dataset.taxels;"
            " if (!t) return false; const d = JSON.parse(t);"
            " return d.ticks.some(k => Math.hypot(k[2], k[3]) > 8) ? d : false; }",
            arg=None, timeout=120_000).json_value()
        wait_for(lambda: drawn["seq"] in received, 10.0, poll=0.05,
                 what=f"frame {drawn['seq']} at the WebSocket client")
    finally:
        stop.set()
        reader.join(10)
    readings = np.asarray(received[drawn["seq"]])
    assert readings.shape == (4, 4, 3)
    ticks = np.array([k[2:] for k in drawn["ticks"]])
    assert [tuple(k[:2]) for k in drawn["ticks"]] == [(m, n) for m in range(4) for n in range(4)]
    xy = readings[..., :2].reshape(-1, 2) * (1, -1)  # y up on screen
    assert drawn["scale"] >= np.hypot(*xy.T).max() - 1e-6
    # one factor (px per reading) for every tick: the lengths in proportion, the directions kept
    big = np.hypot(*xy.T) > 0.2 * np.hypot(*xy.T).max()
    factor = np.hypot(*ticks[big].T) / np.hypot(*xy[big].T)
    np.testing.assert_allclose(factor, factor.mean(), rtol=0.02, atol=0.02)
    cos = np.sum(ticks[big] * xy[big], axis=1) / (np.hypot(*ticks[big].T) * np.hypot(*xy[big].T))
    assert cos.min() > 0.999
    assert not errors, errors

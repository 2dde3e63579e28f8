"""The dashboard on a 3-axis array in a real browser: a simulated XELA server pushes a sphere
sideways (`tactiled simulate --as xela --scene push`); the page draws each contact's tangential
arrow along the estimate's (fx, fy) and shows the shear and slip readouts."""

from __future__ import annotations

import math

import pytest
from dash_helpers import wait_numeric_seq
from svc_helpers import sim_settings
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
            ".dataset.contacts || '[]').find(d => d.shear && Math.hypot(d.shear.dx, d.shear.dy) > 15);"
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

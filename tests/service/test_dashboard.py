"""The dashboard in a real browser: headless Chromium (Debian's) driven by Playwright loads the
page from a running daemon and sees estimates appear and update, the strain map drawn, the
health counters, the followed contact's readouts and strip chart of the last 10 s with its
bands and the reason of a withheld value on hover; with a token, the ?token= login and its
session cookie open the stream.  The whole hand (six arrays on one laptop screen, several
contacts with their ids, following a clicked sensor or contact) is in test_dashboard_hand.py.

``TACTILED_DOCS_SCREENSHOT=docs/img/dashboard-strip.png`` makes
``test_strip_chart_of_a_moving_contact`` also write its screenshot there, in 256 colours (the
README's picture, of a full 10 s chart, taken at a moment the badge says OK and the tracker's rates are shown: on a
busy machine it may wait up to a minute for one)."""

from __future__ import annotations

import json
import os
import re
import time
from typing import Any

import pytest
from dash_helpers import PANEL, drawn_array, follow, wait_numeric_seq
from svc_helpers import http, sim_settings, wait_for

from tactiled_service.health import SEVERITY

def seq_of(page: Any, sensor: str) -> int:
    return int(page.text_content(f"#sensor-{sensor} [data-k=seq]"))


def canvas_colours(page: Any, sensor: str) -> int:
    """Distinct colours drawn on the sensor's strain map."""
    return page.evaluate("""s => {
        const c = document.querySelector(`#sensor-${s} canvas`);
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        const seen = new Set();
        for (let i = 0; i < d.length; i += 16) seen.add(`${d[i]},${d[i+1]},${d[i+2]}`);
        return seen.size;
    }""", sensor)


def test_dashboard_shows_live_estimates(browser_page, shared_server, tmp_path):
    page, errors = browser_page
    page.goto(shared_server.url + "/")
    for sensor in ("finger0", "finger1"):
        wait_numeric_seq(page, sensor)
    first = seq_of(page, "finger0")
    page.wait_for_function(
        "n => Number(document.querySelector('#sensor-finger0 [data-k=seq]').textContent) > n",
        arg=first, timeout=30_000)
    assert seq_of(page, "finger0") > first  # it updates, not just appears
    # A contact with its readouts and ellipse (the demo scene presses within seconds), in the
    # panel that follows the clicked sensor.
    follow(page, "finger0")
    page.wait_for_function(
        "() => { const q = k => document.querySelector(`#follow-panel [data-k=${k}]`)"
        ".textContent; return q('contact') === 'yes' && q('ellipse') !== '—' "
        "&& q('force_n').includes('±'); }", timeout=40_000)
    force = page.text_content(f"{PANEL} [data-k=force_n]")
    assert re.fullmatch(r"\d+\.\d{3} ± \d+\.\d{3} N", force), force
    assert page.text_content("#follow").startswith("finger0")
    # The tracker's readouts: frames the estimate rests on, and the contact's rates.
    page.wait_for_function(
        "() => { const q = k => document.querySelector(`#follow-panel [data-k=${k}]`)"
        ".textContent; return Number(q('frames_used')) > 10 && q('vx_mm_s').endsWith('mm/s')"
        " && q('force_rate_n_s').endsWith('N/s'); }", timeout=40_000)
    # each component on its own line, with its own sigma
    for k in ("vx_mm_s", "vy_mm_s"):
        velocity = page.text_content(f"{PANEL} [data-k={k}]")
        assert re.fullmatch(r"-?\d+\.\d{2} ± \d+\.\d{2} mm/s", velocity), (k, velocity)
    # the colour legend: the strain map's own colours, from 0 to the array's scale
    assert page.is_visible("#legend .ramp")
    assert " ".join(page.text_content("#legend").split()) == "strain 0 to the array's scale"
    ramp = page.eval_on_selector("#legend .ramp", "e => getComputedStyle(e).backgroundImage")
    assert ramp.startswith("linear-gradient") and "rgb(0, 0, 4)" in ramp, ramp
    assert ramp.endswith("rgb(252, 255, 164))"), ramp
    assert page.text_content(f"{PANEL} [data-k=model]") in ("cylinder", "sphere", "general")
    assert canvas_colours(page, "finger0") > 8, "the strain map is not drawn"
    # Health counters from /v1/health: the badge and each row say what /v1/health says (OK,
    # or WARN when the simulated sources lag on a loaded machine), read between two answers
    # that agree so the page's poll (1 s) is not racing a change.
    def badges() -> tuple[str, ...]:
        return tuple(page.text_content(sel) for sel in (
            "#overall", "#health tbody tr[data-sensor=finger0] td:nth-child(2)",
            "#health tbody tr[data-sensor=finger1] td:nth-child(2)",
            "#sensor-finger1 .status"))

    def health() -> tuple[str, ...]:
        h = http(shared_server.url, "GET", "/v1/health").json()
        s = h["sensors"]
        return h["status"], s["finger0"]["status"], s["finger1"]["status"], s["finger1"]["status"]

    seen: list[tuple[str, ...]] = []

    def shown_matches() -> bool:
        before, shown, after = health(), badges(), health()
        seen.append(shown)
        return before == shown == after

    wait_for(shown_matches, 30.0, poll=0.2, what="the badges showing /v1/health's statuses")
    assert seen[-1][0] in SEVERITY, seen[-1]
    # fits/s counts the fits that happen, tracked/s the frames the tracker measured without one
    heads = page.eval_on_selector_all("#health thead th", "ths => ths.map(t => t.textContent)")
    assert heads[2:5] == ["frames/s", "fits/s", "tracked/s"], heads
    page.wait_for_function(
        "() => { const c = document.querySelector('#health tbody tr[data-sensor=finger0]')"
        ".children; return Number(c[3].textContent) > 0 && Number(c[4].textContent) > 0; }",
        timeout=40_000)
    assert "subscriber(s)" in page.text_content("#subscribers")
    assert page.text_content("#conn") == "live"
    shot = tmp_path / "dashboard.png"
    page.screenshot(path=str(shot), full_page=True)
    assert shot.stat().st_size > 10_000
    assert not errors, errors


def test_dashboard_login_with_token(browser_page, live_server):
    token = "dashboard-token-123"
    server = live_server(sim_settings(1, **{"server.token": token}))
    page, errors = browser_page
    response = page.goto(server.url + "/")
    assert response.status == 401
    errors.clear()  # the browser reports that 401 as a console error
    page.goto(f"{server.url}/?token={token}")
    assert page.url == server.url + "/", "the token must leave the address bar"
    wait_numeric_seq(page, "finger0")
    assert page.text_content("#conn") == "live"
    cookies = page.context.cookies()
    session = [c for c in cookies if c["name"] == "tactiled_session"]
    assert session and session[0]["httpOnly"] and session[0]["sameSite"] == "Strict"
    assert page.evaluate("document.cookie") == "", "scripts cannot read the session"
    assert not errors, errors


# --------------------------------------------------------------------------------------------
# The strip chart


def strip_lanes(page: Any) -> tuple[dict[str, float], list[tuple[float, float]]]:
    """The strip canvas's box on the page and its lanes' [top, bottom] in page pixels (force,
    R1, angle)."""
    canvas = page.locator(f"{PANEL} canvas.strip")
    box = canvas.bounding_box()
    scale = box["height"] / float(canvas.get_attribute("height"))
    lanes = json.loads(canvas.get_attribute("data-lanes"))
    return box, [(box["y"] + a * scale, box["y"] + b * scale) for a, b in lanes]


def hover_until(page: Any, lane: int, pattern: str, timeout_s: float = 30.0) -> str:
    """Sweep the pointer along ``lane`` of the strip chart (newest first) until the tooltip
    matches ``pattern``; its text."""
    tip = f"{PANEL} .strip-tip"
    deadline = time.monotonic() + timeout_s
    seen: set[str] = set()
    while time.monotonic() < deadline:
        box, lanes = strip_lanes(page)
        top, bottom = lanes[lane]
        for x in range(int(box["width"]) - 14, 100, -7):
            page.mouse.move(box["x"] + x, (top + bottom) / 2)
            page.wait_for_timeout(45)  # the tooltip follows on the next redraw (<= 33 ms)
            text = page.text_content(tip) or ""
            if page.is_visible(tip):
                seen.add(text.split(" · ")[0])
                if re.search(pattern, text):
                    return text
    raise AssertionError(f"no tooltip matching {pattern!r} on lane {lane}; saw e.g. {sorted(seen)[:8]}")


def strip_colours(page: Any) -> int:
    """Distinct colours drawn on the strip chart."""
    return page.evaluate("""() => {
        const c = document.querySelector('#follow-panel canvas.strip');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        const seen = new Set();
        for (let i = 0; i < d.length; i += 8) seen.add(`${d[i]},${d[i+1]},${d[i+2]}`);
        return seen.size;
    }""")


def test_strip_chart_bands_and_the_reason_of_a_withheld_value(browser_page, live_server):
    # A sphere fitted as a sphere: force and radius with their sigmas, the angle withheld
    # ("undefined: sphere model") on every contact frame.
    server = live_server(sim_settings(1, **{
        "sensor[0].url": "sim://?scene=sphere&seed=2&sensor_id=0", "sensor[0].model": "sphere"}))
    page, errors = browser_page
    page.goto(server.url + "/")
    wait_numeric_seq(page, "finger0")
    # one sensor: the panel follows it (the strongest contact, or the only sensor without one)
    page.wait_for_function("() => document.querySelector('#follow-panel').dataset.sensor"
                           " === 'finger0'", timeout=30_000)
    force = hover_until(page, 0, r"^force \d+\.\d{3} ± \d+\.\d{3} N · seq \d+")
    radius = hover_until(page, 1, r"^R1 \d+\.\d{2} ± \d+\.\d{2} mm")
    angle = hover_until(page, 2, r"^angle withheld: undefined: sphere model · seq \d+")
    idle = hover_until(page, 0, r"^force withheld: no contact")
    assert strip_colours(page) > 20, "the strip chart is not drawn"
    page.mouse.move(5, 5)  # off the chart: the tooltip goes
    page.wait_for_function("() => document.querySelector('#follow-panel .strip-tip').hidden")
    assert not errors, (errors, force, radius, angle, idle)


def test_strip_chart_of_a_moving_contact(browser_page, live_server, tmp_path):
    server = live_server(sim_settings(1, **{"sensor[0].url": "sim://?scene=moving&seed=1&sensor_id=0"}))
    page, errors = browser_page
    page.set_viewport_size({"width": 1200, "height": 900})
    page.goto(server.url + "/")
    wait_numeric_seq(page, "finger0")
    started = time.monotonic()
    for lane, pattern in ((0, r"^force \d"), (1, r"^R1 \d"), (2, r"^angle \d")):
        hover_until(page, lane, pattern)
    page.mouse.move(5, 5)
    target = os.environ.get("TACTILED_DOCS_SCREENSHOT")
    if target:  # the picture: a full chart (10 s of the scene's motion), at a moment the
        # badge is OK and the tracker's rates are shown
        page.wait_for_timeout(max(0.0, 11.0 - (time.monotonic() - started)) * 1000)
        page.wait_for_function(
            "() => { const q = s => document.querySelector(s).textContent;"
            " return q('#sensor-finger0 .status') === 'OK' && "
            "q('#follow-panel [data-k=vx_mm_s]').endsWith('mm/s'); }",
            timeout=60_000)
    box, lanes = strip_lanes(page)
    page.mouse.move(box["x"] + box["width"] * 0.62, (lanes[1][0] + lanes[1][1]) / 2)
    page.wait_for_timeout(100)
    shot = tmp_path / "strip.png"
    page.locator(PANEL).screenshot(path=str(shot))
    assert shot.stat().st_size > 10_000
    if target:  # 256 colours lose nothing visible here and a third of the bytes
        from PIL import Image  # with matplotlib, in the test extra

        image = Image.open(shot).convert("RGB").quantize(256, Image.Quantize.MEDIANCUT,
                                                         dither=Image.Dither.NONE)
        image.save(target, optimize=True)
    assert not errors, errors


def test_the_dashboard_draws_each_array_as_it_is(browser_page, live_server):
    # a flat 16x16 pad at 2.5 mm and a Robotiq 7x4 fingertip at 4 mm: each map has its
    # array's shape on one common scale, and a cylinder on the pad is drawn and read as a line
    settings = sim_settings(
        2, **{"sensor[0].name": "pad", "sensor[0].description": "flat16",
              "sensor[0].url": "sim://?sensor=flat16&scene=demo&seed=1",
              "sensor[1].name": "tip", "sensor[1].description": "robotiq_tsf85",
              "sensor[1].url": "sim://?sensor=robotiq_tsf85&scene=sphere&seed=2&sensor_id=1"})
    server = live_server(settings)
    page, errors = browser_page
    page.goto(server.url + "/")
    for sensor in ("pad", "tip"):
        wait_numeric_seq(page, sensor)
    tip, pad = drawn_array(page, "tip"), drawn_array(page, "pad")
    # 7 rows x 4 mm across, 4 cols x 4 mm up; 16 x 2.5 mm each way; the same px per mm
    assert (tip["rows"], tip["cols"], pad["rows"], pad["cols"]) == (7, 4, 16, 16)
    assert tip["width"] / tip["height"] == pytest.approx(28.0 / 16.0, abs=0.05)
    assert pad["width"] / pad["height"] == pytest.approx(1.0, abs=0.03)
    assert tip["width"] / pad["width"] == pytest.approx(28.0 / 40.0, abs=0.02)
    page.wait_for_function(
        "() => { const q = k => document.querySelector(`#sensor-pad [data-k=${k}]`).textContent;"
        " return q('force_n').startsWith('line: ') && q('force_n').endsWith('N/mm') &&"
        " document.querySelector('#sensor-pad .model-label').textContent.includes('(line)'); }",
        timeout=60_000)
    # the daemon lists its `contacts`: the pad's one line contact, drawn with its contact_id
    drawn = json.loads(page.get_attribute("#sensor-pad canvas.overlay", "data-contacts"))
    assert len(drawn) <= 1 and all(isinstance(d["id"], int) and d["id"] >= 1 for d in drawn), drawn
    assert canvas_colours(page, "tip") > 4 and canvas_colours(page, "pad") > 8
    assert not errors, errors

"""The dashboard in a real browser: headless Chromium (Debian's) driven by Playwright loads the
page from a running daemon and sees estimates appear and update, the strain map drawn, the
health counters, the strip chart of the last 10 s with its bands and the reason of a withheld
value on hover; with a token, the ?token= login and its session cookie open the stream.

``TACTILED_DOCS_SCREENSHOT=docs/img/dashboard-strip.png`` makes
``test_strip_chart_of_a_moving_contact`` also write its screenshot there, in 256 colours (the
README's picture; take it on a machine with nothing else running, or the badge may say WARN)."""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from svc_helpers import sim_settings

CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]


@pytest.fixture
def browser_page(chromium: str, tmp_path: Path) -> Iterator[tuple[Any, list[str]]]:
    """A fresh Chromium profile and page; yields (page, errors seen by the page)."""
    from playwright.sync_api import sync_playwright

    errors: list[str] = []
    with sync_playwright() as p:
        context = p.chromium.launch_persistent_context(
            str(tmp_path / "profile"), executable_path=chromium, headless=True,
            args=CHROMIUM_ARGS, viewport={"width": 1400, "height": 1000})
        try:
            page = context.pages[0] if context.pages else context.new_page()
            page.on("pageerror", lambda err: errors.append(f"page error: {err}"))
            page.on("console", lambda msg: errors.append(f"console: {msg.text}")
                    if msg.type == "error" else None)
            yield page, errors
        finally:
            context.close()


def seq_of(page: Any, sensor: str) -> int:
    return int(page.text_content(f"#sensor-{sensor} [data-k=seq]"))


def wait_numeric_seq(page: Any, sensor: str, timeout_ms: int = 30_000) -> None:
    page.wait_for_function(
        "s => /^\\d+$/.test(document.querySelector(`#sensor-${s} [data-k=seq]`)"
        "?.textContent || '')", arg=sensor, timeout=timeout_ms)


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
        arg=first, timeout=5000)
    assert seq_of(page, "finger0") > first  # it updates, not just appears
    # A contact with its readouts and ellipse (the demo scene presses within seconds).
    page.wait_for_function(
        "() => { const q = k => document.querySelector(`#sensor-finger0 [data-k=${k}]`)"
        ".textContent; return q('contact') === 'yes' && q('ellipse') !== '—' "
        "&& q('force_n').includes('±'); }", timeout=40_000)
    force = page.text_content("#sensor-finger0 [data-k=force_n]")
    assert re.fullmatch(r"\d+\.\d{3} ± \d+\.\d{3} N", force), force
    # The tracker's readouts: frames the estimate rests on, and the contact's rates.
    page.wait_for_function(
        "() => { const q = k => document.querySelector(`#sensor-finger0 [data-k=${k}]`)"
        ".textContent; return Number(q('frames_used')) > 10 && q('velocity').endsWith('mm/s')"
        " && q('force_rate_n_s').endsWith('N/s'); }", timeout=40_000)
    velocity = page.text_content("#sensor-finger0 [data-k=velocity]")
    assert re.fullmatch(r"-?\d+\.\d{2}, -?\d+\.\d{2} ± \d+\.\d{2} mm/s", velocity), velocity
    assert page.text_content("#sensor-finger0 [data-k=model]") in (
        "cylinder", "sphere", "general")
    assert canvas_colours(page, "finger0") > 8, "the strain map is not drawn"
    # Health counters from /v1/health.
    page.wait_for_function("() => document.querySelector('#overall').textContent === 'OK' && "
                           "document.querySelector('#sensor-finger1 .status').textContent "
                           "=== 'OK'", timeout=15_000)
    row = page.text_content("#health tbody tr[data-sensor=finger0]")
    assert "finger0" in row and "OK" in row
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


def strip_lanes(page: Any, sensor: str) -> tuple[dict[str, float], list[tuple[float, float]]]:
    """The strip canvas's box on the page and its lanes' [top, bottom] in page pixels (force,
    R1, angle)."""
    canvas = page.locator(f"#sensor-{sensor} canvas.strip")
    box = canvas.bounding_box()
    scale = box["height"] / float(canvas.get_attribute("height"))
    lanes = json.loads(canvas.get_attribute("data-lanes"))
    return box, [(box["y"] + a * scale, box["y"] + b * scale) for a, b in lanes]


def hover_until(page: Any, sensor: str, lane: int, pattern: str, timeout_s: float = 30.0) -> str:
    """Sweep the pointer along ``lane`` of the strip chart (newest first) until the tooltip
    matches ``pattern``; its text."""
    tip = f"#sensor-{sensor} .strip-tip"
    deadline = time.monotonic() + timeout_s
    seen: set[str] = set()
    while time.monotonic() < deadline:
        box, lanes = strip_lanes(page, sensor)
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


def strip_colours(page: Any, sensor: str) -> int:
    """Distinct colours drawn on the sensor's strip chart."""
    return page.evaluate("""s => {
        const c = document.querySelector(`#sensor-${s} canvas.strip`);
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        const seen = new Set();
        for (let i = 0; i < d.length; i += 8) seen.add(`${d[i]},${d[i+1]},${d[i+2]}`);
        return seen.size;
    }""", sensor)


def test_strip_chart_bands_and_the_reason_of_a_withheld_value(browser_page, live_server):
    # A sphere fitted as a sphere: force and radius with their sigmas, the angle withheld
    # ("undefined: sphere model") on every contact frame.
    server = live_server(sim_settings(1, **{
        "sensor[0].url": "sim://?scene=sphere&seed=2&sensor_id=0", "sensor[0].model": "sphere"}))
    page, errors = browser_page
    page.goto(server.url + "/")
    wait_numeric_seq(page, "finger0")
    force = hover_until(page, "finger0", 0, r"^force \d+\.\d{3} ± \d+\.\d{3} N · seq \d+")
    radius = hover_until(page, "finger0", 1, r"^R1 \d+\.\d{2} ± \d+\.\d{2} mm")
    angle = hover_until(page, "finger0", 2, r"^angle withheld: undefined: sphere model · seq \d+")
    idle = hover_until(page, "finger0", 0, r"^force withheld: no contact")
    assert strip_colours(page, "finger0") > 20, "the strip chart is not drawn"
    page.mouse.move(5, 5)  # off the chart: the tooltip goes
    page.wait_for_function("() => document.querySelector('#sensor-finger0 .strip-tip').hidden")
    assert not errors, (errors, force, radius, angle, idle)


def test_strip_chart_of_a_moving_contact(browser_page, live_server, tmp_path):
    server = live_server(sim_settings(1, **{"sensor[0].url": "sim://?scene=moving&seed=1&sensor_id=0"}))
    page, errors = browser_page
    page.set_viewport_size({"width": 1200, "height": 900})
    page.goto(server.url + "/")
    wait_numeric_seq(page, "finger0")
    started = time.monotonic()
    for lane, pattern in ((0, r"^force \d"), (1, r"^R1 \d"), (2, r"^angle \d")):
        hover_until(page, "finger0", lane, pattern)
    page.mouse.move(5, 5)
    # a full chart for the picture: 10 s of the scene's motion
    page.wait_for_timeout(max(0.0, 11.0 - (time.monotonic() - started)) * 1000)
    box, lanes = strip_lanes(page, "finger0")
    page.mouse.move(box["x"] + box["width"] * 0.62, (lanes[1][0] + lanes[1][1]) / 2)
    page.wait_for_timeout(100)
    shot = tmp_path / "strip.png"
    page.locator("#sensor-finger0").screenshot(path=str(shot))
    assert shot.stat().st_size > 10_000
    target = os.environ.get("TACTILED_DOCS_SCREENSHOT")
    if target:  # 256 colours lose nothing visible here and a third of the bytes
        from PIL import Image  # with matplotlib, in the test extra

        image = Image.open(shot).convert("RGB").quantize(256, Image.Quantize.MEDIANCUT,
                                                         dither=Image.Dither.NONE)
        image.save(target, optimize=True)
    assert not errors, errors


def test_the_dashboard_draws_each_array_as_it_is(browser_page, live_server):
    # a flat 16x16 pad at 2.5 mm and a Robotiq 7x4 fingertip at 4 mm: each map has its
    # array's aspect, and a cylinder on the pad is drawn and read as a line
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
    aspect = page.evaluate("""s => { const c = document.querySelector(`#sensor-${s} canvas`);
                                     return [c.width, c.height]; }""", "tip")
    # 7 rows x 4 mm across, 4 cols x 4 mm up, plus a 24 px margin each side
    w, h = aspect
    assert (h - 48) / (w - 48) == pytest.approx(16.0 / 28.0, abs=0.02)
    pad = page.evaluate("""s => { const c = document.querySelector(`#sensor-${s} canvas`);
                                  return [c.width, c.height]; }""", "pad")
    assert (pad[1] - 48) / (pad[0] - 48) == pytest.approx(1.0, abs=0.02)
    page.wait_for_function(
        "() => { const q = k => document.querySelector(`#sensor-pad [data-k=${k}]`).textContent;"
        " return q('force_n').startsWith('line: ') && q('force_n').endsWith('N/mm'); }",
        timeout=60_000)
    assert "(line)" in page.text_content("#sensor-pad .model-label")
    assert canvas_colours(page, "tip") > 4 and canvas_colours(page, "pad") > 8
    assert not errors, errors

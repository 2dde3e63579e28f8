"""The dashboard of a whole hand in a real browser (headless Chromium, as test_dashboard.py):
six simulated arrays (five of the paper's fingertips, a flat 16x16 palm) on one laptop screen,
each at its own shape and pitch on one scale, measured on the page's canvases; clicking a
sensor makes the strip chart follow it; several contacts on one array drawn with their ids, a
clicked contact followed until it ends; the strongest contact of any sensor followed by default.

``TACTILED_DOCS_SCREENSHOT_HAND=docs/img/dashboard-hand.png`` makes
``test_six_arrays_on_a_laptop_screen`` also write its 1366x768 screenshot there, in 256
colours."""

from __future__ import annotations

import json
import os
import threading
import time
from typing import Any
from urllib.parse import quote

import pytest
from dash_helpers import PANEL, drawn_array, follow, wait_numeric_seq
from svc_helpers import http, sim_settings

from tactiled.fit.result import FitResult
from tactiled.pipeline.estimate import make_estimate
from tactiled.sensors.description import load_description

FINGERS = ["finger1", "finger2", "finger3", "finger4", "finger5"]  # as deploy/hand.toml names them
# Each finger plays its own scene; finger5 stays untouched, so following it shows no force.
SCENES = {"finger1": "demo", "finger2": "press", "finger3": "sphere", "finger4": "moving",
          "finger5": "empty"}


def hand_settings() -> Any:
    """Five 8x8 fingertips of the paper (fearing1988) and a flat 16x16 palm, at 200 Hz each
    (a whole hand at 1 kHz is the acquisition bench's job, not this page's)."""
    extra: dict[str, Any] = {}
    for i, name in enumerate(FINGERS):
        extra.update({f"sensor[{i}].name": name, f"sensor[{i}].description": "fearing1988",
                      f"sensor[{i}].url": f"sim://?sensor=fearing1988&scene={SCENES[name]}"
                                          f"&seed={i + 1}&sensor_id={i}&rate=200"})
    extra.update({"sensor[5].name": "palm", "sensor[5].description": "flat16",
                  "sensor[5].url": "sim://?sensor=flat16&scene=demo&seed=9&sensor_id=5&rate=200"})
    return sim_settings(6, **extra)


def boxes(page: Any, selector: str) -> dict[str, dict[str, float]]:
    """Page boxes (CSS px) of the sensors' elements matching ``selector`` inside their tile."""
    return page.evaluate("""sel => Object.fromEntries(
        [...document.querySelectorAll('.card.sensor')].map(c => {
            const b = (c.querySelector(sel) || c).getBoundingClientRect();
            return [c.dataset.sensor, {x: b.left, y: b.top, r: b.right, b: b.bottom}];
        }))""", selector)


def overlap(a: dict[str, float], b: dict[str, float]) -> bool:
    return a["x"] < b["r"] and b["x"] < a["r"] and a["y"] < b["b"] and b["y"] < a["b"]


def check_hand_fits(page: Any, width: int, height: int) -> float:
    """Every array drawn whole, with its own tactel count and proportions, on one scale, each
    tile labelled and inside the viewport, no two overlapping; the scale (px per mm)."""
    tiles = boxes(page, ":scope")
    assert sorted(tiles) == sorted([*FINGERS, "palm"]), tiles
    for name, box in tiles.items():
        assert 0 <= box["x"] and box["r"] <= width and 0 <= box["y"] and box["b"] <= height, (
            f"{name} is not on the {width}x{height} screen: {box}")
        assert page.text_content(f"#sensor-{name} h2 .name") == name
        assert page.is_visible(f"#sensor-{name} h2 .name")
    # no label cut short: every tile's heading shows whole (no ellipsis), the header too
    cut = page.evaluate("""() => [...document.querySelectorAll('.card.sensor h2, header > *')]
        .filter(e => e.scrollWidth > e.clientWidth + 1).map(e => e.textContent.trim())""")
    assert cut == [], f"labels cut at {width}x{height}: {cut}"
    names = sorted(tiles)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert not overlap(tiles[a], tiles[b]), (a, tiles[a], b, tiles[b])
    scales = []
    for name in tiles:
        # what the array is, from its description file (not from the page or the daemon)
        d = load_description("flat16" if name == "palm" else "fearing1988")
        got = drawn_array(page, name)
        assert (got["rows"], got["cols"]) == (d.rows, d.cols), (name, got)
        width_mm, height_mm = d.rows * d.pitch_x_mm, d.cols * d.pitch_y_mm
        # the drawn array's proportions are the array's, within a pixel each way
        assert abs(got["width"] / width_mm * height_mm - got["height"]) <= 2.0, (name, got)
        scales.append(got["width"] / width_mm)
    assert max(scales) / min(scales) < 1.02, f"arrays drawn at different scales: {scales}"
    return min(scales)


def test_six_arrays_on_a_laptop_screen(browser_page, live_server, tmp_path):
    server = live_server(hand_settings())
    page, errors = browser_page
    page.set_viewport_size({"width": 1366, "height": 768})
    page.goto(server.url + "/")
    for name in [*FINGERS, "palm"]:
        wait_numeric_seq(page, name, timeout_ms=60_000)
    # the daemon's geometry of each sensor is what the page lays out by
    for s in http(server.url, "GET", "/v1/sensors").json()["sensors"]:
        tile = page.locator(f"#sensor-{s['name']}")
        assert (int(tile.get_attribute("data-rows")), int(tile.get_attribute("data-cols")),
                float(tile.get_attribute("data-pitch-x-mm")),
                float(tile.get_attribute("data-pitch-y-mm"))) == (
            s["rows"], s["cols"], s["pitch_x_mm"], s["pitch_y_mm"])
    small = check_hand_fits(page, 1366, 768)
    # a fingertip's tactel is big enough to see: 3.3 mm at the scale chosen
    assert 3.3 * small >= 12, small
    # the strip chart, under the arrays, is on the screen too, and the readouts beside it
    strip = page.locator(f"{PANEL} canvas.strip").bounding_box()
    assert strip["y"] + strip["height"] <= 768, strip
    readouts = page.locator(f"{PANEL} dl.readouts").bounding_box()
    assert readouts["x"] >= strip["x"] + strip["width"] and readouts["y"] < 768, readouts
    target = os.environ.get("TACTILED_DOCS_SCREENSHOT_HAND")
    if target:
        page.wait_for_timeout(3000)  # some history on the strip chart
        page.wait_for_function(  # a moment the badge is OK and four arrays are pressed
            "() => document.querySelector('#overall').textContent === 'OK' && "
            "[...document.querySelectorAll('.card.sensor [data-k=contact]')]"
            ".filter(e => e.textContent !== 'no').length >= 4", timeout=60_000, polling=50)
        shot = tmp_path / "hand.png"
        page.screenshot(path=str(shot))
        from PIL import Image  # with matplotlib, in the test extra

        image = Image.open(shot).convert("RGB").quantize(256, Image.Quantize.MEDIANCUT,
                                                         dither=Image.Dither.NONE)
        image.save(target, optimize=True)

    # every label whole once the arrays are pressed and their models shown
    page.wait_for_function("() => [...document.querySelectorAll('.card.sensor .model-label')]"
                           ".filter(e => e.textContent).length >= 3", timeout=60_000)
    cut = page.evaluate("""() => [...document.querySelectorAll('.card.sensor h2, header > *')]
        .filter(e => e.scrollWidth > e.clientWidth + 1).map(e => e.textContent.trim())""")
    assert cut == [], f"labels cut at 1366x768: {cut}"
    check_hand_fits(page, 1366, 768)
    # Clicking a sensor: the panel and its strip chart follow it.  The untouched finger's
    # chart has no force line; the palm's (pressed by its scene) has one.
    follow(page, "finger5")
    assert page.text_content("#follow").startswith("finger5 (clicked sensor)")
    assert "followed" in page.get_attribute("#sensor-finger5", "class")
    page.wait_for_function("() => document.querySelector('#follow-panel canvas.strip')"
                           ".dataset.follows === 'sensor|finger5|null'", timeout=30_000)
    page.wait_for_timeout(300)
    # (a lone false detection would draw one 3x3 dot; a followed pressed sensor, hundreds)
    assert force_pixels(page) < 10, "a force line on the untouched finger's chart"
    assert page.text_content(f"{PANEL} [data-k=contact]") == "no"
    # an untouched array shows its scale's floor, 0.5 %: its noise (0.05 %) stays dark
    assert page.text_content("#sensor-finger5 [data-k=scale]") == "0.50 % strain"
    follow(page, "palm")
    page.wait_for_function(f"() => ({FORCE_PIXELS})() > 20", timeout=60_000)
    assert page.text_content("#follow").startswith("palm")
    # back to the strongest contact, whichever sensor has it
    page.click("#follow-auto")
    page.wait_for_function("() => document.querySelector('#follow-panel').dataset.mode"
                           " === 'auto'", timeout=30_000)
    assert "(the strongest contact" in page.text_content("#follow")

    # 1920x1080: the same arrays, larger
    page.set_viewport_size({"width": 1920, "height": 1080})
    page.wait_for_timeout(500)
    large = check_hand_fits(page, 1920, 1080)
    assert large > small * 1.2, (small, large)
    assert not errors, errors


# The strip chart's force lane (its top third) in the force colour (#39d353), pixels.
FORCE_PIXELS = """() => {
    const c = document.querySelector('#follow-panel canvas.strip');
    const lanes = JSON.parse(c.dataset.lanes);
    const d = c.getContext('2d').getImageData(92, lanes[0][0], c.width - 102,
                                              lanes[0][1] - lanes[0][0]).data;
    let n = 0;
    for (let i = 0; i < d.length; i += 4)
        if (d[i] === 0x39 && d[i + 1] === 0xd3 && d[i + 2] === 0x53) n++;
    return n;
}"""


def force_pixels(page: Any) -> int:
    return page.evaluate(FORCE_PIXELS)


# --------------------------------------------------------------------------------------------
# Several contacts on one array


def contact(contact_id: int, x_mm: float, y_mm: float, force_n: float, r_mm: float) -> dict:
    """One element of an estimate's ``contacts``: a sphere's fit line and its contact_id."""
    line = FitResult(contact=True, model="sphere").to_json_dict()
    line.update(x_mm=x_mm, y_mm=y_mm, force_n=force_n, r1_mm=r_mm, r2_mm=r_mm, label="sphere",
                std={"x_mm": 0.05, "y_mm": 0.05, "force_n": 0.01, "r1_mm": 0.3, "r2_mm": 0.3,
                     "angle_deg": None},
                reasons={"angle_deg": "undefined: sphere model"}, contact_id=contact_id)
    return line


class Injector:
    """Publishes ``self.contacts[sensor]`` as the estimate of each sensor into a real server's
    hub, 20 times a second, on the server's own loop (as the sensor pipelines do), until
    stopped."""

    def __init__(self, server: Any, contacts: dict[str, list[dict]]) -> None:
        self.server, self.contacts = server, contacts
        self.seq = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)

    def estimate(self, sensor: str, contacts: list[dict]) -> Any:
        top = max(contacts, key=lambda c: c["force_n"])  # the strongest at the top level
        return make_estimate(sensor=sensor, sensor_id=0, seq=self.seq,
                             device_time_us=self.seq * 50_000, host_time=time.monotonic(),
                             gate="fit", fitted_seq=self.seq, worker_ms=1.0,
                             fit={**top, "contacts": list(contacts)})

    def run(self) -> None:
        deadline = time.monotonic() + 120
        hub = self.server.service.daemon.hub
        while not self.stop.is_set() and time.monotonic() < deadline:
            self.seq += 1
            items = [self.estimate(name, c) for name, c in list(self.contacts.items())]
            self.server.call(lambda: [hub.publish(est) for est in items])
            self.stop.wait(0.05)

    def __enter__(self) -> Injector:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(10)


def silent_sensor(name: str, description: str, device: Any, index: int) -> dict[str, Any]:
    """Settings of a sensor on a serial port that sends nothing: the daemon publishes no
    estimate of its own for it."""
    return {f"sensor[{index}].name": name, f"sensor[{index}].description": description,
            f"sensor[{index}].wire_id": index,
            f"sensor[{index}].url": f"serial://{quote(device.path)}"}


def test_several_contacts_drawn_with_their_ids(browser_page, live_server, pty_device):
    """Injected: estimates of the sensor ``pad`` (a flat 16x16 array on a serial port that
    sends nothing, so the daemon publishes no estimate of its own for it) listing two sphere
    contacts, ids 3 (1.2 N at x 10, y 25 mm) and 7 (0.4 N at x 28, y 8 mm), published into the
    real server's hub at 20 Hz; the daemon encodes them (each contact's ellipse) and streams
    them to the real browser.  Then contact 7 ends (only 3 is listed)."""
    server = live_server(sim_settings(1, **silent_sensor("pad", "flat16", pty_device, 0)))
    page, errors = browser_page
    page.set_viewport_size({"width": 1366, "height": 768})
    three, seven = contact(3, 10.0, 25.0, 1.2, 8.0), contact(7, 28.0, 8.0, 0.4, 5.0)
    with Injector(server, {"pad": [three, seven]}) as injector:
        page.goto(server.url + "/")
        page.wait_for_function(
            "() => JSON.parse(document.querySelector('#sensor-pad canvas.overlay')"
            "?.dataset.contacts || '[]').length === 2", timeout=30_000)
        sent = http(server.url, "GET", "/v1/sensors/pad/estimate").json()["contacts"]
        assert [c["contact_id"] for c in sent] == [3, 7]
        assert all(c["ellipse"] and c["ellipse"]["a_mm"] > 0 for c in sent), sent
        drawn = {d["id"]: d for d in json.loads(
            page.get_attribute("#sensor-pad canvas.overlay", "data-contacts"))}
        assert sorted(drawn) == [3, 7]
        # where each should be: tactel [0, 0]'s centre is x = y = 0, y up, at the array's scale
        grid = drawn_array(page, "pad")
        k = grid["width"] / (16 * 2.5)
        for c in sent:
            d = drawn[c["contact_id"]]
            x = grid["left"] + (c["x_mm"] + 1.25) * k
            y = grid["top"] + grid["height"] - (c["y_mm"] + 1.25) * k
            assert abs(d["x"] - x) <= 1.5 and abs(d["y"] - y) <= 1.5, (c["contact_id"], d, x, y)
            assert d["a"] == pytest.approx(c["ellipse"]["a_mm"] * k, abs=1.0)
            # the ellipse is drawn there, in green, and its id in white beside it
            assert ellipse_is_green(page, d), d
            assert id_is_written(page, d), d
        assert page.text_content("#sensor-pad [data-k=contact]") == "2 contacts"
        assert page.text_content("#sensor-pad [data-k=force_n]") == "1.200 ± 0.010 N"

        # click contact 7: the panel follows it, with its own values
        overlay = page.locator("#sensor-pad canvas.overlay").bounding_box()
        scale = overlay["width"] / float(page.get_attribute("#sensor-pad canvas.overlay", "width"))
        page.mouse.click(overlay["x"] + drawn[7]["x"] * scale, overlay["y"] + drawn[7]["y"] * scale)
        page.wait_for_function("() => { const p = document.querySelector('#follow-panel');"
                               " return p.dataset.mode === 'contact' &&"
                               " p.dataset.contactId === '7'; }", timeout=30_000)
        assert page.text_content("#follow") == "pad · contact 7 (clicked contact)"
        page.wait_for_function("() => document.querySelector('#follow-panel [data-k=force_n]')"
                               ".textContent === '0.400 ± 0.010 N'", timeout=30_000)
        # contact 7 ends: back to the strongest (3), saying why
        injector.contacts = {"pad": [three]}
        page.wait_for_function("() => document.querySelector('#follow-panel').dataset.mode"
                               " === 'auto'", timeout=10_000)
        label = page.text_content("#follow")
        assert label.startswith("pad · contact 3 (the strongest contact)"), label
        assert "contact 7 on pad ended" in label
    assert not errors, errors


def test_following_the_strongest_contact_of_any_sensor(browser_page, live_server, pty_device,
                                                     tmp_path):
    """Injected (as in the test above): estimates of two silent sensors, ``pad`` (flat16) and
    ``tip`` (robotiq_tsf85), each listing its contacts; their forces change step by step and
    the panel follows the strongest contact of any sensor, changing sensor only for a force 20 %
    larger than the one it follows."""
    second = type(pty_device)(tmp_path / "ttyTACT2")
    try:
        server = live_server(sim_settings(2, **silent_sensor("pad", "flat16", pty_device, 0),
                                          **silent_sensor("tip", "robotiq_tsf85", second, 1)))
        page, errors = browser_page
        steps = [  # pad's strongest, tip's, the contact followed
            (1.2, 0.5, "pad · contact 3"),
            (1.2, 2.0, "tip · contact 1"),   # 2.0 > 1.2 * 1.2: the tip now
            (1.4, 1.3, "tip · contact 1"),   # the pad is stronger, by less than 20 %: stays
            (1.7, 1.3, "pad · contact 3"),   # 1.7 > 1.3 * 1.2: the pad again
        ]
        def hand(pad_force: float, tip_force: float) -> dict[str, list[dict]]:
            return {"pad": [contact(3, 10.0, 25.0, pad_force, 8.0),
                            contact(7, 28.0, 8.0, 0.4, 5.0)],
                    "tip": [contact(1, 12.0, 6.0, tip_force, 6.0)]}

        with Injector(server, hand(*steps[0][:2])) as injector:
            page.goto(server.url + "/")
            for pad_force, tip_force, followed in steps:
                injector.contacts = hand(pad_force, tip_force)
                # both sensors show the new forces, then the panel's choice is read
                page.wait_for_function(
                    "f => f.every(([s, v]) => document.querySelector("
                    "`#sensor-${s} [data-k=force_n]`).textContent.startsWith(v))",
                    arg=[["pad", f"{pad_force:.3f}"], ["tip", f"{tip_force:.3f}"]],
                    timeout=10_000)
                page.wait_for_timeout(200)  # a few frames of the page's own loop
                label = page.text_content("#follow")
                assert label == f"{followed} (the strongest contact)", (pad_force, tip_force, label)
                assert page.get_attribute(PANEL, "data-mode") == "auto"
        assert not errors, errors
    finally:
        second.close()


def ellipse_is_green(page: Any, d: dict) -> bool:
    """Green (#39d353) on the overlay within 2 px of both ends of the ellipse's major axis."""
    return page.evaluate("""d => {
        const c = document.querySelector('#sensor-pad canvas.overlay');
        const ctx = c.getContext('2d'), t = d.theta_deg * Math.PI / 180;
        return [1, -1].every(sign => {
            const x = Math.round(d.x + sign * d.a * Math.cos(t));
            const y = Math.round(d.y - sign * d.a * Math.sin(t));
            const px = ctx.getImageData(x - 2, y - 2, 5, 5).data;
            for (let i = 0; i < px.length; i += 4)
                if (px[i + 1] > 150 && px[i] < 120 && px[i + 3] > 200) return true;
            return false;
        });
    }""", d)


def id_is_written(page: Any, d: dict) -> bool:
    """White text pixels up and to the right of the contact's centre, past its dot."""
    return page.evaluate("""d => {
        const c = document.querySelector('#sensor-pad canvas.overlay');
        const r = Math.min(d.b, 18);
        const x = Math.round(d.x + r * 0.7 + 3), y = Math.round(d.y - r * 0.7 - 3);
        const px = c.getContext('2d').getImageData(x, y - 10, 16, 11).data;
        let n = 0;
        for (let i = 0; i < px.length; i += 4)
            if (px[i] > 220 && px[i + 1] > 220 && px[i + 2] > 220) n++;
        return n >= 6;
    }""", d)

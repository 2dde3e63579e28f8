"""Driving the dashboard in the browser and measuring what it drew, in the page's own
pixels (Playwright pages)."""

from __future__ import annotations

from typing import Any

PANEL = "#follow-panel"


def follow(page: Any, sensor: str) -> None:
    """Click the sensor's title: the follow panel (readouts, strip chart) shows that sensor."""
    page.click(f"#sensor-{sensor} h2 .name")
    page.wait_for_function(
        "s => { const p = document.querySelector('#follow-panel');"
        " return p.dataset.mode === 'sensor' && p.dataset.sensor === s; }",
        arg=sensor, timeout=30_000)


def wait_numeric_seq(page: Any, sensor: str, timeout_ms: int = 30_000) -> None:
    """Wait until the sensor's tile shows a frame sequence number (its first estimate)."""
    page.wait_for_function(
        "s => /^\\d+$/.test(document.querySelector(`#sensor-${s} [data-k=seq]`)"
        "?.textContent || '')", arg=sensor, timeout=timeout_ms)


# The tactel grid of a sensor's map measured on its canvas: the grid colour (the lines between
# tactels, data-grid) bounds the drawn array; the tactels along x are the most runs of other
# colours on any pixel row across it, those along y the most on any pixel column.
_MEASURE = """s => {
    const c = document.querySelector(`#sensor-${s} canvas.map`);
    const g = c.dataset.grid, rgb = [1, 3, 5].map(i => parseInt(g.slice(i, i + 2), 16));
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    const grid = (x, y) => {
        const i = 4 * (y * c.width + x);
        return d[i] === rgb[0] && d[i + 1] === rgb[1] && d[i + 2] === rgb[2];
    };
    let x0 = c.width, x1 = -1, y0 = c.height, y1 = -1;
    for (let y = 0; y < c.height; y++) for (let x = 0; x < c.width; x++) {
        if (grid(x, y)) {
            x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y);
        }
    }
    const runs = (n, at) => {
        let count = 0, inside = false;
        for (let i = 0; i < n; i++) {
            const cell = !at(i);
            if (cell && !inside) count++;
            inside = cell;
        }
        return count;
    };
    let rows = 0, cols = 0;
    for (let y = y0; y <= y1; y++) rows = Math.max(rows, runs(x1 - x0 + 1, i => grid(x0 + i, y)));
    for (let x = x0; x <= x1; x++) cols = Math.max(cols, runs(y1 - y0 + 1, i => grid(x, y0 + i)));
    return {rows, cols, width: x1 - x0 + 1, height: y1 - y0 + 1, left: x0, top: y0,
            canvas_height: c.height};
}"""


def drawn_array(page: Any, sensor: str) -> dict[str, int]:
    """The sensor's array as its map canvas shows it: tactels counted along x (``rows``) and
    along y (``cols``), and the array's drawn ``width``, ``height``, ``left``, ``top`` in canvas
    pixels (``canvas_height`` too, y being up on the map)."""
    return page.evaluate(_MEASURE, sensor)

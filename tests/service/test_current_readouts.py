"""What the daemon says now is about now: an estimate's ``peak`` is its own frame's largest
strain (not that of the fit the tracker measures it through), health's ``fit_rate_hz`` counts
the fits the workers return (the same fits ``workers.fits`` counts) and ``tracked_rate_hz`` the
contact frames the tracker measured without a fit.  Against a real server (uvicorn on
127.0.0.1, the real daemon on the simulated finger playing a moving contact), one for the
module: both tests only read from it."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from live import LiveServer
from svc_helpers import http, recv_until, sim_settings, subscribe, ws_connect

MOVING = "sim://?scene=moving&seed=1&sensor_id=0"


@pytest.fixture(scope="module")
def moving_server() -> Iterator[LiveServer]:
    """The simulated finger playing a moving contact, served for the whole module."""
    server = LiveServer(sim_settings(1, **{"sensor[0].url": MOVING}), shared=True).start()
    try:
        yield server
    finally:
        server.stop()


def test_peak_is_the_frame_s_own_while_the_tracker_answers(moving_server, arun):
    server = moving_server

    async def main() -> list[dict]:
        async with ws_connect(server.ws_url) as ws:
            await subscribe(ws, streams=["estimates", "frames"])

            def enough(ms: list[dict]) -> bool:
                frames = {m["seq"] for m in ms if m["type"] == "frame"}
                tracked = [m for m in ms if m["type"] == "estimate" and m["contact"]
                           and m["gate"] == "unchanged" and m["seq"] in frames]
                return len(tracked) >= 200
            return await recv_until(ws, enough, 40)

    msgs = arun(main())
    frames = {m["seq"]: m for m in msgs if m["type"] == "frame"}
    tracked = [m for m in msgs if m["type"] == "estimate" and m["contact"]
               and m["gate"] == "unchanged" and m["seq"] in frames]
    assert all(e["fitted_seq"] != e["seq"] for e in tracked)
    for e in tracked:
        frame_peak = max(max(row) for row in frames[e["seq"]]["strain"])
        assert abs(e["peak"] - frame_peak) <= 1e-6, (e["seq"], e["fitted_seq"], e["peak"],
                                                     frame_peak)
    # a moving contact: the frames' peaks differ from the fits' they rest on
    assert len({round(e["peak"], 5) for e in tracked}) > len({e["fitted_seq"] for e in tracked})
    # and the latest estimate over REST says the same as the stream (one field, one meaning)
    est = http(server.url, "GET", "/v1/sensors/finger0/estimate").json()
    assert set(est) >= {"peak", "seq", "gate"}


def test_fit_and_tracked_rates_count_what_happens(moving_server):
    server = moving_server

    def health() -> tuple[float, dict]:
        h = http(server.url, "GET", "/v1/health").json()
        return time.monotonic(), h

    deadline = time.monotonic() + 40
    windows = []
    while len(windows) < 3 and time.monotonic() < deadline:
        t1, h1 = health()
        time.sleep(1.0)
        t2, h2 = health()
        s1, s2 = h1["sensors"]["finger0"], h2["sensors"]["finger0"]
        fits = (h2["workers"]["fits"] - h1["workers"]["fits"]) / (t2 - t1)
        tracked = (s2["tracked"] - s1["tracked"]) / (t2 - t1)
        if tracked > 50:  # in contact, the tracker answering
            windows.append((fits, s2["fit_rate_hz"], tracked, s2["tracked_rate_hz"]))
    assert len(windows) == 3, windows
    for fits, fit_rate, tracked, tracked_rate in windows:
        assert fits > 0, windows
        # counted over the last second at the server, the pair of requests around ~1 s here
        assert abs(fit_rate - fits) <= 0.4 * fits + 5, windows
        assert abs(tracked_rate - tracked) <= 0.4 * tracked + 5, windows

"""The WebSocket stream against a real server and the real daemon: the pinned contract,
subscription variants, bad messages, message size limit, no compression."""

from __future__ import annotations

import asyncio
import json
from collections import defaultdict

import pytest
from svc_helpers import FIT_LINE_KEYS, recv_json, recv_until, subscribe, ws_connect
from websockets.exceptions import ConnectionClosed

from tactiled.pipeline import tracked_run

SENSORS = {"finger0", "finger1"}


def test_pinned_contract_estimates_carry_the_fit_line_keys(shared_server, arun):
    """PINNED for outside clients: version first; then {"type": "subscribe", "streams":
    ["estimates"]} brings, for every sensor, {"type": "estimate", "sensor", "seq", ...} with
    every key of a `tactiled fit` line."""

    async def main() -> None:
        async with ws_connect(shared_server.ws_url) as ws:
            version = await recv_json(ws)
            assert version["type"] == "version"
            assert isinstance(version["v"], int) and "seq" in version
            await ws.send(json.dumps({"type": "subscribe", "streams": ["estimates"]}))
            msgs = await recv_until(ws, lambda ms: all(
                sum(m["type"] == "estimate" and m["sensor"] == s for m in ms) >= 3
                for s in SENSORS), timeout=20)
        by_sensor: dict[str, list[dict]] = defaultdict(list)
        for m in msgs:
            if m["type"] == "estimate":
                by_sensor[m["sensor"]].append(m)
        assert {m["type"] for m in msgs} <= {"subscribed", "estimate"}
        for sensor, ests in by_sensor.items():
            assert sensor in SENSORS
            for m in ests:
                assert m["type"] == "estimate" and m["sensor"] == sensor
                assert isinstance(m["seq"], int) and isinstance(m["v"], int)
                missing = FIT_LINE_KEYS - set(m)
                assert not missing, f"estimate lacks fit-line keys {sorted(missing)}"
                assert "ellipse" in m
            seqs = [m["seq"] for m in ests]
            assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)

    arun(main())


def test_contact_estimates_carry_a_drawable_ellipse(shared_server, arun):
    async def main() -> list[dict]:
        async with ws_connect(shared_server.ws_url) as ws:
            await subscribe(ws, streams=["estimates"], sensors=["finger0"])
            return await recv_until(
                ws, lambda ms: any(m.get("contact") and m.get("ellipse") for m in ms), 40)

    est = next(m for m in arun(main()) if m.get("contact") and m.get("ellipse"))
    ell = est["ellipse"]
    assert ell["a_mm"] >= ell["b_mm"] > 0
    assert 0 <= ell["theta_deg"] < 180


def test_subscribe_to_one_sensor_and_frames(shared_server, arun):
    async def main() -> list[dict]:
        async with ws_connect(shared_server.ws_url) as ws:
            reply = await subscribe(ws, sensors=["finger1"], streams=["frames"])
            assert reply["sensors"] == ["finger1"] and reply["streams"] == ["frames"]
            return await recv_until(ws, lambda ms: len(ms) >= 20, 15)

    msgs = arun(main())
    assert {(m["type"], m["sensor"]) for m in msgs} == {("frame", "finger1")}
    frame = msgs[-1]
    assert frame["rows"] == len(frame["strain"]) == 8
    assert all(len(row) == frame["cols"] == 8 for row in frame["strain"])
    assert isinstance(frame["seq"], int) and frame["v"] >= 1


def test_subscribe_to_both_streams(shared_server, arun):
    async def main() -> list[dict]:
        async with ws_connect(shared_server.ws_url) as ws:
            await subscribe(ws, streams=["estimates", "frames"])
            return await recv_until(
                ws, lambda ms: {(m["type"], m["sensor"]) for m in ms} >= {
                    (t, s) for t in ("estimate", "frame") for s in SENSORS}, 20)

    assert {m["type"] for m in arun(main())} == {"estimate", "frame"}


def test_frame_subscribers_see_a_tracked_contacts_frames(shared_server, arun, monkeypatch):
    """A tracked contact's frames that go through the core's tracked runs (which publish
    their zeroed frames as records only for those who take them) reach a frames subscriber,
    seq for seq, in contact, with their tracked estimates.  (The server runs in this process:
    the runs' frames are noted as the real TrackedRun.publish is called.)"""
    ran: set[int] = set()  # finger0's frames a tracked run stepped
    publish = tracked_run.TrackedRun.publish

    def noted(self, pipe, run, *args, **kwargs):
        if pipe.name == "finger0":
            ran.update(f.seq for f in run[:self.tracked])
        return publish(self, pipe, run, *args, **kwargs)

    monkeypatch.setattr(tracked_run.TrackedRun, "publish", noted)

    tracked: set[int] = set()  # seqs of finger0's estimates gated "unchanged"
    framed: dict[int, dict] = {}  # finger0's frames by seq
    seqs: set[int] = set()  # frames a tracked run stepped, seen as frames and estimates

    def done(ms: list[dict]) -> bool:  # (one message at a time: the client keeps up)
        m = ms[-1] if ms else {}
        if m.get("type") == "estimate" and m["gate"] == "unchanged":
            tracked.add(m["seq"])
        elif m.get("type") == "frame":
            framed[m["seq"]] = m
        else:
            return False
        if m["seq"] in ran and m["seq"] in tracked and m["seq"] in framed:
            seqs.add(m["seq"])
        return len(seqs) >= 20

    async def main() -> list[dict]:
        async with ws_connect(shared_server.ws_url) as ws:
            await subscribe(ws, streams=["estimates", "frames"], sensors=["finger0"])
            return await recv_until(ws, done, 40)

    msgs = arun(main())
    frames = [m for m in msgs if m["type"] == "frame"]
    assert all(framed[q]["contact"] for q in seqs)
    assert [m["seq"] for m in frames] == sorted(framed)
    assert all(len(framed[q]["strain"]) == framed[q]["rows"] == 8 for q in seqs)


def test_max_rate_caps_messages_per_sensor(shared_server, arun):
    """max_rate 20 Hz: over ~1.5 s at most about 20/s per sensor arrive, while the sensors
    publish near 1 kHz."""

    async def main() -> dict[str, int]:
        async with ws_connect(shared_server.ws_url) as ws:
            await subscribe(ws, streams=["estimates"], max_rate=20)
            counts: dict[str, int] = defaultdict(int)
            loop = asyncio.get_running_loop()
            await recv_json(ws)  # the first may come at once
            start = loop.time()
            while loop.time() - start < 1.5:
                m = await recv_json(ws)
                counts[m["sensor"]] += 1
            return counts

    counts = arun(main())
    assert set(counts) == SENSORS
    for n in counts.values():
        assert 10 <= n <= 20 * 1.5 + 3, counts


def test_resubscribe_replaces_and_unsubscribe_stops(shared_server, arun):
    async def main() -> None:
        async with ws_connect(shared_server.ws_url) as ws:
            await subscribe(ws, streams=["estimates"], sensors=["finger0"])
            await ws.send(json.dumps({"type": "subscribe", "streams": ["frames"],
                                      "sensors": ["finger1"]}))
            msgs = await recv_until(ws, lambda ms: any(m["type"] == "subscribed" for m in ms))
            after = await recv_until(ws, lambda ms: len(ms) >= 10)
            assert {(m["type"], m["sensor"]) for m in after} == {("frame", "finger1")}
            await ws.send(json.dumps({"type": "unsubscribe"}))
            rest = await recv_until(ws, lambda ms: ms[-1:] and ms[-1]["type"] == "unsubscribed")
            assert {(m["type"], m.get("sensor")) for m in msgs} <= {
                ("estimate", "finger0"), ("subscribed", None)}
            assert {(m["type"], m.get("sensor")) for m in rest} <= {
                ("frame", "finger1"), ("unsubscribed", None)}
            with pytest.raises(TimeoutError):
                await recv_json(ws, timeout=0.5)  # nothing after unsubscribing
            await ws.send(json.dumps({"type": "ping", "id": 7}))
            pong = await recv_json(ws)
            assert pong == {"type": "pong", "v": pong["v"], "seq": None, "id": 7}

    arun(main())


BAD = [
    ("{not json", "not valid JSON"),
    ("[1, 2]", "JSON object"),
    ('{"streams": ["estimates"]}', "missing \"type\""),
    ('{"type": "watch"}', "unknown message type 'watch'"),
    ('{"type": "subscribe", "streams": ["estimate"]}', "streams.0"),
    ('{"type": "subscribe", "streams": []}', "streams"),
    ('{"type": "subscribe", "max_rate": -1}', "max_rate"),
    ('{"type": "subscribe", "max_rate": 1e9}', "max_rate"),
    ('{"type": "subscribe", "max_rate": "10"}', "max_rate: Input should be a valid number"),
    ('{"type": "subscribe", "max_rate": Infinity}', "max_rate"),
    ('{"type": 5}', "unknown message type '5'"),
    ('{"type": "subscribe", "sensors": "finger0"}', "sensors: Input should be a valid list"),
    ('{"type": "subscribe", "sensors": ["finger9"]}', "unknown sensor(s) 'finger9'"),
    ('{"type": "subscribe", "sensor": ["finger0"]}', "sensor"),
]


def test_bad_messages_get_an_error_and_the_connection_stays(shared_server, arun):
    async def main() -> None:
        async with ws_connect(shared_server.ws_url) as ws:
            assert (await recv_json(ws))["type"] == "version"
            for text, words in BAD:
                await ws.send(text)
                reply = await recv_json(ws)
                assert reply["type"] == "error", (text, reply)
                assert words in reply["message"], (text, reply["message"])
                assert reply["v"] >= 1 and reply["seq"] is None
            await ws.send(b"\x00binary")
            reply = await recv_json(ws)
            assert reply["type"] == "error" and "binary" in reply["message"]
            # Still connected and still served.
            await ws.send(json.dumps({"type": "subscribe", "streams": ["estimates"]}))
            msgs = await recv_until(ws, lambda ms: any(m["type"] == "estimate" for m in ms))
            assert msgs[0]["type"] == "subscribed"

    arun(main())


def test_oversized_message_closes_with_1009(shared_server, arun):
    async def main() -> None:
        async with ws_connect(shared_server.ws_url) as ws:
            await recv_json(ws)
            await ws.send(json.dumps({"type": "ping", "pad": "x" * (64 * 1024)}))
            with pytest.raises(ConnectionClosed) as info:
                while True:
                    await recv_json(ws)
            assert info.value.rcvd is not None and info.value.rcvd.code == 1009

    arun(main())


def test_a_message_just_under_the_limit_is_accepted(shared_server, arun):
    async def main() -> None:
        async with ws_connect(shared_server.ws_url) as ws:
            await recv_json(ws)
            text = json.dumps({"type": "ping", "id": 1, "pad": ""})
            text = text.replace('"pad": ""', '"pad": "' + "x" * (64 * 1024 - len(text)) + '"')
            assert len(text) == 64 * 1024
            await ws.send(text)
            assert (await recv_json(ws))["type"] == "pong"

    arun(main())


def test_no_per_message_compression(shared_server, arun):
    async def main() -> None:
        async with ws_connect(shared_server.ws_url, compression="deflate") as ws:
            assert ws.response.headers.get("Sec-WebSocket-Extensions") is None
            assert (await recv_json(ws))["type"] == "version"

    arun(main())

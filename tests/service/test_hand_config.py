"""The shipped example of a whole simulated hand (deploy/hand.toml): six arrays, each the part
of the hand scene its name says, served by a real server and read by a real WebSocket client
until every part has been touched and the palm has listed several contacts at once."""

from __future__ import annotations

from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from svc_helpers import recv_until, subscribe, ws_connect

from tactiled.sensors import load_description
from tactiled.settings import load_settings

HAND = Path(__file__).resolve().parents[2] / "deploy" / "hand.toml"
PARTS = {f"finger{k}": ("hand-finger" + str(k), "fearing1988") for k in range(1, 6)}
PARTS["palm"] = ("hand-palm", "flat16")


def test_the_example_names_six_arrays_each_its_part_of_the_hand() -> None:
    settings = load_settings(HAND, {}, {})
    assert settings.server.host == "127.0.0.1"
    assert [s.name for s in settings.sensors] == list(PARTS)
    for s in settings.sensors:
        query = {k: v[0] for k, v in parse_qs(urlsplit(s.url).query).items()}
        scene, description = PARTS[s.name]
        assert (query["scene"], query["sensor"], s.description) == (scene, description, description)
        assert int(query["sensor_id"]) == s.wire_id  # the check of a swapped cable is on
        load_description(s.description)  # a description the daemon knows


def test_the_example_runs_a_hand_whose_palm_lists_several_contacts(live_server, arun) -> None:
    settings = load_settings(HAND, {}, {"server.port": 0, "fit.workers": 1})
    server = live_server(settings)

    def done(msgs: list[dict]) -> bool:
        touched = {m["sensor"] for m in msgs if m.get("type") == "estimate" and m["contacts"]}
        palm = any(m.get("sensor") == "palm" and len(m.get("contacts") or ()) >= 2 for m in msgs)
        return touched == set(PARTS) and palm

    async def main() -> list[dict]:
        async with ws_connect(server.ws_url) as ws:
            await subscribe(ws, streams=["estimates"])
            return await recv_until(ws, done, 45)  # the scenes loop every 4 s

    msgs = [m for m in arun(main()) if m.get("type") == "estimate"]
    assert {m["sensor"] for m in msgs} == set(PARTS)
    for m in msgs:
        ids = [c["contact_id"] for c in m["contacts"]]
        assert len(set(ids)) == len(ids)

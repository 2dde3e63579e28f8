"""Several contacts through the live daemon: a simulated palm (flat16) playing the hand scene,
whose grasp presses two and three knuckles at once, read by a real WebSocket client from a
real server; the REST estimate lists the same contacts."""

from __future__ import annotations

from svc_helpers import http, recv_until, sim_settings, subscribe, ws_connect


def test_the_stream_lists_every_contact_of_a_grasp_with_stable_ids(live_server, arun) -> None:
    settings = sim_settings(1, **{"sensor[0].name": "palm", "sensor[0].description": "flat16",
                                  "sensor[0].url": "sim://?sensor=flat16&scene=hand-palm&seed=1&rate=200",
                                  "sensor[0].model": "sphere"})
    server = live_server(settings)

    async def main() -> list[dict]:
        async with ws_connect(server.ws_url) as ws:
            await subscribe(ws, streams=["estimates"], sensors=["palm"])
            # the scene loops every 4 s: a whole grasp, with its three knuckles at once
            return await recv_until(
                ws, lambda ms: sum(len(m.get("contacts", ())) >= 3 for m in ms) >= 20, 45)

    msgs = [m for m in arun(main()) if m["type"] == "estimate"]
    several = [m for m in msgs if len(m["contacts"]) >= 2]
    assert len(several) >= 20
    for m in msgs:
        ids = [c["contact_id"] for c in m["contacts"]]
        assert len(set(ids)) == len(ids)  # one id per contact
        if m["contacts"]:
            # the top level is the strongest contact, listed first
            assert m["contact_id"] == ids[0] and m["force_n"] == m["contacts"][0]["force_n"]
            forces = [c["force_n"] for c in m["contacts"] if c["force_n"] is not None]
            assert m["force_n"] == (max(forces) if forces else None)
            assert len(ids) == 1 or all(
                c["reasons"].get("contacts", "").startswith(f"one of {len(ids)} contacts")
                for c in m["contacts"]), (m["gate"], [c["reasons"] for c in m["contacts"]])
        else:
            assert m["contact_id"] is None
    # while the grasp holds, the knuckles keep their ids: few ids for many frames
    held = {c["contact_id"] for m in several for c in m["contacts"]}
    assert len(held) <= 3 * 3, held
    # the REST estimate is the same object as the stream's
    est = http(server.url, "GET", "/v1/sensors/palm/estimate").json()
    assert est["type"] == "estimate" and "contacts" in est and "contact_id" in est

"""The daemon's shear track on 3-axis frames (tactiled.pipeline.shear_track): the zero learned
from free frames, the tables of the strongest contact against the scene's truth, slip onsets
published on the hub for a pull-until-slip scene and none for a push (stick only), and the hub
keeping slip events from listeners that did not ask for them."""

from __future__ import annotations

import asyncio
import math

import numpy as np

from tactiled.frames import Frame
from tactiled.pipeline.hub import Hub
from tactiled.pipeline.shear_track import NO_ZERO, for_sensor
from tactiled.sensors import load_description
from tactiled.sim.shear import sequence

REST = np.array([0x8000, 0x8000, 10000.0])


def frames_of(readings: np.ndarray, start: int) -> list[Frame]:
    out = []
    for k, r in enumerate(readings):
        counts = np.round(r + REST).astype(np.uint16)
        out.append(Frame(seq=start + k, device_time_us=(start + k) * 1000, raw=counts[..., 2].copy(),
                         sensor_id=1, host_time=float(start + k), taxels=counts))
    return out


async def play(kind: str, seed: int) -> tuple[list, list, dict]:
    """A scene after 60 frames at rest, the scene's contact frames those with a true force over
    0.3 N.  Every tenth frame waits for the fits under way (as a daemon fitting at ~100 Hz
    would see them: the frames between are superseded for the fit and estimated by the step)."""
    desc = load_description("xela_uskin_4x4")
    hub = Hub()
    events: list = []
    hub.add_listener(events.append, events=True)
    plain: list = []
    hub.add_listener(plain.append)
    track = for_sensor(desc, "xela", hub.publish)
    assert track is not None and for_sensor(load_description("fearing1988"), "f", hub.publish) is None
    rng = np.random.default_rng(seed)
    noise = np.array(desc.axis_noise)
    rest = rng.normal(size=(60, 4, 4, 3)) * noise
    scene, truth = sequence(desc, kind, rng)
    tables = []
    for k, frame in enumerate(frames_of(rest, 0)):
        track.on_frame(frame, False)
    fit = {"contact": True, "contact_id": 7, "reasons": {}, "contacts": [{"contact": True, "contact_id": 7}]}
    for k, frame in enumerate(frames_of(scene, 60)):
        contact = truth["true_force"][k] > 0.3
        track.on_frame(frame, contact)
        while k % 10 == 0 and track._busy:  # the fit in its thread: wait for it (a condition, not a sleep)
            await asyncio.sleep(0.001)
        tables.append((k, track.annotate(fit) if contact else None))
    track.close()
    return tables, [e for e in events if e.kind == "slip"], {"truth": truth, "plain": plain}


def test_pull_declares_an_onset_near_the_truth_and_tables_follow_it() -> None:
    tables, events, info = asyncio.run(play("pull", 3))
    truth = info["truth"]
    onset = int(truth["true_onset"])
    onsets = [e for e in events if e.event == "onset"]
    assert len(onsets) == 1
    declared = onsets[0].seq - 60
    assert 0 <= declared - onset <= 5, (declared, onset)
    assert onsets[0].contact_id == 7 and onsets[0].state == "slip"
    assert not info["plain"]  # a listener that did not ask for events sees none
    # before the onset: fx, fy within 3 sigma of the truth on most frames
    inside = []
    for k, doc in tables:
        if doc is None or doc["shear"] is None or k >= onset:
            continue
        sh = doc["shear"]
        assert doc["contacts"][0]["shear"] is sh
        for key, true in (("fx_n", truth["true_fx"][k]), ("fy_n", truth["true_fy"][k])):
            inside.append(abs(sh[key] - true) <= 3 * sh["std"][key])
    assert len(inside) > 100 and np.mean(inside) >= 0.95
    after = [doc for k, doc in tables if doc is not None and doc["slip"] and k >= declared]
    assert after and after[0]["slip"]["state"] == "slip"
    assert after[0]["slip"]["onset"]["seq"] == onsets[0].seq


def test_push_declares_no_slip() -> None:
    tables, events, _ = asyncio.run(play("push", 4))
    assert events == []
    slips = [doc["slip"] for _, doc in tables if doc and doc["slip"]]
    assert len(slips) > 100 and all(s["onset"] is None and s["end"] is None for s in slips)


def test_no_zero_yet_is_said() -> None:
    desc = load_description("xela_uskin_4x4")
    track = for_sensor(desc, "xela", lambda item: None)
    counts = np.full((4, 4, 3), 0x8000, dtype=np.uint16)
    track.on_frame(Frame(seq=0, device_time_us=0, raw=counts[..., 2].copy(), taxels=counts), True)
    doc = track.annotate({"contact": True, "contact_id": 1, "reasons": {}})
    assert doc["shear"] is None and doc["reasons"]["shear"] == NO_ZERO
    assert track.annotate({"contact": False}) == {"contact": False}
    track.close()
    assert math.isfinite(track.frames)

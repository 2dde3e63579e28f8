"""Slip events through a paced WebSocket subscription: `max_rate` paces estimates and frames
(the newest wins), but every slip event reaches the subscriber, in order, however close
together; the encoder gives a slip item its own message."""

from __future__ import annotations

from tactiled.pipeline.estimate import make_estimate
from tactiled.pipeline.hub import Subscription
from tactiled.pipeline.shear_track import SlipItem
from tactiled_service.json_messages import Encoder
from tactiled_service.stream import PaceGroup, Spec


def slip(seq: int, event: str) -> SlipItem:
    return SlipItem("xela", 1, seq, seq * 1000, float(seq), 1.7e9 + seq, event, 3,
                    "slip" if event == "onset" else "stick")


def test_slip_events_are_never_paced() -> None:
    spec = Spec(None, frozenset({"estimate", "slip"}), max_rate=1.0)
    group = PaceGroup(spec)
    sub = Subscription(None, None, spec.kinds, 100)
    group.members.append(sub)
    items = []
    for seq in range(1, 7):
        est = make_estimate(sensor="xela", sensor_id=1, seq=seq, device_time_us=seq,
                            host_time=float(seq), gate="fit", fitted_seq=seq, worker_ms=0.0,
                            fit={"contact": False})
        items += [est, slip(seq, "onset" if seq % 2 else "end")]
    for item in items:  # all within one pacing period
        group.offer(item, now=100.0)
    got = [sub.get_nowait() for _ in range(sub.qsize())]
    slips = [g for g in got if g.kind == "slip"]
    assert [s.seq for s in slips] == [1, 2, 3, 4, 5, 6]
    assert sum(g.kind == "estimate" for g in got) == 1  # the first; later ones held/coalesced


def test_slip_message() -> None:
    msg = Encoder({}).message(slip(7, "onset"))
    assert msg["type"] == "slip" and msg["v"] >= 2
    assert (msg["event"], msg["seq"], msg["contact_id"], msg["state"]) == ("onset", 7, 3, "slip")
    assert "ellipse" not in msg and "rows" not in msg

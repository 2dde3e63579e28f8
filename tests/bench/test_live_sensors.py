"""``tactiled bench --suite sensors``'s live part: the daemon's own estimates of the demo scene
on a coarse pad (XELA 4x4: without the gate's carry limit one fit was reused for 220 frames
while the cylinder rolled), through the whole daemon with real worker processes, scored
against the simulator's truth (tactiled/bench/live_sensors.py).

Bars: no value bit-identical for more than ``MAX_CARRIED`` + 1 estimates while its contact
moves; no estimate listing a second contact on a pad touched once; at least 85 % of the
published values within 2 of their sigmas; the share of estimates with a value beyond 4
sigma under 5 % (what this pad gives: 2.6 %, docs/performance/fit-time.md; the 1 % the
paper's finger and the 16x16 pad meet is not met on the coarse pads).
"""

from __future__ import annotations

from tactiled.bench import live_sensors
from tactiled.pipeline.gate import MAX_CARRIED
from tactiled.sensors import load_description


def test_the_daemon_on_a_coarse_pad_against_the_truth() -> None:
    desc = load_description("xela_uskin_4x4")
    s = live_sensors.score(desc, rate=100.0, seed=1)
    c = s["counts"]
    assert c["contact_estimates"] >= 1000, c
    assert c["phantom"] == 0, c
    assert max(s["stale"].values()) <= MAX_CARRIED + 1, s["stale"]
    published = sum(s["n"].values()) - sum(s["withheld"].values())
    assert published >= 2000
    assert sum(s["covered"].values()) >= 0.85 * published
    assert c["with_far"] <= 0.05 * c["contact_estimates"], c
    lines = live_sensors.report(desc, s, 100.0)
    assert any(line.startswith("| offset |") for line in lines)

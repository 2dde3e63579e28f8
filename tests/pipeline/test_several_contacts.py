"""Several contacts on one array through the whole daemon: a recording of two contacts (one
held, one pressed beside it, then lifted) replayed by ``tactiled replay`` (real worker
processes): each estimate lists its contacts with stable ids, the top level is the strongest."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from pipeline_helpers import PERIOD_US, SETTLE_FRAMES, write_recording

from tactiled.calibration.lut import LookupTable
from tactiled.cli import main as cli
from tactiled.frames import Frame
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel

SIGMA = 0.0005


def _frames() -> tuple[list[Frame], list[list[Contact]]]:
    model = StrainModel()
    rng = np.random.default_rng(7)
    a = lambda k: Contact(5.0, 5.0, 0.0, 1.2, 5.0 + 0.01 * k, 12.0)  # noqa: E731 (rolls slowly)
    b = Contact(8.0, 8.0, 0.0, 0.6, 18.0, 16.0)
    scene: list[list[Contact]] = ([[]] * SETTLE_FRAMES + [[a(k)] for k in range(20)]
                                  + [[a(20 + k), b] for k in range(30)] + [[a(50 + k)] for k in range(20)]
                                  + [[]] * 10)
    strain = [sum((model.predict(c) for c in cs), np.zeros((8, 8))) + rng.normal(0.0, SIGMA, (8, 8))
              for cs in scene]
    counts = LookupTable.linear().to_counts(np.array(strain))
    return [Frame(seq=k, device_time_us=k * PERIOD_US, raw=c, sensor_id=0)
            for k, c in enumerate(counts)], scene


def test_each_contact_is_listed_with_a_stable_id(tmp_path: Path, capsys) -> None:
    frames, scene = _frames()
    rec = write_recording(tmp_path / "two.tact", frames)
    assert cli(["replay", str(rec), "--mode", "lossless", "--speed", "0", "--no-timing",
                "--model", "sphere"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert len(lines) == len(frames)
    held_ids, second_ids = set(), set()
    released = SETTLE_FRAMES + 70  # the first frame after the last contact lifted
    for line, truth in zip(lines, scene):
        if not truth:
            if line["seq"] < SETTLE_FRAMES or line["seq"] >= released + 3:  # (the detector's exit)
                assert line["contacts"] == [] and line["contact_id"] is None, line["seq"]
            continue
        assert len(line["contacts"]) == len(truth), line["seq"]
        # the top level is the strongest contact, and the first listed
        assert line["contact_id"] == line["contacts"][0]["contact_id"]
        assert line["force_n"] == line["contacts"][0]["force_n"]
        for c in line["contacts"]:
            true = min(truth, key=lambda t: math.dist((t.x0, t.y0), (c["x_mm"], c["y_mm"])))
            assert math.dist((true.x0, true.y0), (c["x_mm"], c["y_mm"])) < 0.5
            (held_ids if true.force > 1.0 else second_ids).add(c["contact_id"])
        if len(truth) == 2:
            assert all(c["reasons"]["contacts"].startswith("one of 2 contacts") for c in line["contacts"])
    # the held contact keeps one id through the second's press and lift; the second has its own
    assert len(held_ids) == 1 and len(second_ids) == 1 and held_ids != second_ids
    # each contact has its own filter: the frames of two contacts are measured without a fit
    # of their own (the pair's first frame and the refits its own change asks for aside), the
    # held contact's filter goes on through the second's press and lift, and its velocity is
    # the scene's (0.01 mm a frame along x)
    pair = [line for line, truth in zip(lines, scene) if len(truth) == 2]
    assert sum(line["gate"] == "fit" for line in pair) <= 3
    last = {c["contact_id"]: c for c in pair[-1]["contacts"]}
    assert last[next(iter(held_ids))]["frames_used"] >= 45
    assert last[next(iter(second_ids))]["frames_used"] >= 25
    speed = 0.01 / (PERIOD_US * 1e-6)
    held = next(iter(held_ids))
    for line in pair[10:]:
        c = next(c for c in line["contacts"] if c["contact_id"] == held)
        assert abs(c["vx_mm_s"] - speed) < 4 * c["std"]["vx_mm_s"] + 0.1 * speed, line["seq"]
    after = lines[SETTLE_FRAMES + 50]  # the first frame after the second lifted
    assert after["contacts"][0]["frames_used"] >= 50


def test_two_held_contacts_average_down_each_within_its_sigma(tmp_path: Path, capsys) -> None:
    """Two contacts held still: each one's filter averages its frames (measured on the frame
    less the other's strain), so its sigmas shrink as frames accumulate, and its values stay
    within them of the truth."""
    model = StrainModel()
    rng = np.random.default_rng(11)
    truth = [Contact(5.0, 5.0, 0.0, 1.2, 7.0, 11.0), Contact(8.0, 8.0, 0.0, 0.6, 18.0, 16.0)]
    pair = sum((model.predict(c) for c in truth), np.zeros((8, 8)))
    scene = [None] * SETTLE_FRAMES + [pair] * 80
    strain = [(np.zeros((8, 8)) if s is None else s) + rng.normal(0.0, SIGMA, (8, 8)) for s in scene]
    counts = LookupTable.linear().to_counts(np.array(strain))
    frames = [Frame(seq=k, device_time_us=k * PERIOD_US, raw=c, sensor_id=0) for k, c in enumerate(counts)]
    rec = write_recording(tmp_path / "held.tact", frames)
    assert cli(["replay", str(rec), "--mode", "lossless", "--speed", "0", "--no-timing",
                "--model", "sphere"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()][SETTLE_FRAMES:]
    assert sum(line["gate"] == "fit" for line in lines) <= 3
    first_sd: dict[int, float] = {}
    checked = 0
    for line in lines:
        assert len(line["contacts"]) == 2, line["seq"]
        for c in line["contacts"]:
            true = min(truth, key=lambda t: math.dist((t.x0, t.y0), (c["x_mm"], c["y_mm"])))
            first_sd.setdefault(c["contact_id"], c["std"]["force_n"])
            if c["frames_used"] >= 10:
                sd = c["std"]
                assert abs(c["force_n"] - true.force) < 4 * sd["force_n"], (line["seq"], c)
                assert abs(c["x_mm"] - true.x0) < 4 * sd["x_mm"], (line["seq"], c)
                assert abs(c["y_mm"] - true.y0) < 4 * sd["y_mm"], (line["seq"], c)
                checked += 1
    assert checked >= 2 * 60
    last = {c["contact_id"]: c for c in lines[-1]["contacts"]}
    assert set(last) == set(first_sd)
    for cid, c in last.items():
        assert c["frames_used"] >= 70
        # 80 frames averaged: the force's sigma well under a single frame's
        assert c["std"]["force_n"] < 0.5 * first_sd[cid], (cid, c["std"], first_sd[cid])

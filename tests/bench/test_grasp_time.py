"""``python -m tactiled_bench.grasp_time``: the contacts bench's grasp frames, their fit time per
grasp over rounds in fresh processes, and the published results compared between two codes."""

from __future__ import annotations

import numpy as np

from tactiled_bench import grasp_time, grasps
from tactiled_bench.checkout import ROOT


def test_the_frames_are_the_contacts_suites_grasps_drawn_again_alike() -> None:
    labels, frames = grasp_time.grasp_frames("flat16", seed=2, frames=2)
    again_labels, again = grasp_time.grasp_frames("flat16", seed=2, frames=2)
    assert labels == again_labels and np.array_equal(frames, again)
    assert set(labels) == {*grasps.FLAT_GRASPS, "single"}
    assert frames.shape[1:] == (16, 16) and len(labels) == frames.shape[0] >= 10
    other = grasp_time.grasp_frames("flat16", seed=3, frames=2)[1]
    assert not np.array_equal(frames[:1], other[:1])  # another seed draws other grasps


def test_differences_name_what_moved_beyond_the_tolerance() -> None:
    a = [{"model": "sphere", "values": {"force_n": 1.0, "r1_mm": None}, "fit_ms": 3.0}]
    same = [{"model": "sphere", "values": {"force_n": 1.0 + 1e-9, "r1_mm": None}, "fit_ms": 9.0}]
    assert grasp_time.differences(a, same) == []
    moved = [{"model": "sphere", "values": {"force_n": 1.0 + 1e-5, "r1_mm": None}, "fit_ms": 3.0}]
    assert grasp_time.differences(a, moved) == ["[0]/values/force_n: 1.0 against 1.00001"]
    other = [{"model": "general", "values": {"force_n": 1.0, "r1_mm": 2.0}}]
    assert grasp_time.differences(a, other) == ["[0]/model: 'sphere' against 'general'",
                                                "[0]/values/r1_mm: None against 2.0"]
    assert grasp_time.differences(a, a + a) == [": 1 against 2 items"]


def test_a_run_against_the_same_code_times_every_grasp_and_finds_the_same_results() -> None:
    out = grasp_time.run(["flat16"], seed=1, frames=1, rounds=1, baseline="HEAD", baseline_tree=str(ROOT))
    assert "round 1: this, load average" in out and "round 2: HEAD, load average" in out
    rows = [line for line in out.splitlines() if line.startswith("| flat16 |")]
    assert {r.split(" | ")[1] for r in rows} == {*grasps.FLAT_GRASPS, "single"}
    assert "published results: 5 of 5 frames the same" in out

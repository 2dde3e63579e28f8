"""Contact ids from frame to frame (tactiled.pipeline.association)."""

from __future__ import annotations

import pytest

from tactiled.pipeline.association import ContactIds, identified


def c(x: float | None, y: float | None, r: float | None = 5.0, r_sd: float = 0.1) -> dict:
    return {"contact": True, "x_mm": x, "y_mm": y, "r1_mm": r, "std": {"r1_mm": r_sd}}


def test_a_held_contact_keeps_its_id_as_it_moves() -> None:
    ids = ContactIds(gate_mm=2.0)
    got = [ids.assign([c(5.0 + 0.5 * k, 5.0)])[0] for k in range(20)]
    assert got == [1] * 20


def test_contacts_appear_and_end_with_new_ids_never_reused() -> None:
    ids = ContactIds(gate_mm=2.0)
    assert ids.assign([c(5, 5)]) == [1]
    assert ids.assign([c(5, 5), c(15, 5)]) == [1, 2]
    assert ids.assign([c(15.2, 5)]) == [2]  # the first lifted
    assert ids.assign([c(5, 5), c(15.3, 5)]) == [3, 2]  # the first pressed again: a new contact
    ids.clear()
    assert ids.assign([c(5, 5)]) == [4]
    assert ids.started == 4


def test_a_jump_beyond_the_gate_or_another_shape_is_another_contact() -> None:
    ids = ContactIds(gate_mm=2.0)
    assert ids.assign([c(5, 5)]) == [1]
    assert ids.assign([c(8, 5)]) == [2]
    assert ids.assign([c(8, 5, r=50.0, r_sd=1.0)]) == [3]  # 10x the radius, both well measured
    # a radius measured no better than 25 % says nothing of the shape
    assert ids.assign([c(8, 5, r=2.0, r_sd=1.0)]) == [3]


def test_merge_and_split_end_the_old_ids() -> None:
    ids = ContactIds(gate_mm=2.0)
    assert ids.assign([c(5, 5), c(7, 5)]) == [1, 2]
    assert ids.assign([c(6, 5)]) == [3] and ids.merges == 1  # both within the gate of one
    assert ids.assign([c(5, 5), c(7, 5)]) == [4, 5] and ids.splits == 1


def test_a_withheld_place_keeps_the_single_contact() -> None:
    ids = ContactIds(gate_mm=2.0)
    assert ids.assign([c(5, 5)]) == [1]
    assert ids.assign([c(None, 5)]) == [1]
    assert ids.assign([c(5.5, None)]) == [1]
    assert ids.assign([c(5.6, 5)]) == [1]


def test_identified_lists_every_contact_with_its_id() -> None:
    ids = ContactIds(gate_mm=2.0)
    none = identified({"contact": False, "x_mm": None}, ids)
    assert none["contact_id"] is None and none["contacts"] == []
    one = identified({**c(5, 5), "peak": 0.1}, ids)
    assert one["contact_id"] == 1 and one["contacts"] == [{**c(5, 5), "peak": 0.1, "contact_id": 1}]
    # an estimate reused: its listed contact is rebuilt from the top level
    again = identified({**one, "peak": 0.2}, ids)
    assert again["contacts"][0]["peak"] == 0.2 and again["contacts"][0]["contact_id"] == 1
    two = identified({**c(5, 5), "contacts": [c(5, 5), c(15, 5)]}, ids, lambda d: {**d, "seen": 1})
    assert two["contact_id"] == 1 and [x["contact_id"] for x in two["contacts"]] == [1, 2]
    assert all(x["seen"] == 1 for x in two["contacts"])


def test_a_gate_must_be_a_distance() -> None:
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="gate_mm"):
            ContactIds(bad)


@pytest.mark.parametrize("several", [False, True])
def test_identified_in_place_equals_identified_by_copy(several: bool) -> None:
    """``fresh=True`` (a tracker's estimate, completed in place) gives the very dict the
    copying path gives, frame after frame, and the ids move alike."""
    import copy

    def fit(k: int) -> dict:
        one = {"contact": True, "x_mm": 3.0 + 0.1 * k, "y_mm": 4.0, "r1_mm": 5.0,
               "std": {"r1_mm": 0.1}, "frames_used": 3}
        if not several:
            return {**one, "contacts": [dict(one)]} if k % 2 else one
        other = {**one, "x_mm": 12.0 - 0.1 * k}
        return {**one, "contacts": [one, other]}

    by_copy, in_place = ContactIds(gate_mm=3.8), ContactIds(gate_mm=3.8)
    for k in range(5):
        original = fit(k)
        want = identified(copy.deepcopy(original), by_copy)
        got = identified(copy.deepcopy(original), in_place, fresh=True)
        assert got == want
        assert got["contacts"][0]["contact_id"] == want["contact_id"]

"""Which contact is which from one frame to the next: stable ``contact_id`` numbers."""

# Each contact of a frame is matched to a contact of the previous estimate by place (within
# ``gate_mm``) and shape (radii within a factor ``SHAPE_FACTOR`` when both are well measured).  A
# contact keeps its id while exactly one contact of the next frame matches it and matches
# nothing else; anything else is a new contact with a new id:
#
# * a **merge** (two held contacts match one new one) ends both ids and starts one;
# * a **split** (one held contact matches two new ones) ends its id and starts two;
# * a contact that appears, or one that no held contact is near, starts a new id; one that
#   is not seen again ends.
#
# Ids count up from 1 per sensor and are never reused while the daemon runs.  No I/O, no physics:
# the main process runs this on every estimate, a few microseconds for a few contacts.

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

#: Two radii further apart than this factor are two different objects ...
SHAPE_FACTOR = 4.0
#: ... when both are measured to within this share (a radius near the limit of what the array
#: resolves, an edge's, wanders by more than that from frame to frame).
SHAPE_RELATIVE_SIGMA = 0.25


def _radius(c: dict[str, Any]) -> float | None:
    """A contact's r1 (mm) when it is well measured, else None."""
    r, sd = c.get("r1_mm"), (c.get("std") or {}).get("r1_mm")
    return r if r and sd is not None and sd <= SHAPE_RELATIVE_SIGMA * r else None


class ContactIds:
    """The ids of one sensor's held contacts."""

    def __init__(self, gate_mm: float) -> None:
        if not (gate_mm > 0.0 and math.isfinite(gate_mm)):
            raise ValueError(f"gate_mm must be a positive distance in mm, got {gate_mm!r}")
        self.gate_mm = gate_mm
        self._next = 1
        #: the last frame's contacts: (id, x_mm, y_mm, r1_mm), any of the three may be None
        self._held: list[tuple[int, float | None, float | None, float | None]] = []
        self.started = 0  # ids handed out
        self.merges = 0
        self.splits = 0

    def clear(self) -> None:
        """Nothing is touched: every held id ends."""
        self._held = []

    def _new(self) -> int:
        i = self._next
        self._next += 1
        self.started += 1
        return i

    def _near(self, held: tuple[int, float | None, float | None, float | None],
              c: tuple[float | None, float | None, float | None]) -> bool:
        """Whether a held contact and a contact placed at ``c`` (``x_mm, y_mm`` and its well
        measured radius, any of them None) can be the same."""
        _, hx, hy, hr = held
        x, y, r = c
        if hx is None or hy is None or x is None or y is None:
            return False
        if math.hypot(x - hx, y - hy) > self.gate_mm:
            return False
        return hr is None or r is None or (hr / SHAPE_FACTOR <= r <= hr * SHAPE_FACTOR)

    def assign(self, contacts: list[dict[str, Any]]) -> list[int]:
        """The id of each of this frame's ``contacts`` (dicts with ``x_mm``, ``y_mm`` and
        ``r1_mm``, any of them None), in order; they become the held contacts."""
        held = self._held
        places = [(c.get("x_mm"), c.get("y_mm"), _radius(c)) for c in contacts]
        if len(held) == 1 and len(places) == 1:  # the common case: one contact, held
            c = places[0]
            unplaced = None in (held[0][1], held[0][2], c[0], c[1])
            # a withheld place says nothing against it being the same contact
            ids = [held[0][0] if unplaced or self._near(held[0], c) else self._new()]
        else:
            near = [[k for k, h in enumerate(held) if self._near(h, c)] for c in places]
            claims = [sum(k in n for n in near) for k in range(len(held))]
            ids = []
            for n in near:
                if len(n) == 1 and claims[n[0]] == 1:
                    ids.append(held[n[0]][0])
                else:
                    self.merges += len(n) > 1
                    ids.append(self._new())
            self.splits += sum(1 for c in claims if c > 1)
        self._held = [(i, *c) for i, c in zip(ids, places)]
        return ids


def identified(fit: dict[str, Any], ids: ContactIds,
               element: Callable[[dict[str, Any]], dict[str, Any]] | None = None,
               fresh: bool = False) -> dict[str, Any]:
    """An estimate's (or a ``tactiled fit`` line's) dict with its contacts' ids:
    ``contact_id``, the top-level contact's (the strongest), and ``contacts``, every contact's
    keys and id, the strongest first (``[]``: no contact).  A fit of one contact lists it; a
    fit of several already lists them (the worker's), each passed through ``element``.
    ``fresh``: ``fit`` and its contacts are the caller's own, made for this estimate (a
    tracker's): they are completed in place rather than copied."""
    if not fit.get("contact"):
        ids.clear()
        return fit if "contacts" in fit else {**fit, "contact_id": None, "contacts": []}
    several = fit.get("contacts")
    if several is None or len(several) == 1:  # one contact: the top level is all of it
        if fresh:
            one = fit
            one.pop("contacts", None)
        else:  # one copy, ours to complete
            one = dict(fit) if several is None else {k: v for k, v in fit.items()
                                                     if k != "contacts"}
        (cid,) = ids.assign((one,))
        one["contact_id"] = cid
        return {**one, "contacts": [one]}
    numbers = ids.assign(several)
    if fresh:
        for n, i in enumerate(numbers):
            c = several[n] if element is None else element(several[n])
            c["contact_id"] = i
            several[n] = c
        fit["contact_id"] = numbers[0]
        return fit
    listed = [{**(c if element is None else element(c)), "contact_id": i}
              for c, i in zip(several, numbers)]
    return {**fit, "contact_id": numbers[0], "contacts": listed}

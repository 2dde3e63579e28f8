"""Several contacts of one array tracked at once: a temporal filter per contact."""

# A frame of several contacts is fitted as such (:func:`tactiled.fit.multi.fit_contacts`), and
# the worker linearises each contact on the frame less the others' predicted strain
# (:func:`tactiled.fit.multi.linearize_several`).  From then on each later frame is measured
# without a fit: contact ``i``'s :class:`~tactiled.pipeline.contact_filter.Tracker` reads the frame
# less the strain the others have *now* (their linearisation's whole-array strain, moved to
# their current state through their Jacobian over their own window), so a neighbour's motion
# does not leak into it.  A frame any contact cannot measure (outside its linear range, a
# jump) goes to a fit of the whole frame, before any filter has moved: the contacts stay in
# step.  The strain is linear in the pressure, so this is the joint model's measurement to
# first order wherever the contacts' windows do not overlap, and close to it where they do
# (the core of a neighbour is out of each window).
#
# :class:`ContactTrackers` holds the filters and answers the pipeline as one
# :class:`~tactiled.pipeline.contact_filter.Tracker` does (``adopt``, ``step``, ``estimate``, ...):
# with one contact it *is* that tracker, call for call, so a one-contact stream's estimates
# are unchanged.  Contacts keep their filters across fits by place (the nearest filter within
# ``gate_mm``); a new contact starts a filter, a contact gone ends its own.  No I/O and no
# physics: the main process runs it per frame.

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from tactiled.fit.warm import SEVERAL
from tactiled.pipeline.contact_filter import Tracker


def _centre(tr: Tracker) -> tuple[float, float] | None:
    """A filter's contact centre (internal x0, y0, mm): its state, else its point."""
    if tr.x is not None:
        return tr.x[-2], tr.x[-1]
    if tr.lin is not None:
        return float(tr.lin.p[-2]), float(tr.lin.p[-1])
    return None


def _force(est: dict[str, Any]) -> tuple[float, float]:
    f = est.get("force_n")
    return (-1.0 if f is None else float(f), float(est.get("peak") or 0.0))


class ContactTrackers:
    """The temporal filters of one array's contacts (see the module's doc).

    ``make`` builds one contact's :class:`Tracker`; ``gate_mm``: how far a contact may be
    from a filter's last place and still be that filter's contact (the cover's depth, as
    :class:`~tactiled.pipeline.association.ContactIds` gates ids).
    """

    def __init__(self, make: Callable[[], Tracker], gate_mm: float) -> None:
        self._make = make
        self.gate_mm = float(gate_mm)
        self.trackers: list[Tracker] = [make()]
        #: each filter's fit dict (an element of the fit's ``contacts``), with several
        self.bases: list[dict[str, Any]] = []
        self._ended_resets = 0
        self._ended_skipped = 0
        #: per contact, the others' strain on its window (``_cross_terms``)
        self._cross: list[tuple[np.ndarray, list[tuple[int, np.ndarray, np.ndarray]]]] = []

    # -- what the pipeline reads ---------------------------------------------------------------

    @property
    def lin(self) -> Any:
        """The linearisation frames are measured through (one contact's; with several, a
        tuple of each one's)."""
        if not self.several:
            return self.trackers[0].lin
        return tuple(tr.lin for tr in self.trackers)

    @property
    def several(self) -> bool:
        return len(self.trackers) > 1

    @property
    def active(self) -> bool:
        return all(tr.active for tr in self.trackers)

    @property
    def started(self) -> bool:
        return all(tr.started for tr in self.trackers)

    @property
    def model(self) -> str | None:
        return SEVERAL if self.several else self.trackers[0].model

    @property
    def t(self) -> float | None:
        ts = [tr.t for tr in self.trackers]
        return None if None in ts else min(ts)  # type: ignore[type-var]

    @property
    def resets(self) -> int:
        return self._ended_resets + sum(tr.resets for tr in self.trackers)

    @property
    def skipped(self) -> int:
        return self._ended_skipped + sum(tr.skipped for tr in self.trackers)

    # -- state ---------------------------------------------------------------------------------

    def clear(self) -> None:
        """Forget every contact (they ended, a tare, new settings)."""
        self._keep([self.trackers[0]])
        self.trackers[0].clear()
        self.bases = []

    def _keep(self, kept: list[Tracker]) -> None:
        for tr in self.trackers:
            if not any(tr is k for k in kept):
                self._ended_resets += tr.resets
                self._ended_skipped += tr.skipped
        self.trackers = kept

    def adopt(self, lin: Any, zero_var: float = 0.0, base: dict[str, Any] | None = None) -> bool:
        """Measure the following frames through ``lin``: one contact's
        :class:`~tactiled.fit.linearize.Linearization`, or several's
        (:class:`~tactiled.fit.linearize.SeveralLinearizations`) with ``base`` the fit they
        come from (its ``contacts`` in the same order), or without it a relinearisation asked
        for by :meth:`wants_linearization` (in the filters' order).  False when it does not
        fit the contacts held (a relinearisation of contacts that have changed since)."""
        if lin.model != SEVERAL:
            if self.several:  # one contact left: the filter nearest it goes on
                self._keep([self._nearest([(float(lin.p[-2]), float(lin.p[-1]))])[0]
                            or self.trackers[0]])
                self.bases = []
            self.trackers[0].adopt(lin, zero_var, base)
            return True
        lins = lin.lins
        if base is None:
            if len(lins) != len(self.trackers) or not self.several:
                return False
            for tr, one in zip(self.trackers, lins):
                tr.adopt(one, zero_var)
            self._cross_terms()
            return True
        elements = base.get("contacts") or []
        if len(elements) != len(lins):
            raise ValueError(f"{len(lins)} linearisations for {len(elements)} contacts")
        matched = self._nearest([(float(one.p[-2]), float(one.p[-1])) for one in lins])
        kept = [tr if tr is not None else self._make() for tr in matched]
        self._keep(kept)
        self.bases = [dict(e) for e in elements]
        for tr, one, b in zip(kept, lins, self.bases):
            tr.adopt(one, zero_var, b)
        self._cross_terms()
        return True

    def _nearest(self, centres: list[tuple[float, float]]) -> list[Tracker | None]:
        """For each centre, a distinct held filter within ``gate_mm`` (the closest pairs
        first), or None: a new contact."""
        pairs = []
        for i, (x, y) in enumerate(centres):
            for k, tr in enumerate(self.trackers):
                c = _centre(tr)
                if c is not None:
                    d = math.hypot(c[0] - x, c[1] - y)
                    if d <= self.gate_mm:
                        pairs.append((d, i, k))
        out: list[Tracker | None] = [None] * len(centres)
        taken: set[int] = set()
        for _, i, k in sorted(pairs):
            if out[i] is None and k not in taken:
                out[i] = self.trackers[k]
                taken.add(k)
        return out

    def wants_linearization(self) -> tuple[str, Any] | None:
        """Where to linearise again (:meth:`Tracker.wants_linearization`); with several
        contacts, every one's state as ``(SEVERAL, ((model, params), ...))`` once one has
        moved from its point (each is linearised on the frame less the others)."""
        if not self.several:
            return self.trackers[0].wants_linearization()
        if any(tr.wants_linearization() is not None for tr in self.trackers):
            return SEVERAL, tuple((tr.model, tuple(map(float, tr.x))) for tr in self.trackers)
        return None

    def predicted(self, t: float) -> tuple[str, Any] | None:
        """The contacts predicted at ``t``: a fit's warm start (several's tagged SEVERAL)."""
        if not self.several:
            return self.trackers[0].predicted(t)
        each = tuple(p for p in (tr.predicted(t) for tr in self.trackers) if p is not None)
        return (SEVERAL, each) if each else None

    # -- a frame -------------------------------------------------------------------------------

    def step(self, strain: np.ndarray, t: float, fitted: bool = False) -> str:
        """:meth:`Tracker.step` for every contact, each on the frame less the others' strain:
        ``"refit"`` (before any filter moved) when one cannot measure it, ``"reset"`` when
        one restarted, else ``"tracked"``."""
        if not self.several:
            return self.trackers[0].step(strain, t, fitted)
        if fitted:
            out = [tr.step(strain, t, fitted=True) for tr in self.trackers]
        else:
            frame = np.ascontiguousarray(strain, dtype=np.float64)
            for tr, at in zip(self.trackers, self._windows(frame)):
                if not tr.measure_at(frame, at):
                    return "refit"
            # (a jump one filter sees after another has moved is rare: that frame's fit then
            # restarts the filters that moved)
            out = [tr.step(frame, t, measured=True) for tr in self.trackers]
        return "refit" if "refit" in out else "reset" if "reset" in out else "tracked"

    def _windows(self, strain: np.ndarray) -> list[np.ndarray]:
        """What each contact's filter measures, as :meth:`Tracker.measure_at` takes it
        (``strain[index] - at``, ``at`` returned): its window of the frame less its linearisation's strains
        and the others' strain there now: at their points, and where their own windows
        overlap it, moved to their filters' states through their Jacobians (outside its own
        window a contact's strain is taken at its point: it is relinearised as it moves)."""
        out = []
        for tr, (at, overlaps) in zip(self.trackers, self._cross):
            if not overlaps:
                out.append(at)
                continue
            own = at.copy()
            for j, mine, theirs in overlaps:
                o = self.trackers[j]
                if o.x is not None:
                    own[mine] += o.lin.jacobian[theirs] @ (np.asarray(o.x) - o.lin.p)
            out.append(own)
        return out

    def _cross_terms(self) -> None:
        """Per contact, what ``_windows`` subtracts: its linearisation's strains plus the
        others' strain at their points on its window, and where another's window overlaps
        it, ``(j, positions in its window, rows of j's window)``."""
        self._cross = []
        # each window as a map from tactel to its row there (-1: not in it)
        size = max(tr.lin.predicted.size for tr in self.trackers)
        rows = []
        for tr in self.trackers:
            row = np.full(size, -1, dtype=np.intp)
            row[tr.lin.index] = np.arange(tr.lin.index.size)
            rows.append(row)
        for i, tr in enumerate(self.trackers):
            idx = tr.lin.index
            at = tr._at.copy()
            overlaps = []
            for j, o in enumerate(self.trackers):
                if j == i:
                    continue
                at += o.lin.predicted.ravel()[idx]
                theirs = rows[j][idx]
                mine = np.flatnonzero(theirs >= 0)
                if mine.size:
                    overlaps.append((j, mine, theirs[mine]))
            self._cross.append((at, overlaps))

    def skip(self) -> None:
        for tr in self.trackers:
            tr.skip()

    # -- the estimate --------------------------------------------------------------------------

    def estimate(self, base: dict[str, Any], at: float | None = None) -> dict[str, Any]:
        """:meth:`Tracker.estimate`; with several contacts, each one's from its own fit dict,
        the strongest at the top level and every one in ``contacts``, the strongest first."""
        if not self.several:
            return self.trackers[0].estimate(base, at)
        return _strongest_first([tr.estimate(b, at) for tr, b in zip(self.trackers, self.bases)])

    def estimate_from(self, base: dict[str, Any], numbers: list[tuple]) -> dict[str, Any]:
        """:meth:`estimate` from the tracked run's numbers, one tuple per contact
        (:meth:`Tracker.estimate_from`'s arguments after ``base``)."""
        if not self.several:
            return self.trackers[0].estimate_from(base, *numbers[0])
        return _strongest_first([tr.estimate_from(b, *nums)
                                 for tr, b, nums in zip(self.trackers, self.bases, numbers)])

    def overlapping(self) -> bool:
        """Whether a contact's window overlaps another's (their strain there then moves with
        the other's state, frame by frame: ``_windows``)."""
        return any(overlaps for _, overlaps in self._cross)

    def measured_at(self) -> list[np.ndarray]:
        """What each contact's window is measured less, when no window overlaps another."""
        if not self.several:
            return [self.trackers[0]._at]
        return [at for at, _ in self._cross]


def _strongest_first(each: list[dict[str, Any]]) -> dict[str, Any]:
    """Several contacts' estimates as one: the strongest at the top level, all in
    ``contacts``, the strongest first."""
    each.sort(key=_force, reverse=True)
    return {**each[0], "contacts": each}

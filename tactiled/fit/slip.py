"""Slip events from a sequence of 3-axis estimates (docs/concepts/shear.md, "Slip").

A contact slides when the stick zone is gone and the object moves over the skin.  Frame by
frame the fit gives ``lam = Q / (mu P)`` (the stick zone's radius is ``a (1 - lam)^(1/3)``) and
the contact's centre with their bounds.  The detector keeps the centre's *stick anchor*, the
mean of the centre over a past window of frames, and tests the residual of the stick
hypothesis: the centre's displacement from the anchor along the tangential force, in units of
its own sigma.  A slip onset is declared on the first frame where the stick zone has shrunk to nothing within
the bound, ``lam + 2 sigma >= 1``, and either

* the centre has moved along ``Q`` (resolved: over :data:`MIN_Q_SIGMAS` sigma) by more than
  :data:`ONSET_Z` sigma, and on the frame before
  by more than :data:`CONFIRM_Z` sigma (a moving object, not one noisy frame), or
* the tangential force has fallen by more than :data:`DROP_Z` sigma below its mean over the
  :data:`RECENT` frames before (static friction giving way to the weaker kinetic friction).

No threshold on raw readings enters: both tests are in units of the fit's own bounds.  The
slip ends when the stick zone is resolved again (``lam + 2 sigma < 1``) for :data:`END_FRAMES`
frames.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

ONSET_Z = 4.0
CONFIRM_Z = 2.0
#: The anchor averages the centre over frames ``[i - LAG - WINDOW, i - LAG)``.
WINDOW, LAG = 20, 4
END_FRAMES = 3
DROP_Z = 5.0
#: The motion test needs a tangential force this many of its sigma (its direction).
MIN_Q_SIGMAS = 3.0
RECENT = 3


@dataclass
class SlipEvent:
    """``kind`` is ``onset`` or ``end``; ``frame`` the frame it was declared on."""

    kind: str
    frame: int


class SlipDetector:
    """Feed one estimate per frame (:meth:`update`); it returns the slip state and any event."""

    def __init__(self) -> None:
        self._past: deque[tuple[float, float, float, float]] = deque(maxlen=WINDOW + LAG)
        self.sliding = False
        self._z_prev = 0.0
        self._calm = 0
        self._q: deque[tuple[float, float]] = deque(maxlen=RECENT)

    def _anchor(self) -> tuple[float, float, float, float] | None:
        old = list(self._past)[:WINDOW]
        if len(old) < WINDOW:
            return None
        n = len(old)
        x = sum(p[0] for p in old) / n
        y = sum(p[1] for p in old) / n
        sx = math.sqrt(sum(p[2] ** 2 for p in old)) / n
        sy = math.sqrt(sum(p[3] ** 2 for p in old)) / n
        return x, y, sx, sy

    def update(self, frame: int, x: float, y: float, sx: float, sy: float, fx: float, fy: float,
               lam: float, s_lam: float, s_q: float = math.inf) -> tuple[str | None, SlipEvent | None]:
        """The state after this frame (``slip`` while sliding, else ``None``: the frame's own
        state stands) and the event declared on it, if any.  Units: mm, N; ``s_q`` is the
        bound of ``|Q|`` (inf: no force-drop test)."""
        event = None
        anchor = self._anchor()
        q = math.hypot(fx, fy)
        z = 0.0
        if anchor is not None and q > MIN_Q_SIGMAS * s_q:  # slip runs along a resolved Q
            ax, ay, asx, asy = anchor
            ux, uy = fx / q, fy / q
            d = (x - ax) * ux + (y - ay) * uy
            s = math.sqrt((sx * ux) ** 2 + (sy * uy) ** 2 + (asx * ux) ** 2 + (asy * uy) ** 2)
            z = d / s if s > 0 else 0.0
        gone = math.isfinite(s_lam) and lam + 2.0 * s_lam >= 1.0
        drop = 0.0
        if len(self._q) == RECENT and math.isfinite(s_q):
            ref = sum(v for v, _ in self._q) / RECENT
            s_ref = math.sqrt(sum(s * s for _, s in self._q)) / RECENT
            drop = (ref - q) / math.sqrt(s_q * s_q + s_ref * s_ref)
        self._q.append((q, s_q))
        if not self.sliding:
            if gone and ((z > ONSET_Z and self._z_prev > CONFIRM_Z) or drop > DROP_Z):
                self.sliding = True
                self._calm = 0
                event = SlipEvent("onset", frame)
            else:
                self._past.append((x, y, sx, sy))
        else:
            self._calm = 0 if gone else self._calm + 1
            if self._calm >= END_FRAMES:
                self.sliding = False
                self._past.clear()
                event = SlipEvent("end", frame)
        self._z_prev = z
        return ("slip" if self.sliding else None), event

    def feed(self, frame: int, est) -> tuple[str | None, SlipEvent | None]:
        """:meth:`update` from a :class:`~tactiled.fit.shear.ShearEstimate`."""
        p, s = est.params, est.sigma
        _, s_q = est.tangential()
        return self.update(frame, p[2], p[3], s[2], s[3], p[4], p[5], p[7], s[7], s_q)

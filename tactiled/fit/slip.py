"""Slip events from a sequence of 3-axis estimates (docs/concepts/shear.md, "Slip")."""

# A contact slides when the stick zone is gone and the object moves over the skin.  Frame by
# frame an estimate gives ``lam = Q / (mu P)`` (the stick zone's radius is ``a (1 - lam)^(1/3)``),
# the tangential force ``Q`` and the contact's centre, with their bounds.  The detector keeps the
# centre's *stick anchor*, the mean of the centre over :data:`WINDOW` frames ending :data:`LAG`
# frames ago, and tests the residuals of the stick hypothesis (the centre stays at its anchor)
# against a slide starting from rest on one of the last :data:`LAG` + 1 frames, ``t0``: the
# centre's displacement from the anchor along ``Q`` growing as ``(t - t0 + 1)^2`` (a constant
# net force on the object).  The test is the generalised likelihood ratio of that template, in
# units of its own sigma (the frames' bounds and the anchor's, which every frame shares),
# maximised over ``t0``: the evidence of several frames adds up, so a slide is seen a few frames
# after it starts even where one frame's motion is within the noise.
#
# A slip onset is declared on the first frame where the stick zone has shrunk to nothing within
# the bound, ``lam + 2 sigma >= 1``, and either
#
# * the motion test exceeds :data:`ONSET_Z` (with ``Q`` resolved: over :data:`MIN_Q_SIGMAS`
#   sigma, so that its direction is known), or
# * the tangential force has fallen by more than :data:`DROP_Z` sigma below its mean over the
#   :data:`RECENT` frames before (static friction giving way to the weaker kinetic friction).
#
# No threshold on raw readings enters: both tests are in units of the estimates' own bounds.
# The slip ends when the object sticks again: the stick zone resolved (``lam + 2 sigma < 1``)
# and the centre at rest (moved by less than :data:`REST_Z` sigma over the last
# :data:`REST_FRAMES` frames) on :data:`END_FRAMES` frames in a row.  A sliding contact's
# estimate may show a stick zone on a frame or two (the fit of a contact that moves fast);
# the centre's motion does not stop there.

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

ONSET_Z = 4.5
#: The anchor averages the centre over frames ``[i - LAG - WINDOW, i - LAG)``; a slide may
#: start on any of the frames ``i - LAG .. i``.
WINDOW, LAG = 30, 8
END_FRAMES = 3
#: At rest: moved by less than this many sigma over this many frames.
REST_Z, REST_FRAMES = 3.0, 10
DROP_Z = 5.0
#: The motion test needs a tangential force this many of its sigma (its direction).
MIN_Q_SIGMAS = 3.0
RECENT = 3


def motion_z(recent: list[tuple[float, float]], anchor_sigma: float) -> float:
    """The largest likelihood-ratio statistic (in sigma) of a slide from rest along ``Q``:
    ``recent`` is the last frames' ``(d, sigma_d)``, oldest first (``d`` the centre's
    displacement from the anchor along ``Q``, mm); ``anchor_sigma`` the anchor's sigma along
    ``Q``, shared by every ``d``.  Only slides along ``Q`` count (a fit of positive size)."""
    best = 0.0
    n = len(recent)
    for start in range(n):
        num = var_w = sum_w = 0.0
        for k, (d, s) in enumerate(recent[start:]):
            w = (k + 1) ** 2 / (s * s)
            num += w * d
            var_w += w * w * s * s
            sum_w += w
        var = var_w + (anchor_sigma * sum_w) ** 2
        if var > 0 and num > 0:
            best = max(best, num / math.sqrt(var))
    return best


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
        self._calm = 0
        self._slide: deque[tuple[float, float, float, float]] = deque(maxlen=REST_FRAMES + 1)
        self._q: deque[tuple[float, float]] = deque(maxlen=RECENT)
        #: the last frame's motion statistic and force drop (sigma), for the record
        self.z = 0.0
        self.drop = 0.0

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

    def _at_rest(self) -> bool:
        """The centre moved by less than :data:`REST_Z` sigma over the last frames."""
        if len(self._slide) < self._slide.maxlen:
            return False
        (x0, y0, sx0, sy0), (x1, y1, sx1, sy1) = self._slide[0], self._slide[-1]
        zx = (x1 - x0) / math.hypot(sx0, sx1) if sx0 or sx1 else 0.0
        zy = (y1 - y0) / math.hypot(sy0, sy1) if sy0 or sy1 else 0.0
        return math.hypot(zx, zy) < REST_Z

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
            recent = list(self._past)[WINDOW:] + [(x, y, sx, sy)]
            along = [((px - ax) * ux + (py - ay) * uy, math.hypot(psx * ux, psy * uy))
                     for px, py, psx, psy in recent]
            z = motion_z(along, math.hypot(asx * ux, asy * uy))
        gone = math.isfinite(s_lam) and lam + 2.0 * s_lam >= 1.0
        drop = 0.0
        if len(self._q) == RECENT and math.isfinite(s_q):
            ref = sum(v for v, _ in self._q) / RECENT
            s_ref = math.sqrt(sum(s * s for _, s in self._q)) / RECENT
            drop = (ref - q) / math.sqrt(s_q * s_q + s_ref * s_ref)
        self._q.append((q, s_q))
        self.z, self.drop = z, drop
        if not self.sliding:
            if gone and (z > ONSET_Z or drop > DROP_Z):
                self.sliding = True
                self._calm = 0
                event = SlipEvent("onset", frame)
            else:
                self._past.append((x, y, sx, sy))
        else:
            self._slide.append((x, y, sx, sy))
            self._calm = 0 if gone or not self._at_rest() else self._calm + 1
            if self._calm >= END_FRAMES:
                self.sliding = False
                self._past.clear()
                self._slide.clear()
                event = SlipEvent("end", frame)
        return ("slip" if self.sliding else None), event

    def feed(self, frame: int, est) -> tuple[str | None, SlipEvent | None]:
        """:meth:`update` from a :class:`~tactiled.fit.shear.ShearEstimate`."""
        p, s = est.params, est.sigma
        _, s_q = est.tangential()
        return self.update(frame, p[2], p[3], s[2], s[3], p[4], p[5], p[7], s[7], s_q)

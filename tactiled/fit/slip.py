"""Slip events from a sequence of 3-axis estimates (docs/concepts/shear.md, "Slip")."""

# A contact slides when the stick zone is gone and the object moves over the skin.  Frame by
# frame an estimate gives ``lam = Q / (mu P)`` (the stick zone's radius is ``a (1 - lam)^(1/3)``)
# and the other parameters with their covariance.  The detector runs them through the contact's
# Kalman filter (:class:`tactiled.fit.shear_filter.ShearFilter`: the forces and the size follow a
# constant-velocity model, the centre the stick hypothesis) and tests its innovations for a slide
# along the filtered tangential force starting on one of the last frames
# (:class:`tactiled.fit.shear_filter.SlideTest`: the generalised likelihood ratio, a unit normal
# for each start under stick).
#
# A slip onset is declared on the first frame where the stick zone has shrunk to nothing within
# the bound (``lam + 2 sigma >= 1``, the frame's or the filter's), and either
#
# * the slide test exceeds :data:`ONSET_Z` (with the filtered ``Q`` resolved: over
#   :data:`MIN_Q_SIGMAS` sigma, so that its direction is known; on the tracks of
#   :data:`SLIDE_FRAMES` frames or more), or
# * the friction is mobilised (the filtered ``lam`` above :data:`MOBILISED` by 2 sigma) and, for
#   one start, the tangential force has levelled off by :data:`PLATEAU_Z` sigma while the centre
#   moved by :data:`CONFIRM_Z` sigma, or the slide and the levelling-off together (the
#   likelihood ratio of both scales >= 0) exceed :data:`COMBINE_Z` with the slide alone over
#   :data:`CONFIRM_Z`, both on a start whose frames since show no stick zone (the mean of their
#   unclipped ``lam`` within 2 sigma of 1: a grip held just below the friction's limit levels
#   off too, and its stick zone, resolved by those frames pooled, keeps these rules shut), or
# * the tangential force's mean over the last :data:`DROP_FRAMES` frames has fallen by more
#   than :data:`DROP_Z` sigma below its mean over the :data:`RECENT` frames before (static
#   friction giving way to the weaker kinetic friction), or
# * the margin to slip ``1 - Q/(mu P)``, from the contact's whole history under stick
#   (:class:`Margin`: ``lam`` against ``Q/P`` under stick, a line read off at the present ``Q/P``), is resolved (its sigma
#   at most :data:`MARGIN_SIGMA`) and within one sigma of 0: a pull that stays put at the
#   friction's limit (no motion, no drop) shows its onset only there.
#
# :data:`ONSET_Z` and :data:`DROP_Z` are set from their null distributions on Gaussian
# estimates (``tactiled bench --suite shear``: a few 1e-6 of a held contact's frames beyond 4.5
# for the slide test) against the frames the bench holds without slip (some 3e5 over seeds 1-5
# and four arrays: no false onset there needs some 2e-7 a frame); no threshold on raw readings
# enters.  The slip ends when the object
# sticks again: the frame's stick zone resolved (``lam + 2 sigma < 1``) and the centre at rest
# (moved by less than :data:`REST_Z` sigma over the last :data:`REST_FRAMES` frames) on
# :data:`END_FRAMES` frames in a row; the slide test then starts afresh.  A sliding contact's
# estimate may show a stick zone on a frame or two (the fit of a contact that moves fast); the
# centre's motion does not stop there.

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from tactiled.fit.shear_filter import WINDOW, ShearFilter, SlideTest

#: The slide test alone (no mobilised friction needed): its rate on a held contact's Gaussian
#: estimates is about ``Phi(-ONSET_Z)`` a frame (``tactiled bench --suite shear``'s null tail:
#: a few 1e-6 over 4.5), and the bench's 3e5 stick-only frames (seeds 1-5, four arrays) need
#: some 2e-7 a frame for all rules together before a single false onset becomes unlikely.
ONSET_Z = 5.0
#: Frames of a contact before the slide test counts: the filter's rates settle from their start.
SETTLE = 10
END_FRAMES = 3
#: At rest: moved by less than this many sigma over this many frames.
REST_Z, REST_FRAMES = 3.0, 10
#: The force's drop: the mean of the last :data:`DROP_FRAMES` frames' ``Q`` under the mean of
#: the :data:`RECENT` frames before by this many sigma.  A kinetic drop persists, one frame's
#: noise does not; the threshold keeps the rate on a held contact's Gaussian estimates near
#: 2e-8 a frame (one-sided), which the bench's stick-only frames need (docs/concepts/shear.md,
#: "False onsets").
DROP_Z, DROP_FRAMES = 5.5, 2
#: A slide track counts once it spans this many frames: a slide from rest accelerates, its
#: displacement over one frame is far below a frame's bound, and a track of one frame tests that
#: frame's centre alone (one estimate's outlier, not a motion).
SLIDE_FRAMES = 3
#: The slide test needs a filtered tangential force this many of its sigma (its direction).
MIN_Q_SIGMAS = 3.0
RECENT = 3
#: The detector's filter lets a force's rate walk this much a frame (single-frame sigmas):
#: a longer memory than the reported filter's, which extrapolates a pull's ramp far enough to
#: see the force level off, at the price of bounds some 20-35 % short after a ramp's slope
#: changes (``tactiled bench --suite shear``); the reported values use RATE_WALK.
DETECT_WALK = 0.04
#: While sliding the filter's centre follows the frames (its random walk, single-frame sigmas).
SLIDING_WALK = 3.0
#: The friction is mobilised when the filtered ``lam`` is above this by 2 sigma: then a
#: tangential force levelling off by :data:`PLATEAU_Z` sigma while the centre moves by
#: :data:`CONFIRM_Z` sigma (the same start) is the onset.
MOBILISED = 0.9
PLATEAU_Z, CONFIRM_Z = 3.0, 3.0
#: With the friction mobilised, the slide and the levelling-off together over COMBINE_Z (the
#: slide test's own threshold), on a start since which the stick zone is gone, the slide alone
#: over CONFIRM_Z: the evidence of both halves of a slip added, where the levelling-off alone
#: falls short of PLATEAU_Z (``tactiled bench --suite shear``: no onset on its stick-only
#: scenes nor on contacts held at 0.95 mu P; with the slide alone over 2.5 sigma instead,
#: held contacts whose stick zone the array does not resolve gave onsets).
COMBINE_Z = 4.5
#: The margin rule: the margin to slip ``1 - Q/(mu P)`` from the contact's history
#: (:class:`Margin`) resolved to this many hundredths of ``mu P`` (its 1-sigma) before it may
#: declare an onset; a contact held at 0.95 ``mu P`` then sits 5 of its sigma from the limit.
MARGIN_SIGMA = 0.01
#: Frames of stick the margin needs before it counts (its slope settles, its residuals say
#: whether the model holds).
MARGIN_FRAMES = 20
#: The margin pools the frames whose ``Q/P`` is at least this share of the present one.
NEAR = 0.5
#: The margin's memory: the newest this many frames of the contact (2 s at 1 kHz: a pull's ramp).
HISTORY = 2000
#: The margin's pooled sums are kept per bin of ``Q/P`` this wide (the selection ``Q/P >=
#: NEAR q`` is taken at the bin edge at or above it); ``Q/P`` beyond the last bin joins it.
BIN, BINS = 0.005, 1024
#: The sums kept per bin: frames, ``w``, ``w x``, ``w y``, ``w x^2``, ``w x y``, ``w y^2``,
#: ``w s``, ``w x s`` (``x = Q/P``, ``y`` the unclipped ``lam``, ``w`` its weight, ``s`` its
#: single-frame sigma).
_SUMS = 9
#: A frame's linear ``lam`` near slip may be biased, by the same share of its sigma on a
#: contact's frames (its likelihood is one-sided), which pooling does not reduce: the
#: margin's sigma keeps a floor of this share of the frames' sigma carried through the line
#: (measured by ``python -m tactiled_bench.shear``: the mean error of frames under stick whose
#: true ``lam`` is 0.8 or more is +0.07 to +0.12 of their sigma on the XELA-like patches, the
#: PaXini module and the 16x16 pad, and no contact's beyond that by more than its noise).
BIAS = 0.25


class Margin:
    """The margin to slip ``1 - Q/(mu P)`` from a contact's history under stick.

    Under stick every frame's ``lam`` is ``(Q/P) / mu`` with one ``mu`` for the contact: the
    stick zone shrinks as the friction mobilised grows, ``lam`` a line in ``Q/P``.  The
    frames' ``lam`` (before the clip) against their ``Q/P``, fitted by weighted least squares
    (each residual weighed by its variance from the frame's covariance, the correlation of
    ``lam`` and ``Q`` included), pools the contact's frames, where one frame's ``lam`` is known
    to a few hundredths near slip at best; the margin now is ``1 - lam`` read off the line at
    the present ``Q/P``.  The line has an intercept: a frame's linear ``lam`` near slip is
    biased by a share of its sigma, of one sign on a contact's frames (the likelihood of
    ``lam`` is one-sided), which pooling does not reduce and a line through the origin turns
    into a bias of the margin; the intercept takes it up, at the price of a wider bound at the
    end of the range.  Only the frames whose ``Q/P`` is at least :data:`NEAR` of the present
    one enter (a selection on the regressor leaves the line unbiased), and the bound is widened
    by the residuals' chi-square per degree of freedom where that exceeds 1 (the model or the
    step's linearisation off).  A frame's weight is the previous frame's variance: a frame's
    own bound of ``lam`` shrinks as its noise pushes ``lam`` toward 1, and weights drawn from
    the noise of ``lam`` itself would tilt the fit toward slip.

    The sums are kept per bin of ``Q/P`` (:data:`BIN`) over the newest :data:`HISTORY` frames,
    the oldest frame's share taken out as a new one comes (and the bins summed afresh every
    :data:`HISTORY` frames, so rounding does not accumulate): a frame costs a sum over the bins,
    not over the frames."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._ring = np.zeros((HISTORY, _SUMS))  # each frame's share of the sums, newest frames
        self._bin = np.zeros(HISTORY, dtype=np.int64)
        self._sums = np.zeros((BINS, _SUMS))
        self._n = 0
        self._top = 0  # one past the highest bin used
        self._k = 1.0
        self._last: float | None = None  # the previous frame's variance
        #: frames the last :meth:`margin` used, and the floor of its sigma (:data:`BIAS`)
        self.frames = 0
        self.floor = math.inf

    def add(self, params: np.ndarray, cov: np.ndarray, lam_free: float | None) -> None:
        """One frame's estimate (the shear fit's order; ``lam_free`` its unclipped ``lam``)."""
        lam = float(params[7]) if lam_free is None else float(lam_free)
        fx, fy, force = float(params[4]), float(params[5]), math.exp(float(params[1]))
        q = math.hypot(fx, fy)
        if not (math.isfinite(lam) and q > 0 and np.all(np.isfinite(cov[np.ix_((1, 4, 5, 7), (1, 4, 5, 7))]))):
            return
        k = self._k
        g = np.zeros(8)  # the gradient of lam - k Q/P
        g[7] = 1.0
        g[4], g[5], g[1] = -k * fx / (q * force), -k * fy / (q * force), k * q / force
        var = float(g @ cov @ g)
        if not var > 0:
            return
        var, self._last = (self._last if self._last is not None else var), var
        x, w, s = q / force, 1.0 / var, math.sqrt(max(0.0, float(cov[7, 7])))
        slot = self._n % HISTORY
        if self._n >= HISTORY:
            self._sums[self._bin[slot]] -= self._ring[slot]
        row = self._ring[slot]
        row[:] = (1.0, w, w * x, w * lam, w * x * x, w * x * lam, w * lam * lam, w * s, w * x * s)
        self._bin[slot] = b = min(int(x / BIN), BINS - 1)
        self._sums[b] += row
        self._top = max(self._top, b + 1)
        self._n += 1
        if self._n % HISTORY == 0:  # rounding does not pile up over a long contact
            self._sums[:] = 0.0
            np.add.at(self._sums, self._bin, self._ring)

    def line(self, at: float, lo: float = 0.0) -> tuple[float, float, float, int]:
        """The line ``lam = a + k Q/P`` through the frames whose ``Q/P`` is at least ``lo`` (at
        the bin edge at or above it): ``lam`` on it at ``Q/P = at`` and its 1-sigma (widened by
        the residuals' scatter beyond the bounds), the slope ``k`` and the frames' count."""
        first = min(BINS - 1, max(0, math.ceil(lo / BIN - 1e-9)))
        bins = self._sums[first:max(first, self._top)]
        n, sw, sx, sy, sxx, sxy, syy, _, _ = bins.sum(axis=0)
        n = int(round(n))
        det = sw * sxx - sx * sx
        if n < 3 or not (sw > 0 and det > 1e-12 * sw * sxx):
            self.floor = math.inf
            return math.nan, math.inf, math.nan, n
        k = (sw * sxy - sx * sy) / det
        a = (sy - k * sx) / sw
        chi2 = max(0.0, syy - a * sy - k * sxy)  # the weighted residuals' sum of squares
        var = (sxx - 2.0 * at * sx + at * at * sw) / det
        # lam on the line at ``at`` is sum_i h_i y_i with h_i = w_i (alpha + beta x_i): a bias
        # of BIAS s_i on every frame moves it by at most BIAS sum_i |h_i| s_i (per bin)
        alpha, beta = (sxx - at * sx) / det, (at * sw - sx) / det
        self.floor = BIAS * float(np.abs(alpha * bins[:, 7] + beta * bins[:, 8]).sum())
        return a + k * at, math.sqrt(max(1.0, chi2 / (n - 2)) * max(0.0, var)), k, n

    def margin(self, q_over_p: float, s_qp: float) -> tuple[float, float]:
        """The margin ``1 - Q/(mu P)`` at the friction mobilised ``q_over_p`` (its sigma
        ``s_qp``) and its 1-sigma; :attr:`frames` the frames it pooled."""
        lam, s_lam, k, self.frames = self.line(q_over_p, NEAR * q_over_p)
        if not math.isfinite(lam):
            return math.nan, math.inf
        if k > 0:  # the weights' gradient: lam's change with Q/P
            self._k = k
        return 1.0 - lam, math.hypot(s_lam, k * s_qp, self.floor)


@dataclass
class SlipEvent:
    """``kind`` is ``onset`` or ``end``; ``frame`` the frame it was declared on."""

    kind: str
    frame: int


def _q_sigma(params: np.ndarray, cov: np.ndarray) -> float:
    """The 1-sigma of ``|Q|`` from the estimate's covariance (``fx``, ``fy`` at 4 and 5)."""
    fx, fy = params[4], params[5]
    q = math.hypot(fx, fy)
    c = cov[4:6, 4:6]
    if not np.all(np.isfinite(c)):
        return math.inf
    if q <= 0:
        return float(math.sqrt(max(0.0, c[0, 0])))
    g = np.array((fx / q, fy / q))
    return float(math.sqrt(max(0.0, g @ c @ g)))


class SlipDetector:
    """Feed one estimate per frame (:meth:`update`); it returns the slip state and any event.
    :attr:`filter` is the detector's own shear filter (:data:`DETECT_WALK`), :attr:`tracking`
    the contact's reported one (:data:`tactiled.fit.shear_filter.RATE_WALK`); both let the
    centre follow the frames while the contact slides."""

    def __init__(self) -> None:
        self.filter = ShearFilter(DETECT_WALK)
        self.tracking = ShearFilter()
        self.test = SlideTest(PLATEAU_Z)
        self.sliding = False
        self._calm = 0
        self._slide: deque[tuple[float, float, float, float]] = deque(maxlen=REST_FRAMES + 1)
        self._q: deque[tuple[float, float]] = deque(maxlen=RECENT + DROP_FRAMES - 1)
        #: the unclipped lam and its 1-sigma of the frames the slide test advanced on (newest last)
        self._lam: deque[tuple[float, float]] = deque(maxlen=WINDOW + 1)
        #: the last frame's slide statistic and force drop (sigma), for the record
        self.z = 0.0
        self.drop = 0.0
        #: the contact's margin to slip from its history under stick (:class:`Margin`), and the
        #: last frame's margin and its 1-sigma
        self.history = Margin()
        self.margin = (math.nan, math.inf)
        #: the rules that declared the last onset (``margin``, ``slide``, ``drop``, ``plateau``,
        #: ``combined``)
        self.rules: tuple[str, ...] = ()

    def _at_rest(self) -> bool:
        """The centre moved by less than :data:`REST_Z` sigma over the last frames."""
        if len(self._slide) < self._slide.maxlen:
            return False
        (x0, y0, sx0, sy0), (x1, y1, sx1, sy1) = self._slide[0], self._slide[-1]
        zx = (x1 - x0) / math.hypot(sx0, sx1) if sx0 or sx1 else 0.0
        zy = (y1 - y0) / math.hypot(sy0, sy1) if sy0 or sy1 else 0.0
        return math.hypot(zx, zy) < REST_Z

    def _gone_since(self, test: SlideTest) -> tuple[float, float]:
        """Over the tracks of :data:`SLIDE_FRAMES` frames or more whose frames since their start
        show no stick zone (the mean of their unclipped ``lam`` within 2 sigma of 1 or above),
        with the slide over :data:`CONFIRM_Z`: the largest combined statistic, and the largest
        slide statistic among those whose levelling-off exceeds :data:`PLATEAU_Z`.  A contact
        held below the limit levels off at its ramp's end: the levelling-off alone is no
        evidence of slip there, and a 3-sigma slide among the starts is a chance of a few per
        cent a hold, so both rules need the stick zone gone since the start."""
        gate = np.zeros(WINDOW + 2, bool)
        num = den = 0.0
        for age, (v, s) in enumerate(reversed(self._lam), start=1):
            if not (math.isfinite(v) and math.isfinite(s) and s > 0):
                break
            num += v / (s * s)
            den += 1.0 / (s * s)
            gate[age] = num / den + 2.0 / math.sqrt(den) >= 1.0
        ages = np.clip(test.ages, 0, WINDOW + 1)
        ok = (test.ages >= SLIDE_FRAMES) & gate[ages] & (test.slides > CONFIRM_Z)
        plateau = ok & (test.levels > PLATEAU_Z)
        return float(test.tracks[ok].max(initial=0.0)), float(test.slides[plateau].max(initial=0.0))

    def update(self, frame: int, params: np.ndarray, cov: np.ndarray, lam_free: float | None = None
               ) -> tuple[str | None, SlipEvent | None]:
        """The state after this frame (``slip`` while sliding, else ``None``: the frame's own
        state stands) and the event declared on it, if any.  ``params`` and ``cov`` are the
        frame's estimate in the shear fit's order (:data:`tactiled.fit.shear.NAMES`; mm, N);
        ``lam_free`` its ``lam`` before the clip to [0, 1], for the filter."""
        params = np.asarray(params, dtype=float)
        cov = np.asarray(cov, dtype=float)
        event = None
        sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        lam, s_lam = float(params[7]), float(sig[7])
        s_q = _q_sigma(params, cov)
        q = math.hypot(params[4], params[5])
        self.filter.centre_walk = self.tracking.centre_walk = SLIDING_WALK if self.sliding else None
        self.tracking.update(params, cov, lam_free)
        z = joint = both = 0.0
        mobilised = False
        if self.filter.update(params, cov, lam_free) and not self.sliding:
            self.history.add(params, cov, lam_free)
            self.margin = self.history.margin(*self.filter.shear()["q_over_p"])
            self._lam.append((float(lam_free) if lam_free is not None else lam, s_lam))
            fx, fy, qf, s_qf = self.filter.tangential()
            if qf > MIN_Q_SIGMAS * s_qf:  # slip runs along a resolved Q
                self.test.update(self.filter, fx / qf, fy / qf)
                z = float(self.test.slides[self.test.ages >= SLIDE_FRAMES].max(initial=0.0))
                both, joint = self._gone_since(self.test)
            else:  # the tracks advance; no direction to test along
                self.test.update(self.filter, 1.0, 0.0)
            lam_f, s_lam_f = self.filter.value(7)
            mobilised = lam_f - 2.0 * s_lam_f > MOBILISED
            if self.filter.frames <= SETTLE:
                z = joint = both = 0.0
        # the stick zone gone within the frame's bound, or within the filter's (one frame's
        # lam scatters; the filter's follows the friction mobilised through the frames)
        gone_here = math.isfinite(s_lam) and lam + 2.0 * s_lam >= 1.0
        gone = gone_here
        if not gone and self.filter.x is not None and self.filter.frames > SETTLE:
            lam_f, s_lam_f = self.filter.value(7)
            gone = lam_f + 2.0 * s_lam_f >= 1.0
        drop = 0.0
        if len(self._q) == self._q.maxlen and math.isfinite(s_q):
            old, new = list(self._q)[:RECENT], [*list(self._q)[RECENT:], (q, s_q)]
            ref = sum(v for v, _ in old) / RECENT
            s_ref = math.sqrt(sum(s * s for _, s in old)) / RECENT
            now = sum(v for v, _ in new) / DROP_FRAMES
            s_now = math.sqrt(sum(s * s for _, s in new)) / DROP_FRAMES
            drop = (ref - now) / math.sqrt(s_now * s_now + s_ref * s_ref)
        self._q.append((q, s_q))
        self.z, self.drop = z, drop
        m, s_m = self.margin
        at_limit = (not self.sliding and self.history.frames >= MARGIN_FRAMES and s_m <= MARGIN_SIGMA
                    and m <= s_m)
        if not self.sliding:
            rules = {"margin": at_limit, "slide": z > ONSET_Z, "drop": drop > DROP_Z,
                     "plateau": mobilised and joint > CONFIRM_Z, "combined": mobilised and both > COMBINE_Z}
            if gone and any(rules.values()):
                self.rules = tuple(k for k, v in rules.items() if v)
                self.sliding = True
                self._calm = 0
                event = SlipEvent("onset", frame)
        else:
            self._slide.append((float(params[2]), float(params[3]), float(sig[2]), float(sig[3])))
            self._calm = 0 if gone_here or not self._at_rest() else self._calm + 1
            if self._calm >= END_FRAMES:
                self.sliding = False
                self._slide.clear()
                self.test.reset()
                self.history.reset()
                event = SlipEvent("end", frame)
        return ("slip" if self.sliding else None), event

    def feed(self, frame: int, est) -> tuple[str | None, SlipEvent | None]:
        """:meth:`update` from a :class:`~tactiled.fit.shear.ShearEstimate`."""
        return self.update(frame, est.params, est.cov, est.lam_free)

    def track(self, frame: int, step: Callable[[np.ndarray], Any], readings: np.ndarray
              ) -> tuple[Any, str, SlipEvent | None]:
        """One frame of a contact as the daemon estimates it: ``readings`` ``(rows, cols, 3)``
        through ``step``, the newest fit's :class:`~tactiled.fit.shear.ShearStep` (its
        estimate carries ``lam`` before the clip, which the filter needs), then the detector.
        Returns ``(estimate, state, event)``: ``state`` is ``slip`` while sliding, else the
        estimate's own.  The daemon (:mod:`tactiled.pipeline.shear_track`) and ``tactiled fit``
        on a 3-axis sequence both run this."""
        est = step(readings)
        sliding, event = self.feed(frame, est)
        return est, sliding or est.state(), event

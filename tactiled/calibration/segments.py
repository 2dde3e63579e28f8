"""Many independent piecewise-affine maps evaluated with one ``np.searchsorted`` call."""

# The lookup tables need, for every tactel ``t`` of a frame, ``y = f_t(x_t)`` where each ``f_t`` is
# piecewise affine with its own breakpoints.  A Python loop over 64 tactels costs ~100 us; instead
# all tactels' interior breakpoints live in *one* sorted array, tactel ``t``'s shifted by ``t * B``
# (``B`` larger than the span of any breakpoint or query), so a single ``searchsorted`` of the
# shifted queries finds every tactel's segment at once.  Segments are stored flat, tactel after
# tactel, so the segment found is a plain integer index into flat parameter arrays.
#
# Inside a segment ``y = y0 + slope * (x - x0)`` (the form ``np.interp`` uses, so results agree to
# rounding), clamped to ``[y0, cap]`` (its own start value and the next segment's start value) so
# that rounding can never make a non-decreasing table decrease across a breakpoint.

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


class Segments:
    """``T`` piecewise-affine channels: channel ``t`` has ``S_t >= 1`` segments.

    ``starts[t]``: segment start abscissae, strictly increasing (``starts[t][0]`` only labels the
    first segment: it also covers everything below, and the last segment everything above, i.e.
    the end segments extrapolate linearly).  ``y0[t]``, ``slope[t]``: value at the start and
    slope of each segment.  ``cap[t]``: upper bound of each segment's output (``inf`` for none);
    its lower bound is its ``y0`` (none for the first segment).
    ``domain``: the range queries are promised to lie in; outside it (or for NaN) the result is
    unspecified but never an exception.
    """

    def __init__(
        self,
        starts: Sequence[np.ndarray],
        y0: Sequence[np.ndarray],
        slope: Sequence[np.ndarray],
        cap: Sequence[np.ndarray],
        domain: tuple[float, float],
    ) -> None:
        channels = len(starts)
        if not (len(y0) == len(slope) == len(cap) == channels) or channels == 0:
            raise ValueError("starts, y0, slope and cap need one entry per channel")
        lo, hi = float(domain[0]), float(domain[1])
        for s in starts:
            if len(s) > 1:
                lo = min(lo, float(s[1:].min()))
                hi = max(hi, float(s[1:].max()))
        lo = math.floor(lo)  # integer offsets keep integer counts exact after shifting
        # Channel spacing: every shifted breakpoint and every shifted in-domain query of channel t
        # must sort strictly between those of channels t-1 and t+1.  Rounded up to an integer so
        # integer counts plus offset stay exact.
        spacing = float(math.ceil(hi - lo) + 2)
        if not math.isfinite(spacing) or spacing * channels > 2.0**52:
            raise ValueError(f"breakpoints/domain span too large to index: {lo!r} .. {hi!r}")
        self.channels = channels
        self._offset = np.arange(channels, dtype=np.float64) * spacing - lo
        # Each channel contributes a sentinel just below its shifted domain, then its interior
        # breakpoints: a query of channel t then counts sum(S_u, u < t) + 1 + j entries <= itself,
        # which is exactly the row of its segment j in the parameter table below, whose row 0 is
        # a NaN dummy (reached only by queries below channel 0's domain).  No per-tactel index
        # arithmetic is left for the hot path.
        self._breaks = np.concatenate(
            [
                np.concatenate(([lo - 1.0], np.asarray(s[1:], dtype=np.float64))) + self._offset[t]
                for t, s in enumerate(starts)
            ]
        )
        #: where each channel's entries (its sentinel, then its interior breakpoints) begin
        #: in ``_breaks``, and where the last ends, (T + 1,): the compiled stage searches a
        #: tactel's own entries only (tactiled.calibration.fused)
        self._first = np.cumsum([0] + [len(s) for s in starts]).astype(np.int64)
        x0 = np.concatenate([np.asarray(s, dtype=np.float64) for s in starts])
        y0_all = np.concatenate([np.asarray(v, dtype=np.float64) for v in y0])
        # Floor: a segment's own start value, except the first of each channel, which
        # extrapolates downwards.
        first = np.cumsum([0] + [len(s) for s in starts[:-1]])
        floor = y0_all.copy()
        floor[first] = -np.inf
        params = np.empty((5, x0.size + 1))
        params[:, 0] = (0.0, 0.0, np.nan, np.nan, np.nan)
        params[0, 1:] = x0
        params[1, 1:] = np.concatenate([np.asarray(v, dtype=np.float64) for v in slope])
        params[2, 1:] = y0_all
        params[3, 1:] = np.concatenate([np.asarray(v, dtype=np.float64) for v in cap])
        params[4, 1:] = floor
        # Rows x0, slope, y0, cap, floor; one column per segment: one take() fetches all, and
        # each row of the result is contiguous.
        self._params = params

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Evaluate at float64 ``x`` of shape ``(T,)`` or ``(N, T)``; returns a new flat array.

        Written for the per-frame hot path: every line is one numpy call on 64 elements.  (Pass
        float64: mixed-dtype arithmetic costs more than one astype.)
        """
        q = x + self._offset
        if q.ndim > 1:
            q = q.ravel()
            x = x.ravel()
        p = self._params.take(self._breaks.searchsorted(q, "right"), axis=1)
        y = x - p[0]
        y *= p[1]
        y += p[2]
        # Keep each segment's output within [its start value, the next segment's start value]:
        # rounding in the shifted search can put a query a hair from a breakpoint into the
        # neighbouring segment, and the clamp turns that into an exact, monotone answer.
        np.minimum(y, p[3], out=y)
        np.maximum(y, p[4], out=y)
        return y

"""The tracker's per-frame arithmetic in compiled kernels.

A tracked contact's frame is measured through its linearisation
(:meth:`tactiled.pipeline.tracker.Tracker.measure`) and tested for another contact pressed
beside it (:meth:`tactiled.pipeline.tracking.ContactTracking._pressed_elsewhere`): a gather,
two small matrix products and a weighted sum of squares on 20 to 100 tactels, which as numpy
calls cost more in call overhead than in arithmetic, on every frame of every array.  Here each
is one pass.  Results equal numpy's to rounding (the sums run in another order than BLAS's);
tests/pipeline/test_kernels.py compares them.

The signatures are explicit: the kernels load from numba's cache (or compile) when this module
is imported, at the daemon's start, never at a contact's first frame.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types

_VECTOR = types.Array(types.float64, 1, "C")
_MATRIX = types.Array(types.float64, 2, "A")
_INDEX = types.Array(types.intp, 1, "C")
#: a frame's strain: the pipeline hands it on read-only (frames are shared, never changed)
_FRAMES = (_VECTOR, types.Array(types.float64, 1, "C", readonly=True))


@njit([types.Tuple((types.float64, _VECTOR, _VECTOR))(frame, _INDEX, _VECTOR, _MATRIX, _MATRIX,
                                                      _VECTOR) for frame in _FRAMES],
      cache=True)
def measure_window(frame: np.ndarray, index: np.ndarray, at: np.ndarray, gain: np.ndarray,
                   jacobian: np.ndarray, weight: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """One frame through a linearisation: ``d = frame[index] - at`` (``frame`` flat, strain;
    ``at`` the linearisation's strains on its window, less whatever else the caller takes
    out there), ``dp = gain @ d`` (``gain`` (k, n)), ``e = d - jacobian @ dp`` (``jacobian``
    (n, k)).  Returns ``(chi2, dp, e)``, ``chi2 = sum(e^2 weight)``."""
    n = index.size
    k = gain.shape[0]
    d = np.empty(n)
    for j in range(n):
        d[j] = frame[index[j]] - at[j]
    dp = np.zeros(k)
    for i in range(k):
        s = 0.0
        for j in range(n):
            s += gain[i, j] * d[j]
        dp[i] = s
    chi2 = 0.0
    for j in range(n):
        r = d[j]
        for i in range(k):
            r -= jacobian[j, i] * dp[i]
        d[j] = r
        chi2 += r * r * weight[j]
    return chi2, dp, d


@njit([types.float64(frame, _INDEX, _VECTOR) for frame in _FRAMES], cache=True)
def largest_excess(frame: np.ndarray, index: np.ndarray, expected: np.ndarray) -> float:
    """``max(frame[index] - expected)`` (``frame`` flat); -inf for an empty ``index``."""
    top = -np.inf
    for j in range(index.size):
        top = max(top, frame[index[j]] - expected[j])
    return top


@njit([types.Tuple((types.int64, types.float64))(_VECTOR, _VECTOR, _INDEX, _VECTOR, types.float64,
                                                 types.float64, types.float64)], cache=True)
def fold_residuals(total: np.ndarray, count: np.ndarray, index: np.ndarray, buffered: np.ndarray,
                   frames: float, fade: float, least: float) -> tuple[int, float]:
    """The tracker's per-tactel residual sums (``total``, ``count``: the whole array, flat)
    faded by ``fade``, then ``buffered`` (the sum of ``frames`` frames' residuals on the
    window ``index``) added in, and ``buffered`` zeroed, all in place.  Returns the tactels
    whose count is at least ``least`` and the sum of ``total^2 / count`` over them (the mean
    residual's chi^2 times sigma^2)."""
    for i in range(total.size):
        total[i] *= fade
        count[i] *= fade
    for j in range(index.size):
        total[index[j]] += buffered[j]
        count[index[j]] += frames
        buffered[j] = 0.0
    used = 0
    chi2 = 0.0
    for i in range(total.size):
        if count[i] >= least:
            used += 1
            chi2 += total[i] * total[i] / count[i]
    return used, chi2

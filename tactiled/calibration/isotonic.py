"""Isotonic regression by pool-adjacent-violators (PAV).

Used by the table builder to make fitted knot values monotone.  Tiny inputs (one value per knot),
so a plain O(n) stack loop is the clearest correct implementation.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def isotonic_increasing(y: ArrayLike, weights: ArrayLike | None = None) -> np.ndarray:
    """Weighted least-squares non-decreasing fit to ``y``.

    Returns ``f`` minimising ``sum(w * (y - f)^2)`` subject to ``f[0] <= f[1] <= ...``.  Where
    ``y`` already is non-decreasing, ``f == y`` exactly.  ``weights`` must be positive (default
    1).  Runs of pooled values are equal to the weighted mean of the pooled ``y``.
    """
    yv = np.asarray(y, dtype=np.float64).ravel()
    wv = np.ones_like(yv) if weights is None else np.asarray(weights, dtype=np.float64).ravel()
    if wv.shape != yv.shape:
        raise ValueError(f"weights shape {wv.shape} does not match y shape {yv.shape}")
    if not (np.all(np.isfinite(yv)) and np.all(np.isfinite(wv))):
        raise ValueError("y and weights must be finite")
    if np.any(wv <= 0):
        raise ValueError("weights must be positive")
    # Stack of blocks: (weighted mean, total weight, number of points).
    means: list[float] = []
    totals: list[float] = []
    sizes: list[int] = []
    for value, weight in zip(yv.tolist(), wv.tolist()):
        means.append(value)
        totals.append(weight)
        sizes.append(1)
        # Pool while the newest block violates the order with its predecessor.
        while len(means) > 1 and means[-2] > means[-1]:
            w = totals[-2] + totals[-1]
            mean = (totals[-2] * means[-2] + totals[-1] * means[-1]) / w
            size = sizes[-2] + sizes[-1]
            del means[-1], totals[-1], sizes[-1]
            means[-1], totals[-1], sizes[-1] = mean, w, size
    return np.repeat(np.array(means), sizes)

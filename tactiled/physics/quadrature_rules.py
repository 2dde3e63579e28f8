"""Gauss rules for the strain integrals and the node counts they need, kept per process.

The unit-disk rule (weight ``sqrt(1 - u^2 - v^2)``) is a Gauss-Jacobi(1, 1) rule in u times a
Gauss-Chebyshev (second kind) rule in s, ``v = sqrt(1 - u^2) s``; the line contact integrates
across its line with the Chebyshev rule alone.  Node counts follow from the kernel's pole at
distance ``d`` (the rubber depth) from the real axis: ``n = ln(1/tol) / (2 ln rho)``,
``rho = d/a + sqrt(1 + (d/a)^2)``, rounded up to a ladder of sizes.  Used by
:mod:`tactiled.physics.strain`, :mod:`tactiled.physics.line`, :mod:`tactiled.physics.traction`
and the compiled fit's tables (:mod:`tactiled.fit.compiled`).
"""

from __future__ import annotations

import bisect
import math
from functools import lru_cache

import numpy as np
from scipy.special import roots_chebyu, roots_jacobi

DEFAULT_TOL = 1e-9
MIN_NODES = 3
#: Nodes per axis at most.  A contact needing more (longer than ~150x the rubber depth, some
#: 600 mm at tol 1e-6: 25 times the array) is refused with a ValueError rather than
#: integrated inaccurately; the planar model means nothing there anyway.
MAX_NODES = 1024
_LADDER = sorted({MIN_NODES, *range(4, 13), 14, 16, 18, 20, 24, 28, 32, 40, 48, 56, 64, 80, 96,
                  112, 128, 160, 192, 224, 256, 320, 384, 448, 512, 640, 768, 896, MAX_NODES})


@lru_cache(maxsize=None)
def _rule_u(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Jacobi(1, 1) nodes and weights (weight ``1 - u^2``)."""
    return roots_jacobi(n, 1.0, 1.0)


@lru_cache(maxsize=None)
def _rule_s(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Chebyshev (second kind) nodes and weights (weight ``sqrt(1 - s^2)``)."""
    return roots_chebyu(n)


#: Disk rules of at most this many nodes (``n_u * n_s``) are kept: with node counts on the
#: ladder that is 320 rules and 4.4 MB, all built by :func:`warm_rules` (in the forkserver's
#: template, so the workers share them).  Larger ones (contacts much longer than the rubber is
#: deep: rare, and each costs far more to integrate than to build) are built on every use and
#: never kept.  A cache of every pair met instead (an LRU of 512 rules, up to 24 MB each) grew
#: for hours as fits met new contact sizes: the fit workers' memory creep (docs/performance/reliability.md).
CACHED_RULE_NODES = 2048
#: The pairs of node counts kept: ``n_u >= n_s`` (the major semi-axis never needs fewer nodes
#: than the minor), both on the ladder.
_KEPT = frozenset((n_u, n_s) for n_u in _LADDER for n_s in _LADDER
                  if n_s <= n_u and n_u * n_s <= CACHED_RULE_NODES)


def warm_rules() -> None:
    """Compute now every rule this process will keep: the 1-D rules of every ladder size
    (~0.3 s) and the disk rules up to ``CACHED_RULE_NODES`` nodes (~10 ms).  A fit then never
    builds a rule it keeps, so a process's memory does not grow with the contacts it meets;
    and the first frames are fitted as fast as the later ones (scipy's root finders cost up to
    0.1 s a call)."""
    for n_u in _LADDER:
        _rule_u(n_u)
        _rule_s(n_u)
    for n_u, n_s in sorted(_KEPT):
        _kept_disk_rule(n_u, n_s)


def disk_rule(n_u: int, n_s: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nodes ``(u, v)`` and weights of the unit-disk rule for weight ``sqrt(1 - u^2 - v^2)``.

    The weights sum to ``2 pi / 3``.  Arrays are read-only (kept and shared up to
    ``CACHED_RULE_NODES`` nodes, built afresh beyond).  The 1-D rules are cached on their own,
    so a new pair of sizes costs only the tensor product.
    """
    if (n_u, n_s) in _KEPT:
        return _kept_disk_rule(n_u, n_s)
    return _build_disk_rule(n_u, n_s)


def _build_disk_rule(n_u: int, n_s: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    u, wu = _rule_u(n_u)
    s, ws = _rule_s(n_s)
    uu = np.repeat(u, n_s)
    ss = np.tile(s, n_u)
    v = np.sqrt(1.0 - uu * uu) * ss
    w = np.repeat(wu, n_s) * np.tile(ws, n_u)
    for arr in (uu, v, w):
        arr.setflags(write=False)
    return uu, v, w


#: The kept disk rules (keys: the pairs of ``_KEPT``, all built by warm_rules).
_kept_disk_rule = lru_cache(maxsize=None)(_build_disk_rule)


def nodes_for(extent: float, depth: float, tol: float = DEFAULT_TOL) -> int:
    """Gauss nodes needed along a semi-axis of ``extent`` mm for a kernel of ``depth`` mm;
    ``ValueError`` when that exceeds ``MAX_NODES`` (a contact too long to integrate)."""
    r = depth / max(extent, 1e-12)
    log_rho = math.asinh(r)  # ln(r + sqrt(1 + r^2))
    n = math.ceil(0.5 * math.log(1.0 / tol) / log_rho) if log_rho > 0 else MAX_NODES + 1
    if n > MAX_NODES:
        raise ValueError(
            f"contact ellipse semi-axis {extent:.4g} mm is too long for the planar model "
            f"(over {MAX_NODES} quadrature nodes at tol {tol:g})"
        )
    # Round up to a ladder of sizes: a fit exploring contact sizes then reuses a few dozen
    # cached rules instead of building hundreds (measured: 1.1 s of a fresh worker's first fit
    # went to building rules; extra nodes only add accuracy).
    return _LADDER[bisect.bisect_left(_LADDER, max(n, MIN_NODES))]

"""Separate pressed regions of one strain frame: where one array is touched in several places."""

# A contact's strain is one smooth bump, as wide as the cover spreads it (a few depths).  Two
# contacts are told apart by the dip between them: a region is a contact of its own when its peak
# stands out from the saddle that joins it to a higher one by more than the noise can make
# (``SEPARATION_Z`` sigmas) and by a share of its height (``SEPARATION_SHARE``) that no single
# contact's bump shows (a contact's strain has a single maximum; a flat top or a ridge wobbles by
# the noise and by the model error, a small share of its height).  Two contacts closer than the
# cover spreads them leave no such dip: they are one region, and the region says that it holds a
# second maximum (``absorbed``), so the fit reports one contact labelled ``merged`` rather than
# two guesses.
#
# The search is the topographic prominence of the strain surface: tactels are visited from the
# highest down and joined to their 8-neighbours already visited (a union-find); when two regions
# meet at a saddle, the lower one's prominence decides whether it stays a contact of its own.
# No I/O; a frame of 32x32 tactels costs well under a millisecond.

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tactiled import native

#: A region's peak must stand this many noise sigmas above zero to be a contact of its own
#: (the largest of 1024 tactels' pure noise is ~3.5 sigma; below ~8 sigma no curvature is
#: observable anyway).
SIGNIFICANT_Z = 8.0
#: ... and stand out from the saddle joining it to a higher region by this many sigmas ...
SEPARATION_Z = 6.0
#: ... and by this share of its own height (a single contact's strain never dips by this much
#: between two of its maxima: its wobble is the noise and the model's few per cent).
SEPARATION_SHARE = 0.25
#: A lower maximum joined to a higher one without the dip above is recorded (``absorbed``)
#: when it stands out by this many sigmas and this share of its height: a second contact the
#: cover merged with the first, or a sharp feature of one.
ABSORBED_SHARE = 0.1
#: Tactels below this many sigmas belong to no region (they are the noise around the contacts).
SUPPORT_Z = 3.0


@dataclass
class Region:
    """One pressed region: its peak tactel and strain, and its tactels (a boolean mask)."""

    peak_idx: tuple[int, int]
    peak: float
    tactels: np.ndarray
    #: lower maxima inside it that the cover merged with this one (see ABSORBED_SHARE): how
    #: many, and each one's tactel and strain
    absorbed: int = 0
    absorbed_at: list[tuple[tuple[int, int], float]] = field(default_factory=list)
    #: strain of the saddle to the higher region it meets (None for the highest region)
    saddle: float | None = None
    members: list[int] = field(default_factory=list, repr=False)


def _local_maxima(s: np.ndarray, floor: float) -> int:
    """How many tactels exceed ``floor`` and every 8-neighbour (a fast first look)."""
    p = np.full((s.shape[0] + 2, s.shape[1] + 2), -np.inf)  # padded (np.pad costs 30 us)
    p[1:-1, 1:-1] = s
    c = p[1:-1, 1:-1]
    is_max = c > floor
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr or dc:
                is_max &= c >= p[1 + dr:p.shape[0] - 1 + dr, 1 + dc:p.shape[1] - 1 + dc]
    return int(is_max.sum())


def find_regions(strain: np.ndarray, sigma: float, mask: np.ndarray | None = None) -> list[Region]:
    """The separate pressed regions of a zeroed strain frame, highest peak first.

    ``sigma`` is one tactel's strain noise (1 sigma); ``mask`` marks usable tactels (unusable
    and non-finite ones belong to no region).  A frame with at most one significant maximum
    is one region (or none when nothing reaches ``SIGNIFICANT_Z`` sigmas).
    """
    s = np.array(strain, dtype=float)
    ok = np.isfinite(s)
    if mask is not None:
        ok &= np.asarray(mask, dtype=bool)
    s[~ok] = -np.inf
    rows, cols = s.shape
    significant = SIGNIFICANT_Z * sigma
    if _local_maxima(s, significant) <= 1:
        if not s.size or not float(s.max()) > significant:
            return []
        flat = int(np.argmax(s))
        m, n = divmod(flat, cols)
        return [Region((m, n), float(s[m, n]), s > SUPPORT_Z * sigma)]
    return _watershed(s, sigma)


def _separable(peak: float, saddle: float, sigma: float) -> bool:
    rise = peak - saddle
    return (peak > SIGNIFICANT_Z * sigma and rise > SEPARATION_Z * sigma
            and rise > SEPARATION_SHARE * peak)


def _notable(peak: float, saddle: float, sigma: float) -> bool:
    rise = peak - saddle
    return (peak > SIGNIFICANT_Z * sigma and rise > SEPARATION_Z * sigma
            and rise > ABSORBED_SHARE * peak)


def _watershed(s: np.ndarray, sigma: float) -> list[Region]:
    rows, cols = s.shape
    peaks, heights, saddles, labels, absorbed = watershed(
        np.ascontiguousarray(s, dtype=float).ravel(), int(rows), int(cols), float(sigma),
        SUPPORT_Z, SIGNIFICANT_Z, SEPARATION_Z, SEPARATION_SHARE, ABSORBED_SHARE)
    out = []
    for k, (i, peak, saddle) in enumerate(zip(peaks.tolist(), heights.tolist(), saddles.tolist())):
        tactels = (labels == k).reshape(rows, cols)
        at = [(divmod(int(j), cols), float(h)) for r, j, h in absorbed.tolist() if int(r) == k]
        out.append(Region(divmod(int(i), cols), float(peak), tactels, absorbed=len(at),
                          absorbed_at=at, saddle=None if math.isnan(saddle) else float(saddle),
                          members=np.flatnonzero(labels == k).tolist()))
    return out


def watershed(flat: np.ndarray, rows: int, cols: int, sigma: float, support_z: float,
              significant_z: float, separation_z: float, separation_share: float,
              absorbed_share: float) -> tuple[np.ndarray, ...]:
    """The regions of a frame ``flat`` (row-major, ``rows`` x ``cols``, unusable tactels
    -inf) by topographic prominence (see the module's comment), highest peak first, as
    arrays: ``(peak tactels, peaks, saddles (NaN for none), each tactel's region or -1,
    absorbed maxima (region, tactel, strain) rows)``.  Equal heights are visited, and equal
    regions ranked, by tactel index.  The core's (core/regions.cpp) is held to this body."""
    support = support_z * sigma
    significant = significant_z * sigma

    def separable(peak: float, saddle: float, share: float) -> bool:
        rise = peak - saddle
        return peak > significant and rise > separation_z * sigma and rise > share * peak

    order = [int(i) for i in np.argsort(-flat, kind="stable") if flat[i] > support]
    parent: dict[int, int] = {}
    # per root: its peak's tactel and strain, lower maxima it absorbed, its tactels; in
    # the order the roots were made (``done``: regions of their own, in the order they met
    # a higher one)
    regions: dict[int, dict] = {}
    done: list[dict] = []

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in order:
        r, c = divmod(i, cols)
        roots = set()
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                rr, cc = r + dr, c + dc
                if (dr or dc) and 0 <= rr < rows and 0 <= cc < cols:
                    j = rr * cols + cc
                    if j in parent:
                        roots.add(root(j))
        if not roots:
            parent[i] = i
            regions[i] = {"peak_idx": i, "peak": float(flat[i]), "saddle": math.nan,
                          "absorbed": [], "members": [i]}
            continue
        ranked = sorted(roots, key=lambda k: (-regions[k]["peak"], k))
        main = ranked[0]
        level = float(flat[i])
        for other in ranked[1:]:
            low = regions.pop(other)
            parent[other] = main
            if separable(low["peak"], level, separation_share):
                low["saddle"] = level
                done.append(low)  # a contact of its own: its tactels stay its own
            else:
                high = regions[main]
                high["members"].extend(low["members"])
                high["absorbed"] += low["absorbed"]
                if separable(low["peak"], level, absorbed_share):
                    high["absorbed"].append((low["peak_idx"], low["peak"]))
        parent[i] = main
        regions[main]["members"].append(i)
    out = [reg for reg in (*regions.values(), *done) if reg["peak"] > significant]
    out.sort(key=lambda reg: reg["peak"], reverse=True)
    labels = np.full(flat.size, -1, dtype=np.int64)
    for k, reg in enumerate(out):
        labels[reg["members"]] = k
    absorbed = [(k, j, h) for k, reg in enumerate(out) for j, h in reg["absorbed"]]
    return (np.array([reg["peak_idx"] for reg in out], dtype=np.int64),
            np.array([reg["peak"] for reg in out], dtype=float),
            np.array([reg["saddle"] for reg in out], dtype=float), labels,
            np.array(absorbed, dtype=float).reshape(-1, 3))


#: The Python body the core is held to (tests/native), whichever runs.
REFERENCE = native.bind(globals(), ("watershed",))

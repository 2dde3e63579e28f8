"""Choosing the fit window around the peak and the interpolated centre of pressure."""

from __future__ import annotations

import math

import numpy as np

from tactiled import native


def window_origin(peak: int, size: int, length: int, lower: float, upper: float) -> int:
    """First index of a ``size``-long window on an axis of ``length`` tactels containing
    ``peak``; for an even size the extra tactel goes to the side whose neighbour (``lower`` at
    ``peak - 1``, ``upper`` at ``peak + 1``) is larger, so the peak sits as centrally as the
    data allow (the paper's 4x4 "containing the peak")."""
    if size >= length:
        return 0
    start = peak - (size - 1) // 2
    if size % 2 == 0 and upper < lower:
        start -= 1
    return min(max(start, 0), length - size)


def choose_window(strain: np.ndarray, peak: tuple[int, int], size: int) -> tuple[int, int, int, int]:
    """``(row0, col0, rows, cols)`` of a ``size`` x ``size`` window (clipped to the array)."""
    rows, cols = strain.shape
    m, n = peak
    nr, nc = min(size, rows), min(size, cols)

    def at(i: int, j: int) -> float:
        return float(strain[i, j]) if 0 <= i < rows and 0 <= j < cols else -math.inf

    r0 = window_origin(m, nr, rows, at(m - 1, n), at(m + 1, n))
    c0 = window_origin(n, nc, cols, at(m, n - 1), at(m, n + 1))
    return r0, c0, nr, nc


def _vertex(lo: float, mid: float, hi: float) -> float:
    """Offset in [-0.5, 0.5] tactels of the vertex of the parabola through three samples."""
    den = lo - 2.0 * mid + hi
    if not (den < 0.0):  # not a maximum: stay on the peak tactel
        return 0.0
    return min(max(0.5 * (lo - hi) / den, -0.5), 0.5)


def peak_centre(strain: np.ndarray, m: int, n: int, dx: float, dy: float) -> tuple[float, float]:
    """:func:`interpolated_peak` of the peak at ``(m, n)``, compiled (for callers that are)."""
    rows, cols = strain.shape
    c = strain[m, n]
    lo_x = strain[m - 1, n] if m > 0 else c
    hi_x = strain[m + 1, n] if m < rows - 1 else c
    lo_y = strain[m, n - 1] if n > 0 else c
    hi_y = strain[m, n + 1] if n < cols - 1 else c
    return (m + _vertex(lo_x, c, hi_x)) * dx, (n + _vertex(lo_y, c, hi_y)) * dy


def interpolated_peak(strain: np.ndarray, peak: tuple[int, int], dx: float, dy: float) -> tuple[float, float]:
    """Sub-tactel centre of pressure (mm): a parabola through the peak and its neighbours on
    each axis (the paper's start; its aliasing error is ~0.4 mm, which the fit removes)."""
    x, y = peak_centre(np.asarray(strain, dtype=float), int(peak[0]), int(peak[1]), float(dx), float(dy))
    return float(x), float(y)


def plain_window(strain: np.ndarray, size: int, max_strain: float) -> tuple[int, int, int, int, int, int, int]:
    """The peak and window of a frame with every tactel usable, in one compiled pass:
    ``(usable, m, n, row0, col0, rows, cols)``; ``usable`` is 0 when any strain is not finite
    or beyond ``max_strain`` (the caller then takes the general path).  The peak is the first
    maximum in row-major order (``np.argmax``); the window is :func:`choose_window`'s."""
    rows, cols = strain.shape
    best = -np.inf
    m = n = 0
    for i in range(rows):
        for j in range(cols):
            v = strain[i, j]
            if not (abs(v) <= max_strain):
                return 0, 0, 0, 0, 0, 0, 0
            if v > best:
                best, m, n = v, i, j
    nr, nc = min(size, rows), min(size, cols)
    lo_r = strain[m - 1, n] if m > 0 else -np.inf
    hi_r = strain[m + 1, n] if m + 1 < rows else -np.inf
    lo_c = strain[m, n - 1] if n > 0 else -np.inf
    hi_c = strain[m, n + 1] if n + 1 < cols else -np.inf
    return 1, m, n, window_origin(m, nr, rows, lo_r, hi_r), window_origin(n, nc, cols, lo_c, hi_c), nr, nc


def plain_frame(strain: np.ndarray, size: int, max_strain: float, min_peak: float, sigma: float):
    """:func:`plain_window` and the window's arrays in the same call, for a sensor without a
    model-error floor (each tactel weighted by the noise ``sigma`` alone): ``(usable, m, n,
    row0, col0, rows, cols, peak, target, valid, inv_scale, zdata)``, the window's strains
    flattened row-major, every one valid, ``1 / peak`` each, and in units of ``sigma`` (the
    numbers ``Fitter._window_arrays`` computes); ``usable`` is also 0 for a peak not above
    ``min_peak`` (no contact: the caller's general path words it)."""
    usable, m, n, r0, c0, nr, nc = plain_window(strain, size, max_strain)
    peak = strain[m, n]
    if not peak > min_peak:
        usable = 0
    k = nr * nc if usable else 0
    target = np.empty(k)
    valid = np.ones(k, dtype=np.bool_)
    inv_scale = np.empty(k)
    zdata = np.empty(k)
    if usable:
        inv = 1.0 / peak
        for i in range(nr):
            for j in range(nc):
                q = i * nc + j
                t = strain[r0 + i, c0 + j]
                target[q] = t
                inv_scale[q] = inv
                zdata[q] = t / sigma
    # the peak as a Python float, as the core's binding returns it (a numpy float64 would
    # make the fit's chi^2 unit divide by zero to inf where the core's raises)
    return usable, m, n, r0, c0, nr, nc, float(peak), target, valid, inv_scale, zdata


#: the Python bodies (the reference); the module's names run the compiled core's when it is loaded
REFERENCE = native.bind(globals(), ("window_origin", "peak_centre", "plain_window", "plain_frame"))

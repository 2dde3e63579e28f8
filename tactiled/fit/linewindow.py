"""The line model's window: the tactels that see the line, however far it runs (docs/concepts/fitting.md)."""

# A line contact's angle lives in its length: two tactels on the ridge ``L`` apart fix the
# direction to about ``sigma_offset / L``, so a square window cut from the middle of the ridge
# throws the angle's information away (on a 16x16 pad a 4x4 window's bound on the angle is ~10
# times the whole ridge's).  The line's window is therefore its *band*: the tactels 8-connected
# to the peak whose strain stands above the noise (``SUPPORT_Z`` sigmas) and above a share of the
# peak (``BAND_SHARE``: a neighbouring contact's strain, which dips to zero between two contacts
# some cover depths apart, does not join the band), grown by one tactel on every side (the flanks,
# where the strain falls fastest, carry the line's offset and width).  The window is the band's
# bounding box, only the band's tactels valid in it.  On a small array (at most
# ``WHOLE_ARRAY_TACTELS``) the whole array is the window: there every tactel's reading bears on
# the line and a fit over all of them costs what a 8x8 window's does.
#
# A line evaluation costs per tactel what a point contact's does, and a line fit over 100 tactels
# about 0.5 ms (a 4x4 window's: 0.25 ms), so following the line costs little.

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
from tactiled import native
from tactiled.fit.pointstrain import point_strain
from tactiled.fit.regions import SUPPORT_Z
from tactiled.fit.window import choose_window

#: A band tactel's strain is above this share of the peak (and ``SUPPORT_Z`` noise sigmas).
BAND_SHARE = 0.1
#: A band of fewer tactels (a weak line: a few tactels above the noise) is grown, a tactel
#: on every side at a time, at most ``MAX_GROWTH`` times, until it holds this many: the
#: line's four parameters fitted to 6-9 tactels follow the noise (its angle 15-70 deg off on
#: the 12x32 mat at 1 N, with a linearised sigma of 3-8 deg), and the tactels along the line
#: beyond its band still see it.
MIN_BAND_TACTELS = 24
MAX_GROWTH = 2
#: Arrays of at most this many tactels are fitted whole.
WHOLE_ARRAY_TACTELS = 64
#: A ridge runs across the array when its half-peak tactels reach within this many pitches of
#: the array's border at both ends of their major axis, and are at least ``RIDGE_ELONGATION``
#: times as long as wide (second moments).
RIDGE_REACH_PITCHES = 1.5
RIDGE_ELONGATION = 2.0


def band(clean: np.ndarray, ok: np.ndarray, peak_idx: tuple[int, int], peak: float,
         sigma: float) -> np.ndarray:
    """The line's band (a boolean frame; see the module's doc): the usable tactels that see
    the ridge through ``peak_idx`` of the zeroed frame ``clean``."""
    if clean.size <= WHOLE_ARRAY_TACTELS:
        return ok.copy()
    out = ridge_band(np.ascontiguousarray(clean, dtype=float), np.ascontiguousarray(ok, dtype=np.bool_),
                     int(peak_idx[0]), int(peak_idx[1]), max(SUPPORT_Z * sigma, BAND_SHARE * peak))
    for _ in range(MAX_GROWTH):
        if int(out.sum()) >= MIN_BAND_TACTELS:
            break
        out = _grown(out) & ok
    return out


def _grown(tactels: np.ndarray) -> np.ndarray:
    """``tactels`` grown by one tactel on every side (8-connected)."""
    out = tactels.copy()
    out[1:, :] |= tactels[:-1, :]
    out[:-1, :] |= tactels[1:, :]
    grown = out.copy()
    grown[:, 1:] |= out[:, :-1]
    grown[:, :-1] |= out[:, 1:]
    return grown


def ridge_band(clean: np.ndarray, ok: np.ndarray, m: int, n: int, threshold: float) -> np.ndarray:
    """The usable tactels above ``threshold`` 8-connected to ``(m, n)`` (a flood fill), grown
    by one tactel on every side, usable ones only.  The core's (core/linewindow.cpp) fills
    from the peak; this reference labels the 8-connected regions and keeps the peak's."""
    from scipy import ndimage

    eight = np.ones((3, 3), dtype=bool)
    above = ok & (clean > threshold)
    above[m, n] = True  # the peak starts the fill, whatever its value
    labels, _ = ndimage.label(above, structure=eight)
    ridge = labels == labels[m, n]
    return ndimage.binary_dilation(ridge, structure=eight) & ok


#: The Python body the core is held to (tests/native), whichever runs.
REFERENCE = native.bind(globals(), ("ridge_band",))


def bounding_window(tactels: np.ndarray) -> tuple[int, int, int, int]:
    """``(row0, col0, rows, cols)`` of the smallest window holding every True tactel (from
    the rows and columns that hold one: a few microseconds where the tactels' indices'
    extremes cost ~25)."""
    rows = np.flatnonzero(tactels.any(axis=1))
    cols = np.flatnonzero(tactels.any(axis=0))
    return int(rows[0]), int(cols[0]), int(rows[-1] - rows[0] + 1), int(cols[-1] - cols[0] + 1)


def square_window(fitter: Any, clean: np.ndarray, ok: np.ndarray, peak: float,
                  size: int) -> tuple[int, int, int, int] | None:
    """A ``size`` x ``size`` window on the ridge (tactels above half the peak) where it
    passes nearest the array's centre: what a square window sees of a line at best (the
    reference the line's band is benchmarked against); None without a ridge tactel."""
    g = fitter.sensor.geometry
    m, n = np.nonzero(ok & (clean >= 0.5 * peak))
    if m.size == 0:
        return None
    d2 = (m * g.dx - 0.5 * g.span_x) ** 2 + (n * g.dy - 0.5 * g.span_y) ** 2
    k = int(np.argmin(d2))
    return choose_window(clean, (int(m[k]), int(n[k])), size)


class KeptFrames:
    """The line windows of one frame's fit, each computed once: while :meth:`kept` is open
    (auto's models, several contacts' candidates), :func:`line_frame` returns the window it
    already made for the same strain and mask objects, the fitter's noise and flat field
    unchanged.  (Auto compares the point models with the line on the line's band, and a
    candidate contact's ridge test reads the band its fit then fits: ~0.06 ms each on a
    16x16 pad.)  The point models' square windows are kept alike (``point=True``: the
    fitter's ``_frame``; a candidate's ridge test and its fit read the same one).  Closed,
    nothing is kept: arrays are not assumed unchanged between fits."""

    def __init__(self) -> None:
        self.frames: list[tuple[tuple, Any]] | None = None
        self.points: list[tuple[tuple, Any]] = []
        #: the last ``(strain, mask, Fitter._prepare's answer)`` (read, never written)
        self.prepared: tuple | None = None

    @contextmanager
    def kept(self) -> Iterator[None]:
        """Keep windows until the outermost ``with`` ends."""
        outer = self.frames is None
        if outer:
            self.frames, self.points, self.prepared = [], [], None
        try:
            yield
        finally:
            if outer:
                self.frames, self.points, self.prepared = None, [], None

    def key(self, fitter: Any, strain: Any, mask: Any) -> tuple:
        f = fitter.flat
        return (strain, mask, fitter.sigma, None if f is None else (f.active, f.dx, f.dy))

    def get(self, key: tuple, point: bool = False) -> Any:
        for k, fr in (self.points if point else self.frames) or ():
            if k[0] is key[0] and k[1] is key[1] and k[2] == key[2] and _same_flat(k[3], key[3]):
                return fr
        return None

    def put(self, key: tuple, fr: Any, point: bool = False) -> None:
        if self.frames is not None:
            kept = self.points if point else self.frames
            kept.append((key, fr))
            del kept[:-KEPT_FRAMES]


#: Line windows :class:`KeptFrames` holds at most (a fit's own, a candidate's, the ridge test's).
KEPT_FRAMES = 4


def _same_flat(a: Any, b: Any) -> bool:
    return a is b or (a is not None and b is not None and a[0] == b[0] and a[1] is b[1] and a[2] is b[2])


def line_frame(fitter: Any, strain: np.ndarray, mask: np.ndarray | None, size: int | None = None):
    """The line model's window on ``strain`` (a ``fitter._Frame``, or the FitResult saying
    there is none): the line's band, or with ``size`` a square window of that side on the
    ridge (:func:`square_window`).  A band is made once per frame while the fitter's
    :class:`KeptFrames` keeps them (the caller reads, never writes, the window's arrays)."""
    kept = getattr(getattr(fitter, "line", None), "frames", None)
    key = None
    if size is None and kept is not None and kept.frames is not None:
        key = kept.key(fitter, strain, mask)
        fr = kept.get(key)
        if fr is not None:
            return fr
    fr = _line_frame(fitter, strain, mask, size)
    if key is not None and not _is_result(fr):
        kept.put(key, fr)
    return fr


def _is_result(fr: Any) -> bool:
    from tactiled.fit.result import FitResult

    return isinstance(fr, FitResult)


def _line_frame(fitter: Any, strain: np.ndarray, mask: np.ndarray | None, size: int | None):
    """:func:`line_frame`, computed."""
    from tactiled.fit.result import FitResult
    from tactiled.fit.search import LINE_MODEL as _LINE_MODEL

    fr = fitter._window(strain, _LINE_MODEL, mask)
    if isinstance(fr, FitResult):
        return fr
    clean, ok = fitter._prepare(strain, mask)
    if size is not None:
        win = square_window(fitter, clean, ok, fr.peak, size)
        if win is None:
            return fr
        out = fitter._window_arrays(clean, ok, fr.peak_idx, fr.peak, win)
        return out if out.n_points > _LINE_MODEL.size else fr
    seen = band(clean, ok, fr.peak_idx, fr.peak, fitter.sigma)
    out = fitter._window_arrays(clean, seen, fr.peak_idx, fr.peak, bounding_window(seen))
    if out.n_points <= _LINE_MODEL.size:
        return fr
    out.clean = np.where(seen, clean, 0.0)  # the starts' moments: the band's strain alone
    return out


def chi2_on_band(fitter: Any, strain: np.ndarray, mask: np.ndarray | None, model: str,
                 params: tuple[float, ...] | None) -> tuple[float | None, int]:
    """``(chi^2, tactels)`` of a point contact ``model`` at ``params`` (internal) on the line's
    band: auto's information criterion compares the line with the point models on the same
    tactels, the band the line was fitted on (a ridge's segment that a finite ellipse explains
    in a 4x4 window, the ellipse's ends leave unexplained along the band).  ``(None, 0)``
    without a band or a prediction."""
    from tactiled.fit.result import FitResult

    fr = line_frame(fitter, strain, mask)
    if isinstance(fr, FitResult) or params is None:
        return None, 0
    pred = point_strain(fitter, model, params, fr.win)
    if pred is None:
        return None, 0
    left = (fr.target - pred.ravel())[fr.valid]
    sd = fitter._tactel_sd(fr.target[fr.valid])
    return float(np.sum((left / sd) ** 2)), fr.n_points


def runs_across(fitter: Any, flat: np.ndarray, mask: np.ndarray | None) -> tuple[bool, np.ndarray | None]:
    """Whether the strain through the peak of ``flat`` (after the flat field) is a ridge that
    runs across the array (a line contact: no ellipse has both its ends beyond the array),
    and the line's band there (None without a peak)."""
    from tactiled.fit.result import FitResult

    fr = line_frame(fitter, flat, mask)
    if isinstance(fr, FitResult):
        return False, None
    g = fitter.sensor.geometry
    seen = np.zeros(flat.shape, bool)
    r0, c0, nr, nc = fr.win
    seen[r0:r0 + nr, c0:c0 + nc] = fr.valid.reshape(nr, nc)
    m, n = np.nonzero(seen & (fr.clean >= 0.5 * fr.peak))
    if m.size < 3:
        return False, seen
    x, y = m * g.dx, n * g.dy
    mx, my = x.mean(), y.mean()
    small, big, (ux, uy) = spread(x - mx, y - my)
    if not small * RIDGE_ELONGATION ** 2 < big:
        return False, seen
    t = (x - mx) * ux + (y - my) * uy
    # the array's extent along the axis through the ridge's centre
    ends = [(-mx / ux, (g.span_x - mx) / ux) if abs(ux) > 1e-9 else (-np.inf, np.inf),
            (-my / uy, (g.span_y - my) / uy) if abs(uy) > 1e-9 else (-np.inf, np.inf)]
    lo = max(min(e) for e in ends)
    hi = min(max(e) for e in ends)
    reach = RIDGE_REACH_PITCHES * max(g.dx, g.dy)
    return bool(t.min() <= lo + reach and t.max() >= hi - reach), seen


def spread(x: np.ndarray, y: np.ndarray) -> tuple[float, float, tuple[float, float]]:
    """The second moments of the points ``(x, y)`` about their mean: ``(smaller, larger,
    (ux, uy))``, the covariance's two eigenvalues and the larger's unit eigenvector (its sign
    arbitrary), in closed form for the 2x2 matrix (a ridge test runs a few times per frame:
    ``np.cov`` and ``eigh`` cost ~30 us where this costs ~5)."""
    dx, dy = x - x.mean(), y - y.mean()
    a, b, c = float(dx @ dx), float(dx @ dy), float(dy @ dy)
    half = 0.5 * (a + c)
    root = math.hypot(0.5 * (a - c), b)
    big = half + root
    ux, uy = (big - c, b) if a >= c else (b, big - a)
    norm = math.hypot(ux, uy)
    if norm > 0.0:
        ux, uy = ux / norm, uy / norm
    scale = 1.0 / max(x.size - 1, 1)
    return (half - root) * scale, big * scale, (ux, uy)

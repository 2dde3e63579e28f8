"""The calibration stage's per-frame arithmetic in numba kernels: the Python reference of the
compiled core's (core/calibrate.cpp), which :mod:`tactiled.calibration.fused` selects unless
``TACTILED_CORE=python``.

What :class:`~tactiled.calibration.stage.CalibrationStage` does to each frame, as the reference
objects do it (:class:`~tactiled.calibration.lut.LookupTable` ->
:class:`~tactiled.calibration.zeroing.Zeroer` with its
:class:`~tactiled.calibration.hysteresis.HysteresisCompensator` ->
:class:`~tactiled.calibration.contact.ContactDetector`), is a dozen numpy calls on 64 to 256
numbers, each costing more in call overhead than in arithmetic.  Here the same arithmetic runs
in one pass over the tactels:

* :func:`zero_frame`: raw counts -> strain through the table's segments (the same search and
  the same clamped affine map as :class:`~tactiled.calibration.segments.Segments`), minus the
  baseline, less the hysteresis residual (updating the compensator's peak-hold), and the
  matched-filter statistic ``max(Ax z Ay^T)`` of the result;
* :func:`follow_baseline`: the baseline's step towards an untouched frame, its pull clipped
  when most tactels are implausibly far out (:data:`~tactiled.calibration.zeroing.MAX_STEP_SIGMAS`).

and under a held contact (:meth:`~tactiled.calibration.zeroing.Zeroer.follow_drift`), every
``DRIFT_STEP_S``: :func:`drift_error` and :func:`pull_baseline`, the baseline following drift
around the contact, and :func:`learn_hysteresis`, a step of the hysteresis learner.

The decisions (contact, settling, release hold-off, tare) stay in Python, in the stage, with
the state of the objects above, so either path can take any frame.  The kernels keep the
interpreter's lock: released for the few microseconds of a frame, it went to the serial read
thread, and the loop then waited to take it back (live on the simulated hand, niced: 105-115
us a frame with the lock kept, 113-122 released, four runs each alternating,
docs/performance/hand.md).  Results equal the
reference path's to rounding (the statistic's sums run in another order than BLAS's);
tests/calibration/test_fused_stage.py compares them on random frames.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from numba import njit, types


@njit(cache=True)
def zero_frame(raw: np.ndarray, offset: np.ndarray, breaks: np.ndarray, first: np.ndarray,
               params: np.ndarray, baseline: np.ndarray, peak: np.ndarray, fraction: float,
               decay: float, floor: float, margin: float, active: bool, ax: np.ndarray,
               ay_t: np.ndarray, bands: np.ndarray, z: np.ndarray, residual: np.ndarray,
               tmap: np.ndarray) -> tuple[int, float, float]:
    """One frame of raw counts ``raw`` (flat, ``T`` tactels, row-major) into ``z`` (flat),
    through the table's :class:`~tactiled.calibration.segments.Segments` (``offset``,
    ``breaks``, ``first``, ``params``):
    linearised, zeroed against ``baseline`` and, with ``fraction`` > 0, compensated for the
    rubber's hysteresis (the compensator's ``peak`` updated in place; its previous peaks
    decayed by ``decay`` = ``exp(-dt / tau)``, 1 for none; ``floor`` = MIN_PEAK_SIGMAS sigma,
    ``margin`` = NOISE_MARGIN sigma; ``active``: some peak was above the floor).

    Returns ``(state, statistic, peak)``: state -1 when a linearised value was not finite
    (nothing was changed: the caller takes the reference path), else bit 0 set when a
    residual was taken (it is in ``residual``; otherwise ``residual`` is untouched) and bit 1
    set when the compensator is still active; ``statistic`` is ``max(Ax z Ay^T)`` on the
    compensated frame, whose filter map (flat, row-major) is written to ``tmap``; ``peak``
    is ``max(z)``.  ``bands``: where the filter
    matrices are not zero (:func:`tactiled.calibration.fused.filter_bands`).
    """
    n = raw.size
    nb = breaks.size
    for t in range(n):
        x = float(raw[t])
        q = x + offset[t]
        # searchsorted(breaks, q, "right"): the number of breaks <= q.  A query between its
        # tactel's sentinel and the next tactel's (any count in the table's domain) is
        # searched among its tactel's own entries (``first``: where each tactel's begin),
        # one step or none for a linear table; any other, among all
        lo, hi = first[t], first[t + 1]
        if breaks[lo] <= q and (hi == nb or q < breaks[hi]):
            lo += 1
        else:
            lo, hi = 0, nb
        while lo < hi:
            mid = (lo + hi) >> 1
            if breaks[mid] <= q:
                lo = mid + 1
            else:
                hi = mid
        y = x - params[0, lo]
        y *= params[1, lo]
        y += params[2, lo]
        y = min(y, params[3, lo])
        y = max(y, params[4, lo])
        if not math.isfinite(y):
            return -1, 0.0, 0.0
        z[t] = y - baseline[t]
    state = 0
    if fraction > 0.0:
        zmax = z[0]
        for t in range(n):
            zmax = max(zmax, z[t])
        if active or zmax >= floor:
            gain = fraction / (1.0 - fraction)
            top = 0.0
            for t in range(n):
                p = peak[t] * decay
                zt = z[t]
                taken = 0.0
                if zt < p and p > floor:
                    taken = min((p - zt) * gain, fraction * p)
                residual[t] = taken
                p = max(p, zt - margin)
                peak[t] = p
                top = max(top, p)
                z[t] = zt - taken
            state = 1 | (2 if top > floor else 0)
    # The matched filter, separable: T = Ax Z Ay^T, Z the (rows, cols) frame; each template
    # row reaches a few tactels only (its band), the rest of the products being zeros.
    cols = ay_t.shape[0]
    nu, nv = ax.shape[0], ay_t.shape[1]
    m = np.zeros((nu, cols))
    for u in range(nu):
        for i in range(bands[0, u], bands[1, u]):
            a = ax[u, i]
            for j in range(cols):
                m[u, j] += a * z[i * cols + j]
    stat = -math.inf
    for u in range(nu):
        for v in range(nv):
            s = 0.0
            for j in range(bands[2, v], bands[3, v]):
                s += m[u, j] * ay_t[j, v]
            tmap[u * nv + v] = s
            stat = max(stat, s)
    peak = z[0]
    for t in range(1, n):
        peak = max(peak, z[t])
    return state, stat, peak


@njit(cache=True)
def average_maps(ring: np.ndarray, total: np.ndarray, tmap: np.ndarray, count: int,
                 head: int) -> tuple[int, int, float]:
    """The detector's running mean of its last ``ring.shape[0]`` filter maps: ``tmap`` (the
    newest) added to ``total`` (the sum of the ``count`` maps in ``ring``, the oldest at
    ``head`` once full), the oldest taken out when the ring is full, ``tmap`` stored in its
    place.  Until the ring has filled, the mean has more noise than the threshold assumes,
    so it is scaled by ``1 / sqrt(n * average)`` instead of ``1 / n`` (the same false-contact
    rate).  Returns ``(count, head, statistic)``: the new count and head, and ``max`` of the
    scaled sum."""
    average = ring.shape[0]
    p = tmap.size
    if count == 0:
        for i in range(p):
            total[i] = tmap[i]
    else:
        for i in range(p):
            total[i] += tmap[i]
        if count == average:
            for i in range(p):
                total[i] -= ring[head, i]
    for i in range(p):
        ring[head, i] = tmap[i]
    head = (head + 1) % average
    count = min(count + 1, average)
    factor = 1.0 / count if count == average else 1.0 / math.sqrt(count * average)
    stat = -math.inf
    for i in range(p):
        stat = max(stat, total[i] * factor)
    return count, head, stat


@njit(cache=True)
def follow_baseline(baseline: np.ndarray, z: np.ndarray, weight: float, limit: float,
                    clip: bool) -> None:
    """``baseline += weight * z``, in place; with ``clip``, when more than half the tactels
    lie beyond ``limit`` (an implausible frame), ``z`` is first clipped to ``[-limit, limit]``
    in place (the frame the zeroer returns, as its pull on the baseline)."""
    n = z.size
    if clip:
        beyond = 0
        for t in range(n):
            if abs(z[t]) > limit:
                beyond += 1
        if beyond * 2 > n:
            for t in range(n):
                z[t] = min(max(z[t], -limit), limit)
                baseline[t] += weight * z[t]
            return
    for t in range(n):
        baseline[t] += weight * z[t]


def _vectors(dtype: types.Type, writable: bool) -> list[types.Array]:
    """Contiguous 1-d arrays of ``dtype`` (any flat ``reshape(-1)`` of an array is one),
    read-only too unless ``writable`` (the daemon's frames are read-only)."""
    return [types.Array(dtype, 1, "C")] + ([] if writable else
                                            [types.Array(dtype, 1, "C", readonly=True)])


_PEAKS = types.Array(types.float64, 2, "C")
_TAUS = types.Array(types.float64, 1, "C")
_NORMAL = types.Array(types.float64, 3, "C")
_MOMENT = types.Array(types.float64, 2, "C")


# Explicit signatures: compiled (or loaded from numba's cache) at import, never at a held
# contact's first drift step.
@njit([types.Tuple((types.int64, types.float64, types.boolean))(z, p, i, e)
       for z, p, i in itertools.product(_vectors(types.float64, False),
                                        _vectors(types.float64, False),
                                        _vectors(types.boolean, False))
       for e in _vectors(types.float64, True)], cache=True)
def drift_error(zeroed: np.ndarray, predicted: np.ndarray, inside: np.ndarray,
                error: np.ndarray) -> tuple[int, float, bool]:
    """``error = zeroed - predicted`` (flat, in place) for the zeroer's drift following under
    a held contact; returns the tactels ``inside`` the contact's window, the sum of the
    squared error there, and whether every error is finite."""
    n_in = 0
    miss = 0.0
    finite = True
    for t in range(zeroed.size):
        e = zeroed[t] - predicted[t]
        error[t] = e
        if inside[t]:
            n_in += 1
            miss += e * e
        if not math.isfinite(e):
            finite = False
    return n_in, miss, finite


@njit([types.none(b, e, i, types.float64, types.float64, types.int64)
       for b in _vectors(types.float64, True) for e in _vectors(types.float64, True)
       for i in _vectors(types.boolean, False)], cache=True)
def pull_baseline(baseline: np.ndarray, error: np.ndarray, inside: np.ndarray, limit: float,
                  weight: float, outside: int) -> None:
    """The baseline's step under a held contact, in place (all flat): outside the window
    each tactel moves by ``weight`` times its error clipped to ``[-limit, limit]``; inside,
    by the mean of those moves over the ``outside`` tactels (the drift common to all)."""
    common = 0.0
    for t in range(error.size):
        if not inside[t]:
            common += min(max(error[t], -limit), limit) * weight
    common /= outside
    for t in range(error.size):
        if inside[t]:
            baseline[t] += common
        else:
            baseline[t] += min(max(error[t], -limit), limit) * weight


@njit([types.boolean(_PEAKS, _TAUS, types.float64, p, u, o, types.float64, _NORMAL, _MOMENT,
                     types.float64)
       for p, u, o in itertools.product(_vectors(types.float64, False),
                                        _vectors(types.float64, False),
                                        _vectors(types.boolean, False))], cache=True)
def learn_hysteresis(peaks: np.ndarray, taus: np.ndarray, dt: float, predicted: np.ndarray,
                     unexplained: np.ndarray, outside: np.ndarray, floor: float,
                     normal: np.ndarray, moment: np.ndarray, forget: float) -> bool:
    """One step of :class:`~tactiled.calibration.hysteresis.HysteresisLearner` (all flat per
    tactel): each time constant's peak-hold of the compressive ``predicted`` strain
    (``peaks``, one row per ``taus`` s) decayed over ``dt`` s (none when ``dt <= 0``) and
    raised to the load, in place; on the ``outside`` tactels, the regressors ``q_k`` (what a
    peak-hold above ``floor`` held beyond the load now) and the normal equations of
    ``unexplained ~ f q_k + a load + c`` added to ``normal`` (k, 3, 3) and ``moment`` (k, 3)
    after both are multiplied by ``forget``.  False (the sums untouched) when no tactel
    outside holds anything: no trail to learn from."""
    kk, n = peaks.shape
    if dt > 0.0:
        for k in range(kk):
            decay = math.exp(-dt / taus[k])
            for j in range(n):
                peaks[k, j] *= decay
    for j in range(n):
        load = max(predicted[j], 0.0)
        for k in range(kk):
            if load > peaks[k, j]:
                peaks[k, j] = load
    qq = np.zeros(kk)
    ql = np.zeros(kk)
    q1 = np.zeros(kk)
    qe = np.zeros(kk)
    ll = l1 = le = e1 = 0.0
    count = 0
    trail = False
    for j in range(n):
        if not outside[j]:
            continue
        load = max(predicted[j], 0.0)
        e = unexplained[j]
        count += 1
        ll += load * load
        l1 += load
        le += load * e
        e1 += e
        for k in range(kk):
            held = peaks[k, j]
            if held > floor:
                q = held - load
                if q != 0.0:
                    trail = True
                qq[k] += q * q
                ql[k] += q * load
                q1[k] += q
                qe[k] += q * e
    if not trail:
        return False
    for k in range(kk):
        for a in range(3):
            moment[k, a] *= forget
            for b in range(3):
                normal[k, a, b] *= forget
        normal[k, 0, 0] += qq[k]
        normal[k, 0, 1] += ql[k]
        normal[k, 1, 0] += ql[k]
        normal[k, 0, 2] += q1[k]
        normal[k, 2, 0] += q1[k]
        normal[k, 1, 1] += ll
        normal[k, 1, 2] += l1
        normal[k, 2, 1] += l1
        normal[k, 2, 2] += count
        moment[k, 0] += qe[k]
        moment[k, 1] += le
        moment[k, 2] += e1
    return True

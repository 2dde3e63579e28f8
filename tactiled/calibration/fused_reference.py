"""The calibration stage's per-frame arithmetic in NumPy: the Python reference of the compiled
core's (core/calibrate.cpp), which :mod:`tactiled.calibration.fused` selects when
``TACTILED_CORE=python``.
"""

# What :class:`~tactiled.calibration.stage.CalibrationStage` does to each frame, as the reference
# objects do it (:class:`~tactiled.calibration.lut.LookupTable` ->
# :class:`~tactiled.calibration.zeroing.Zeroer` with its
# :class:`~tactiled.calibration.hysteresis.HysteresisCompensator` ->
# :class:`~tactiled.calibration.detection.ContactDetector`), is a dozen numpy calls on 64 to 256
# numbers, each costing more in call overhead than in arithmetic.  The core runs the same
# arithmetic in one pass over the tactels; here it is written as whole-array NumPy operations in
# the core's order of operations (each sum runs in tactel order, as ``np.cumsum`` sums, never
# pairwise), so the two give the same bits (tests/native/test_calibrate_core.py):
#
# * :func:`zero_frame`: raw counts -> strain through the table's segments (the same search and
#   the same clamped affine map as :class:`~tactiled.calibration.segments.Segments`), minus the
#   baseline, less the hysteresis residual (updating the compensator's peak-hold), and the
#   matched-filter statistic ``max(Ax z Ay^T)`` of the result;
# * :func:`follow_baseline`: the baseline's step towards an untouched frame, its pull clipped
#   when most tactels are implausibly far out (:data:`~tactiled.calibration.zeroing.MAX_STEP_SIGMAS`).
#
# and under a held contact (:meth:`~tactiled.calibration.zeroing.Zeroer.follow_drift`), every
# ``DRIFT_STEP_S``: :func:`drift_error` and :func:`pull_baseline`, the baseline following drift
# around the contact, and :func:`learn_hysteresis`, a step of the hysteresis learner.
#
# The decisions (contact, settling, release hold-off, tare) stay in Python, in the stage, with
# the state of the objects above, so either path can take any frame.  The core's kernels keep the
# interpreter's lock: released for the few microseconds of a frame, it goes to the serial
# read thread, and the loop then waits to take it back (live on the simulated hand, niced: 105-115
# us a frame with the lock kept, 113-122 released, four runs each alternating,
# docs/performance/hand.md).

from __future__ import annotations

import math

import numpy as np


def _ordered_sum(values: np.ndarray, axis: int = -1) -> np.ndarray | float:
    """The sum of ``values`` along ``axis`` in index order, one addition after another (the
    core's order; ``np.sum`` sums pairwise, to other bits)."""
    if values.shape[axis] == 0:
        out = np.zeros(np.delete(values.shape, axis if axis >= 0 else values.ndim + axis))
        return out if out.ndim else 0.0
    total = np.cumsum(values, axis=axis).take(-1, axis=axis)
    return total if np.ndim(total) else float(total)


def _at_most(x: np.ndarray, limit: np.ndarray | float) -> np.ndarray:
    """Python's ``min(x, limit)`` element by element (``x`` unless ``limit`` is smaller)."""
    return np.where(limit < x, limit, x)


def _at_least(x: np.ndarray, limit: np.ndarray | float) -> np.ndarray:
    """Python's ``max(x, limit)`` element by element (``x`` unless ``limit`` is larger)."""
    return np.where(limit > x, limit, x)


def _largest(values: np.ndarray) -> float:
    """``max`` from -inf as Python takes it one value after another (a NaN never wins)."""
    return float(np.fmax.reduce(values.ravel(), initial=-math.inf))


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
    is ``max(z)``.  ``bands``: where the filter matrices are not zero
    (:func:`tactiled.calibration.fused.filter_bands`; the reference multiplies the zeros too,
    which adds nothing to the sums).
    """
    x = np.asarray(raw, dtype=np.float64)
    # one search of all the tactels' breaks (``first`` lets the core start at each tactel's own)
    seg = np.searchsorted(breaks, x + offset, "right")
    y = x - params[0, seg]
    y *= params[1, seg]
    y += params[2, seg]
    y = _at_least(_at_most(y, params[3, seg]), params[4, seg])
    if not np.isfinite(y).all():
        return -1, 0.0, 0.0
    zz = y - baseline
    state = 0
    if fraction > 0.0 and (active or _largest(zz) >= floor):
        gain = fraction / (1.0 - fraction)
        p = peak * decay
        taken = np.where((zz < p) & (p > floor), _at_most((p - zz) * gain, fraction * p), 0.0)
        residual[:] = taken
        p = _at_least(p, zz - margin)
        peak[:] = p
        top = max(0.0, _largest(p))
        zz = zz - taken
        state = 1 | (2 if top > floor else 0)
    z[:] = zz
    # The matched filter, separable: T = Ax Z Ay^T, Z the (rows, cols) frame; each product's
    # sum runs over the frame's rows (then columns) in order, as the core's does
    cols = ay_t.shape[0]
    frame = zz.reshape(-1, cols)
    m = np.zeros((ax.shape[0], cols))
    for i in range(frame.shape[0]):
        m += ax[:, i:i + 1] * frame[i]
    t = np.zeros((ax.shape[0], ay_t.shape[1]))
    for j in range(cols):
        t += m[:, j:j + 1] * ay_t[j]
    tmap[:] = t.ravel()
    return state, _largest(t), float(zz.max())


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
    if count == 0:
        total[:] = tmap
    else:
        total += tmap
        if count == average:
            total -= ring[head]
    ring[head] = tmap
    head = (head + 1) % average
    count = min(count + 1, average)
    factor = 1.0 / count if count == average else 1.0 / math.sqrt(count * average)
    return count, head, _largest(total * factor)


def follow_baseline(baseline: np.ndarray, z: np.ndarray, weight: float, limit: float,
                    clip: bool) -> None:
    """``baseline += weight * z``, in place; with ``clip``, when more than half the tactels
    lie beyond ``limit`` (an implausible frame), ``z`` is first clipped to ``[-limit, limit]``
    in place (the frame the zeroer returns, as its pull on the baseline)."""
    if clip and int(np.count_nonzero(np.abs(z) > limit)) * 2 > z.size:
        z[:] = _at_most(_at_least(z, -limit), limit)
    baseline += weight * z


def drift_error(zeroed: np.ndarray, predicted: np.ndarray, inside: np.ndarray,
                error: np.ndarray) -> tuple[int, float, bool]:
    """``error = zeroed - predicted`` (flat, in place) for the zeroer's drift following under
    a held contact; returns the tactels ``inside`` the contact's window, the sum of the
    squared error there, and whether every error is finite."""
    np.subtract(zeroed, predicted, out=error)
    e = error[inside]
    return int(e.size), _ordered_sum(e * e), bool(np.isfinite(error).all())


def pull_baseline(baseline: np.ndarray, error: np.ndarray, inside: np.ndarray, limit: float,
                  weight: float, outside: int) -> None:
    """The baseline's step under a held contact, in place (all flat): outside the window
    each tactel moves by ``weight`` times its error clipped to ``[-limit, limit]``; inside,
    by the mean of those moves over the ``outside`` tactels (the drift common to all)."""
    move = _at_most(_at_least(error, -limit), limit) * weight
    common = _ordered_sum(move[~inside]) / outside
    baseline += np.where(inside, common, move)


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
    if dt > 0.0:
        peaks *= np.array([math.exp(-dt / tau) for tau in taus.tolist()])[:, None]
    load = _at_least(predicted, 0.0)
    peaks[:] = np.where(load > peaks, load, peaks)
    held = peaks[:, outside]
    load, e = load[outside], unexplained[outside]
    holding = held > floor
    q = held - load
    if not (holding & (q != 0.0)).any():
        return False
    # a tactel that holds nothing adds 0 to the regressors' sums (which leaves their bits)
    qh = np.where(holding, q, 0.0)
    qq, ql = _ordered_sum(qh * qh), _ordered_sum(qh * load)
    q1, qe = _ordered_sum(qh), _ordered_sum(qh * e)
    ll, l1 = _ordered_sum(load * load), _ordered_sum(load)
    le, e1 = _ordered_sum(load * e), _ordered_sum(e)
    moment *= forget
    normal *= forget
    normal[:, 0, 0] += qq
    normal[:, 0, 1] += ql
    normal[:, 1, 0] += ql
    normal[:, 0, 2] += q1
    normal[:, 2, 0] += q1
    normal[:, 1, 1] += ll
    normal[:, 1, 2] += l1
    normal[:, 2, 1] += l1
    normal[:, 2, 2] += load.size
    moment[:, 0] += qe
    moment[:, 1] += le
    moment[:, 2] += e1
    return True


# The run's state and constants (:func:`zero_run`), one float64 vector each, in this order; the
# stage (:meth:`~tactiled.calibration.stage.CalibrationStage.process_run`) packs its objects'
# state into ``state`` and unpacks it after the call.
#: zeroer: last frame's time (s), frames since the baseline's start, settle and release-hold
#: ends (s), baseline variance, in contact; compensator active; detector: ring count and head,
#: last statistic, in contact; the last frame: its residual valid, its largest strain; a
#: contact released in the run (drift following restarts)
RUN_STATE = ("last_t", "frames", "settle_until", "release_until", "baseline_var",
             "in_contact", "active", "count", "head", "last_statistic", "detector_in_contact",
             "residual_valid", "peak", "released")
#: compensator fraction and time constant (s), its floor and margin (strain), noise sigma,
#: the detector's enter and exit thresholds, tau_drift, tau_release, holdoff (s), the
#: baseline's step limit (strain), frames averaged by the detector
RUN_CONSTANTS = ("fraction", "tau_s", "floor", "margin", "sigma", "enter", "exit",
                 "tau_drift", "tau_release", "holdoff", "max_step", "average")


def zero_run(raws: list[np.ndarray], times: np.ndarray, offset: np.ndarray, breaks: np.ndarray,
             first: np.ndarray, params: np.ndarray, baseline: np.ndarray, peak: np.ndarray,
             ax: np.ndarray, ay_t: np.ndarray, bands: np.ndarray, ring: np.ndarray,
             total: np.ndarray, z: np.ndarray, residual: np.ndarray, stats: np.ndarray,
             peaks: np.ndarray, state: np.ndarray, constants: np.ndarray) -> int:
    """A run of frames through the calibration stage in one call: for each of ``raws`` (counts,
    flat or ``(rows, cols)``) at device time ``times[i]`` (s), what
    :meth:`CalibrationStage.process` does on its compiled path (:func:`zero_frame`, the
    detector's decision with its hysteresis and averaging, the zeroer's settling and the
    baseline's step), its zeroed strain into ``z[i]``, its statistic and largest strain into
    ``stats[i]`` and ``peaks[i]``.  Stops after the first frame in contact (the pipeline's
    tracking may move the baseline before the next frame) and before a frame
    :func:`zero_frame` does not take (a non-finite value: the reference path's).  ``state``
    (``RUN_STATE``) is read and written back; ``baseline``, ``peak``, ``ring``, ``total`` are
    updated in place; ``residual``: the last frame's compensation.  Returns the frames
    taken."""
    (fraction, tau_s, floor, margin, sigma, enter, exit_, tau_drift, tau_release, holdoff,
     max_step, average) = (float(c) for c in constants)
    average = int(average)
    last_t, frames, settle_until, release_until = state[0], int(state[1]), state[2], state[3]
    baseline_var, in_contact, active = state[4], bool(state[5]), bool(state[6])
    count, head, last_statistic = int(state[7]), int(state[8]), state[9]
    det_in, residual_valid, top, released = bool(state[10]), bool(state[11]), state[12], bool(state[13])
    tmap = np.empty(total.size)
    scratch = np.empty(residual.size)
    taken = 0
    for i, raw in enumerate(raws):
        t = float(times[i])
        dt = t - last_t
        zi = z[i].reshape(-1)
        res = scratch if fraction > 0.0 else zi
        code, stat, pk = zero_frame(raw.reshape(-1), offset, breaks, first, params, baseline,
                                    peak, fraction, math.exp(-dt / tau_s) if dt > 0.0 else 1.0,
                                    floor, margin, active, ax, ay_t, bands, zi, res, tmap)
        if code < 0:
            break
        taken += 1
        top = pk
        frames += 1
        settling = t < settle_until
        last_t = t
        residual_valid = bool(code & 1)
        if residual_valid:
            residual[:] = scratch
        if fraction > 0.0:
            active = bool(code & 2)
        if settling:
            contact = False
        else:
            if average > 1:
                count, head, stat = average_maps(ring, total, tmap, count, head)
            last_statistic = stat
            det_in = stat >= exit_ if det_in else stat > enter
            contact = det_in
        stats[i], peaks[i] = last_statistic, pk  # (the detector's: unchanged while settling)
        if contact:
            in_contact = True
            break
        if in_contact:
            in_contact = False
            release_until = t + holdoff
            released = True
        if dt > 0.0:
            tau = tau_release if t < release_until else tau_drift
            ema = -math.expm1(-dt / tau)
            mean = 1.0 / frames
            sigma2 = sigma ** 2
            if mean >= ema:
                follow_baseline(baseline, zi, mean, 0.0, False)
                baseline_var = sigma2 * mean
            else:
                baseline_var = (1.0 - ema) ** 2 * baseline_var + ema * ema * sigma2
                follow_baseline(baseline, zi, ema, max_step, True)
    state[:] = (last_t, frames, settle_until, release_until, baseline_var, in_contact, active,
                count, head, last_statistic, det_in, residual_valid, top, released)
    return taken


class ZeroRun:
    """One stage's :func:`zero_run`: its arrays (the table's segments, ``baseline``, ``peak``,
    the filter, the detector's ``ring`` and ``total``, ``residual``) and ``constants`` given
    once, as the core checks them once; :meth:`run` takes a read's frames."""

    def __init__(self, offset: np.ndarray, breaks: np.ndarray, first: np.ndarray,
                 params: np.ndarray, baseline: np.ndarray, peak: np.ndarray, ax: np.ndarray,
                 ay_t: np.ndarray, bands: np.ndarray, ring: np.ndarray, total: np.ndarray,
                 residual: np.ndarray, constants: np.ndarray) -> None:
        self._arrays = (offset, breaks, first, params, baseline, peak, ax, ay_t, bands, ring,
                        total)
        self._residual, self._constants = residual, np.array(constants, dtype=np.float64)

    def run(self, raws: list[np.ndarray], times: np.ndarray, z: np.ndarray, stats: np.ndarray,
            peaks: np.ndarray, state: np.ndarray) -> int:
        """:func:`zero_run` of these frames with this stage's arrays; returns the frames
        taken."""
        return zero_run(raws, times, *self._arrays, z, self._residual, stats, peaks, state,
                        self._constants)

"""The tracker's per-frame arithmetic in compiled kernels.

A tracked contact's frame is measured through its linearisation
(:meth:`tactiled.pipeline.tracker.Tracker.measure`) and tested for another contact pressed
beside it (:meth:`tactiled.pipeline.tracking.ContactTracking._pressed_elsewhere`): a gather,
two small matrix products and a weighted sum of squares on 20 to 100 tactels, which as numpy
calls cost more in call overhead than in arithmetic, on every frame of every array; its
measurement then goes through the per-parameter Kalman filters
(:meth:`~tactiled.pipeline.tracker.Tracker.step`), a few dozen float operations per parameter
that cost as Python far more than as machine code.  Here each is one pass, on the tracker's
state and constants as two small tables (the ``X .. DRIFT`` and ``C_R .. C_LIN_SD`` rows).  Results equal numpy's to rounding (the sums run in another order than BLAS's);
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


# -- the tracker's filter ------------------------------------------------------------------------

#: Rows of a tracker's state (``Tracker._s``, shape (6, k), a column per parameter): value,
#: rate, the covariance [[pxx, pxv], [pxv, pvv]], the drift detector.
X, V, PXX, PXV, PVV, DRIFT = range(6)
#: Rows of a tracker's constants between linearisations (``Tracker._c``, shape (8, k)): one
#: frame's variance, moving (1) or held (0), the linearisation point, one frame's sigma, the
#: box a measurement is kept in, a logarithm (1) or not (0), the state's sigma when
#: linearised (NaN: there was no state then).
C_R, C_MOVING, C_POINT, C_SD1, C_LOW, C_HIGH, C_LOG, C_LIN_SD = range(8)

_TABLE = types.Array(types.float64, 2, "C")



@njit([types.Tuple((_TABLE, _TABLE, _TABLE, types.boolean))(
    table, _MATRIX, _VECTOR, _TABLE, _MATRIX, types.float64)
    for table in (_TABLE, types.Array(types.float64, 2, "C", readonly=True))], cache=True)
def linearization_constants(table: np.ndarray, cov: np.ndarray, p: np.ndarray, s: np.ndarray,
                            systematic: np.ndarray, zero_scale: float
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """A tracker's constants for a new linearisation (``Tracker.adopt``): ``table`` (the
    model's rows of ``C_R .. C_LIN_SD``) with one frame's variances (the diagonal of ``cov``)
    and sigmas, the point ``p`` and the state's sigma then (from ``s``'s ``PXX`` row; NaN
    when ``s`` has no column per parameter: no state yet); the single frame's correlations
    ``cov / (sd sd^T)``; the systematic covariance ``systematic + zero_scale * cov``, and
    whether any of it is nonzero.  The same arithmetic as numpy's, element by element."""
    k = p.size
    c = table.copy()
    with_state = s.shape[1] == k
    for i in range(k):
        r = cov[i, i]
        c[C_R, i] = r
        c[C_SD1, i] = np.sqrt(r)
        c[C_POINT, i] = p[i]
        c[C_LIN_SD, i] = np.sqrt(s[PXX, i]) if with_state else np.nan
    corr = np.empty((k, k))
    sys = np.empty((k, k))
    nonzero = False
    for i in range(k):
        for j in range(k):
            corr[i, j] = cov[i, j] / (c[C_SD1, i] * c[C_SD1, j])
            v = systematic[i, j] + zero_scale * cov[i, j]
            sys[i, j] = v
            nonzero = nonzero or v != 0.0
    return c, corr, sys, nonzero


@njit([types.Tuple((types.boolean, _VECTOR, _VECTOR))(
    frame, _INDEX, _VECTOR, _MATRIX, _MATRIX, _VECTOR, _TABLE, types.float64, types.int64,
    types.float64, types.float64) for frame in _FRAMES], cache=True)
def measure_point(frame: np.ndarray, index: np.ndarray, at: np.ndarray, gain: np.ndarray,
                  jacobian: np.ndarray, weight: np.ndarray, const: np.ndarray, limit: float,
                  ln_f: int, reset_sigma: float, max_log_force_step: float
                  ) -> tuple[bool, np.ndarray, np.ndarray]:
    """:func:`measure_window`, then the tracker's tests of the step (see
    :meth:`tactiled.pipeline.tracker.Tracker.measure_at`): ``(ok, z, e)``, ``z`` the measured
    parameters (the point plus the step, clipped to the box), ``e`` the residual; ``ok``
    False when the frame needs a fit of its own (``chi2`` beyond ``limit``, a non-finite step,
    a logarithm moved by more than 1 and beyond ``reset_sigma`` single-frame sigmas, or the
    log force (row ``ln_f``) by more than ``max_log_force_step``).  ``const``: the rows
    ``C_R .. C_LIN_SD``."""
    chi2, dz, e = measure_window(frame, index, at, gain, jacobian, weight)
    if chi2 > limit:
        return False, dz, e
    k = dz.size
    for i in range(k):
        if not np.isfinite(dz[i]):
            return False, dz, e
    for i in range(k):
        step = abs(dz[i])
        if const[C_LOG, i] != 0.0 and step >= 1.0 and (
                step > reset_sigma * const[C_SD1, i] or (i == ln_f and step > max_log_force_step)):
            return False, dz, e
    for i in range(k):
        dz[i] = min(max(const[C_POINT, i] + dz[i], const[C_LOW, i]), const[C_HIGH, i])
    return True, dz, e


@njit([types.int64(_VECTOR, _TABLE, _TABLE, types.float64, types.float64, types.float64,
                   types.boolean, types.float64, types.float64, types.float64)], cache=True)
def filter_frame(z: np.ndarray, s: np.ndarray, const: np.ndarray, dt: float, acc_scale: float,
                 walk: float, fitted: bool, reset_sigma: float, drift_alpha: float,
                 drift_limit: float) -> int:
    """One measurement ``z`` through the per-parameter filters ``s`` (rows ``X .. DRIFT``, in
    place), ``dt`` (s) after the last: predicted (a moving parameter: constant velocity with
    white acceleration of density ``acc_scale`` R; a held one: a random walk of ``walk`` R per
    frame), then updated, and the drift detector (running mean ``drift_alpha``, alarm
    ``drift_limit``) widening what lags.  Returns 0 when updated; when a parameter's
    innovation is beyond ``reset_sigma`` of its predicted spread, -1 with ``s`` unchanged (not
    ``fitted``: the frame needs a fit), or (``fitted``) the predicted state kept and a bit
    mask of the parameters that jumped (bit i: parameter i), for the caller to restart them."""
    k = z.size
    xp = np.empty(k)
    pxxp = np.empty(k)
    pxvp = np.empty(k)
    pvvp = np.empty(k)
    u = np.empty(k)
    dt2, dt3 = dt * dt, dt * dt * dt
    jumped = 0
    for i in range(k):
        ri = const[C_R, i]
        x, pxx, pxv, pvv = s[X, i], s[PXX, i], s[PXV, i], s[PVV, i]
        if const[C_MOVING, i] != 0.0:
            acc = acc_scale * ri
            x += s[V, i] * dt
            pxx += 2.0 * dt * pxv + dt2 * pvv + acc * dt3 / 3.0
            pxv += dt * pvv + acc * dt2 / 2.0
            pvv += acc * dt
        else:
            pxx += ri * walk
        xp[i], pxxp[i], pxvp[i], pvvp[i] = x, pxx, pxv, pvv
        u[i] = (z[i] - x) / np.sqrt(pxx + ri)
        if abs(u[i]) > reset_sigma:
            jumped |= 1 << i
    if jumped and not fitted:
        return -1
    for i in range(k):
        s[X, i], s[PXX, i], s[PXV, i], s[PVV, i] = xp[i], pxxp[i], pxvp[i], pvvp[i]
    if jumped:
        return jumped
    for i in range(k):
        ri = const[C_R, i]
        x, v, pxx, pxv, pvv, drift = s[X, i], s[V, i], s[PXX, i], s[PXV, i], s[PVV, i], s[DRIFT, i]
        total = pxx + ri
        k1, k2 = pxx / total, pxv / total
        nu = z[i] - x
        x += k1 * nu
        v += k2 * nu
        pvv -= k2 * pxv
        pxx *= 1.0 - k1
        pxv *= 1.0 - k1
        drift += drift_alpha * (u[i] - drift)
        if abs(drift) > drift_limit:
            # the parameter runs away from the model (it accelerates, or the object changes
            # slowly): widen what is uncertain so the filter catches up
            if const[C_MOVING, i] != 0.0:
                window = dt / drift_alpha
                lag = drift * np.sqrt(total) / window
                pvv = max(pvv, 16.0 * (lag * lag))
            else:
                pxx = max(pxx, total)
            drift = 0.0
        s[X, i], s[V, i], s[PXX, i], s[PXV, i], s[PVV, i], s[DRIFT, i] = x, v, pxx, pxv, pvv, drift
    return 0


@njit([types.boolean(_TABLE, _TABLE, types.float64, types.float64)], cache=True)
def moved_from_point(s: np.ndarray, const: np.ndarray, sigmas: float, sharpen: float) -> bool:
    """The state ``s`` has moved from the linearisation point by more than ``sigmas``
    single-frame sigmas in some parameter, or its spread has shrunk below 1/``sharpen`` of
    what it was when linearised (or there was no state then)."""
    for i in range(s.shape[1]):
        lin_sd = const[C_LIN_SD, i]
        if (abs(s[X, i] - const[C_POINT, i]) > sigmas * const[C_SD1, i] or not lin_sd == lin_sd
                or sharpen * sharpen * s[PXX, i] < lin_sd * lin_sd):
            return True
    return False


@njit(cache=True)
def _delta_cov(idx: np.ndarray, grad: np.ndarray, ka: int, kb: int, sd: np.ndarray,
               corr: np.ndarray, sys: np.ndarray, has_sys: bool) -> float:
    """The covariance of values ``ka`` and ``kb`` from their gradient terms (in the order
    :meth:`Tracker.estimate`'s plain-float version summed them)."""
    total = 0.0
    for ia in range(2):
        a = idx[ka, ia]
        if a < 0:
            break
        ga = grad[ka, ia]
        gsa = ga * sd[a]
        for ib in range(2):
            b = idx[kb, ib]
            if b < 0:
                break
            gb = grad[kb, ib]
            total += gsa * (gb * sd[b]) * corr[a, b]
            if has_sys:
                total += ga * gb * sys[a, b]
    return total


#: The models :func:`estimate_numbers` knows, by the code it takes.
MODEL_CODES = {"cylinder": 0, "sphere": 1, "general": 2}
_RAD_TO_DEG = 180.0 / np.pi


@njit([types.Tuple((_VECTOR, _VECTOR, types.float64, types.int64))(
    types.int64, _TABLE, _TABLE, types.float64, types.float64, _TABLE, _TABLE, types.boolean,
    types.float64)], cache=True)
def estimate_numbers(model: int, s: np.ndarray, const: np.ndarray, dt: float, excess: float,
                     corr: np.ndarray, sys: np.ndarray, has_sys: bool,
                     lag_noise: float) -> tuple[np.ndarray, np.ndarray, float, int]:
    """The numbers of a tracker's estimate (:meth:`~tactiled.pipeline.tracker.Tracker.estimate`):
    the state ``s`` predicted ``dt`` s ahead (0: as it is), each value of
    ``tactiled.fit.params.VALUE_KEYS`` (:func:`~tactiled.fit.params.report_terms` of
    ``model``, a :data:`MODEL_CODES` code; the orientation as psi in radians, for the caller
    to wrap) and its variance by the delta method term by term: the state's variances (each
    moving parameter's lag added where its drift detector's mean, squared, is beyond
    ``lag_noise``; times ``excess``) with the single frame's correlations ``corr``, plus the
    systematic covariance ``sys`` when ``has_sys``; the covariance of r1 and the force.
    Returns ``(values, variances, cov_r1_force, absent)``, ``absent`` a bit mask of the
    values the model does not have (bit i: key i; their value and variance NaN)."""
    k = s.shape[1]
    x = np.empty(k)
    pxx = np.empty(k)
    for i in range(k):
        if dt != 0.0:
            x[i] = s[X, i] + s[V, i] * dt
            pxx[i] = s[PXX, i] + dt * (2.0 * s[PXV, i] + dt * s[PVV, i])
        else:
            x[i] = s[X, i]
            pxx[i] = s[PXX, i]
    for i in range(k):
        d = s[DRIFT, i]
        if const[C_MOVING, i] != 0.0 and d * d > lag_noise:
            pxx[i] = pxx[i] + d * d * (pxx[i] + const[C_R, i])
    sd = np.empty(k)
    for i in range(k):
        q = pxx[i] * excess
        sd[i] = np.sqrt(q) if q >= 0.0 else np.nan
    values = np.full(6, np.nan)
    # each value's gradient: up to two (parameter, derivative) terms; none: absent
    idx = np.full((6, 2), -1, dtype=np.int64)
    grad = np.zeros((6, 2))
    absent = 0
    # every model ends with ln_f, x0, y0
    f = np.exp(x[k - 3])
    values[0], values[1], values[2] = x[k - 2], x[k - 1], f
    idx[0, 0], grad[0, 0] = k - 2, 1.0
    idx[1, 0], grad[1, 0] = k - 1, 1.0
    idx[2, 0], grad[2, 0] = k - 3, f
    if model == 0:  # cylinder: ln_r, psi, ln_f, x0, y0
        r = np.exp(x[0])
        values[3], values[5] = r, x[1]
        idx[3, 0], grad[3, 0] = 0, r
        idx[5, 0], grad[5, 0] = 1, _RAD_TO_DEG
        absent = 1 << 4
    elif model == 1:  # sphere: ln_r, ln_f, x0, y0
        r = np.exp(x[0])
        values[3], values[4] = r, r
        idx[3, 0], grad[3, 0] = 0, r
        idx[4, 0], grad[4, 0] = 0, r
        absent = 1 << 5
    else:  # general: ln_ra, beta, psi, ln_f, x0, y0
        ra, beta = np.exp(x[0]), x[1]
        b2 = beta * beta
        psi = x[2]
        if b2 <= 1.0:  # r1 = R_a, r2 = R_a / beta^2 (none for beta = 0)
            values[3] = ra
            idx[3, 0], grad[3, 0] = 0, ra
            if b2 > 0.0:
                r2 = ra / b2
                values[4] = r2
                idx[4, 0], grad[4, 0] = 0, r2
                idx[4, 1], grad[4, 1] = 1, -2.0 * r2 / beta
            else:
                absent = 1 << 4
        else:  # axes swapped: the R2 axis is perpendicular to the fitted psi
            r1 = ra / b2
            values[3], values[4] = r1, ra
            idx[3, 0], grad[3, 0] = 0, r1
            idx[3, 1], grad[3, 1] = 1, -2.0 * r1 / beta
            idx[4, 0], grad[4, 0] = 0, ra
            psi += 0.5 * np.pi
        values[5] = psi
        idx[5, 0], grad[5, 0] = 2, _RAD_TO_DEG
    var = np.full(6, np.nan)
    for key in range(6):
        if idx[key, 0] >= 0:
            var[key] = _delta_cov(idx, grad, key, key, sd, corr, sys, has_sys)
    cov_rf = np.nan
    if idx[3, 0] >= 0:
        cov_rf = _delta_cov(idx, grad, 3, 2, sd, corr, sys, has_sys)
    return values, var, cov_rf, absent

"""The tracker's per-frame arithmetic, one call per step."""

# A tracked contact's frame is measured through its linearisation
# (:meth:`tactiled.pipeline.contact_filter.Tracker.measure`) and tested for another contact pressed
# beside it (:meth:`tactiled.pipeline.sensor_tracking.ContactTracking._pressed_elsewhere`): a gather,
# two small matrix products and a weighted sum of squares on 20 to 100 tactels, which as numpy
# calls cost more in call overhead than in arithmetic, on every frame of every array; its
# measurement then goes through the per-parameter Kalman filters
# (:meth:`~tactiled.pipeline.contact_filter.Tracker.step`), a few dozen float operations per parameter
# that cost as Python far more than as machine code.  Here each is one call, on the tracker's
# state and constants as two small tables (the ``X .. DRIFT`` and ``C_R .. C_LIN_SD`` rows),
# and :class:`TrackStep` puts a tracked frame's together: one call a frame, one an estimate.
#
# The functions below are the Python reference; the compiled core (core/tracker.cpp) replaces
# them unless ``TACTILED_CORE=python`` (:func:`tactiled.native.bind`).  The core sums in plain
# order; the reference's :func:`measure_window` sums through numpy's BLAS (vectorised), so the
# two agree to rounding there and to the bit elsewhere (tests/native/test_tracker_core.py).
# The reference works on Python floats, as the core on doubles: a float division by zero raises
# ``ZeroDivisionError`` in both.

from __future__ import annotations

import math

import numpy as np

from tactiled import native


def _sqrt(x: float) -> float:
    """``sqrt(x)``, NaN below zero (numpy's and C's, not :func:`math.sqrt`'s ValueError)."""
    return math.sqrt(x) if x >= 0.0 else math.nan


def _exp(x: float) -> float:
    """``exp(x)``, inf on overflow (numpy's and C's, not :func:`math.exp`'s OverflowError)."""
    try:
        return math.exp(x)
    except OverflowError:
        return math.inf


def measure_window(frame: np.ndarray, index: np.ndarray, at: np.ndarray, gain: np.ndarray,
                   jacobian: np.ndarray, weight: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """One frame through a linearisation: ``d = frame[index] - at`` (``frame`` flat, strain;
    ``at`` the linearisation's strains on its window, less whatever else the caller takes
    out there), ``dp = gain @ d`` (``gain`` (k, n)), ``e = d - jacobian @ dp`` (``jacobian``
    (n, k)).  Returns ``(chi2, dp, e)``, ``chi2 = sum(e^2 weight)``."""
    d = frame[index] - at
    dp = gain @ d
    e = d - jacobian @ dp
    return float(np.dot(e * e, weight)), dp, e


def largest_excess(frame: np.ndarray, index: np.ndarray, expected: np.ndarray) -> float:
    """``max(frame[index] - expected)`` (``frame`` flat); -inf for an empty ``index``."""
    # Python's max from -inf, as the core takes it: a NaN never wins (fmax skips it)
    return float(np.fmax.reduce(frame[index] - expected[:index.size], initial=-math.inf))


def fold_residuals(total: np.ndarray, count: np.ndarray, index: np.ndarray, buffered: np.ndarray,
                   frames: float, fade: float, least: float) -> tuple[int, float]:
    """The tracker's per-tactel residual sums (``total``, ``count``: the whole array, flat)
    faded by ``fade``, then ``buffered`` (the sum of ``frames`` frames' residuals on the
    window ``index``) added in, and ``buffered`` zeroed, all in place.  Returns the tactels
    whose count is at least ``least`` and the sum of ``total^2 / count`` over them (the mean
    residual's chi^2 times sigma^2)."""
    total *= fade
    count *= fade
    total[index] += buffered  # (a window's indices are distinct)
    count[index] += frames
    buffered[:] = 0.0
    used = count >= least
    t = total[used]
    chi2 = 0.0
    for v in (t * t / count[used]).tolist():  # summed in order, as the core sums
        chi2 += v
    return int(used.sum()), chi2


# -- the tracker's filter ------------------------------------------------------------------------

#: Rows of a tracker's state (``Tracker._s``, shape (6, k), a column per parameter): value,
#: rate, the covariance [[pxx, pxv], [pxv, pvv]], the drift detector.
X, V, PXX, PXV, PVV, DRIFT = range(6)
#: Rows of a tracker's constants between linearisations (``Tracker._c``, shape (8, k)): one
#: frame's variance, moving (1) or held (0), the linearisation point, one frame's sigma, the
#: box a measurement is kept in, a logarithm (1) or not (0), the state's sigma when
#: linearised (NaN: there was no state then).
C_R, C_MOVING, C_POINT, C_SD1, C_LOW, C_HIGH, C_LOG, C_LIN_SD = range(8)


def linearization_constants(table: np.ndarray, cov: np.ndarray, p: np.ndarray, s: np.ndarray,
                            systematic: np.ndarray, zero_scale: float
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """A tracker's constants for a new linearisation (``Tracker.adopt``): ``table`` (the
    model's rows of ``C_R .. C_LIN_SD``) with one frame's variances (the diagonal of ``cov``)
    and sigmas, the point ``p`` and the state's sigma then (from ``s``'s ``PXX`` row; NaN
    when ``s`` has no column per parameter: no state yet); the single frame's correlations
    ``cov / (sd sd^T)``; the systematic covariance ``systematic + zero_scale * cov``, and
    whether any of it is nonzero."""
    k = p.size
    c = np.array(table, dtype=np.float64, order="C")
    cv = np.asarray(cov, dtype=np.float64).tolist()
    sd = [_sqrt(cv[i][i]) for i in range(k)]
    c[C_R] = [cv[i][i] for i in range(k)]
    c[C_SD1] = sd
    c[C_POINT] = p
    c[C_LIN_SD] = [_sqrt(v) for v in s[PXX].tolist()] if s.shape[1] == k else math.nan
    corr = np.array([[cv[i][j] / (sd[i] * sd[j]) for j in range(k)] for i in range(k)]).reshape(k, k)
    sys = np.asarray(systematic, dtype=np.float64) + zero_scale * np.asarray(cov, dtype=np.float64)
    return c, corr, np.ascontiguousarray(sys).reshape(k, k), bool(np.any(sys != 0.0))


def measure_point(frame: np.ndarray, index: np.ndarray, at: np.ndarray, gain: np.ndarray,
                  jacobian: np.ndarray, weight: np.ndarray, const: np.ndarray, limit: float,
                  ln_f: int, reset_sigma: float, max_log_force_step: float
                  ) -> tuple[bool, np.ndarray, np.ndarray]:
    """:func:`measure_window`, then the tracker's tests of the step (see
    :meth:`tactiled.pipeline.contact_filter.Tracker.measure_at`): ``(ok, z, e)``, ``z`` the measured
    parameters (the point plus the step, clipped to the box), ``e`` the residual; ``ok``
    False when the frame needs a fit of its own (``chi2`` beyond ``limit``, a non-finite step,
    a logarithm moved by more than 1 and beyond ``reset_sigma`` single-frame sigmas, or the
    log force (row ``ln_f``) by more than ``max_log_force_step``).  ``const``: the rows
    ``C_R .. C_LIN_SD``."""
    chi2, dz, e = measure_window(frame, index, at, gain, jacobian, weight)
    if chi2 > limit:
        return False, dz, e
    steps = dz.tolist()
    if not all(math.isfinite(v) for v in steps):
        return False, dz, e
    is_log, sd1 = const[C_LOG].tolist(), const[C_SD1].tolist()
    for i, v in enumerate(steps):
        step = abs(v)
        if is_log[i] != 0.0 and step >= 1.0 and (
                step > reset_sigma * sd1[i] or (i == ln_f and step > max_log_force_step)):
            return False, dz, e
    point, low, high = const[C_POINT].tolist(), const[C_LOW].tolist(), const[C_HIGH].tolist()
    z = np.array([min(max(point[i] + v, low[i]), high[i]) for i, v in enumerate(steps)])
    return True, z.reshape(len(steps)), e


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
    zs = z.tolist()
    k = len(zs)
    rows = s.tolist()
    r_, moving = const[C_R].tolist(), const[C_MOVING].tolist()
    dt2, dt3 = dt * dt, dt * dt * dt
    jumped = 0
    u = [0.0] * k
    for i in range(k):
        ri = r_[i]
        x, pxx, pxv, pvv = rows[X][i], rows[PXX][i], rows[PXV][i], rows[PVV][i]
        if moving[i] != 0.0:
            acc = acc_scale * ri
            x += rows[V][i] * dt
            pxx += 2.0 * dt * pxv + dt2 * pvv + acc * dt3 / 3.0
            pxv += dt * pvv + acc * dt2 / 2.0
            pvv += acc * dt
        else:
            pxx += ri * walk
        rows[X][i], rows[PXX][i], rows[PXV][i], rows[PVV][i] = x, pxx, pxv, pvv
        u[i] = (zs[i] - x) / _sqrt(pxx + ri)
        if abs(u[i]) > reset_sigma:
            jumped |= 1 << i
    if jumped and not fitted:
        return -1
    if not jumped:
        for i in range(k):
            ri = r_[i]
            x, v, pxx, pxv, pvv, drift = (rows[X][i], rows[V][i], rows[PXX][i], rows[PXV][i],
                                          rows[PVV][i], rows[DRIFT][i])
            total = pxx + ri
            k1, k2 = pxx / total, pxv / total
            nu = zs[i] - x
            x += k1 * nu
            v += k2 * nu
            pvv -= k2 * pxv
            pxx *= 1.0 - k1
            pxv *= 1.0 - k1
            drift += drift_alpha * (u[i] - drift)
            if abs(drift) > drift_limit:
                # the parameter runs away from the model (it accelerates, or the object changes
                # slowly): widen what is uncertain so the filter catches up
                if moving[i] != 0.0:
                    window = dt / drift_alpha
                    lag = drift * _sqrt(total) / window
                    pvv = max(pvv, 16.0 * (lag * lag))
                else:
                    pxx = max(pxx, total)
                drift = 0.0
            rows[X][i], rows[V][i], rows[PXX][i], rows[PXV][i], rows[PVV][i], rows[DRIFT][i] = (
                x, v, pxx, pxv, pvv, drift)
    s[...] = rows
    return jumped


def moved_from_point(s: np.ndarray, const: np.ndarray, sigmas: float, sharpen: float) -> bool:
    """The state ``s`` has moved from the linearisation point by more than ``sigmas``
    single-frame sigmas in some parameter, or its spread has shrunk below 1/``sharpen`` of
    what it was when linearised (or there was no state then)."""
    x, pxx = s[X].tolist(), s[PXX].tolist()
    point, sd1, lin = const[C_POINT].tolist(), const[C_SD1].tolist(), const[C_LIN_SD].tolist()
    for i in range(len(x)):
        lin_sd = lin[i]
        if (abs(x[i] - point[i]) > sigmas * sd1[i] or not lin_sd == lin_sd
                or sharpen * sharpen * pxx[i] < lin_sd * lin_sd):
            return True
    return False


#: A held parameter's lag is tested at 1.5 times the moving parameters' z (3 sigmas where
#: they take 2), this squared: its variance is averaged down to ``r / n``, and a chance
#: excursion of the running mean adds about ``4 alpha / (2 - alpha) r`` (a sixteenth of one
#: frame's variance), n/16 times the variance itself after n frames: at 2 sigmas a held
#: contact's radius would be widened so (and withheld) in 5 % of its frames.
HELD_LAG_SCALE = 2.25


def held_lag(drift: float, pxx: float, r: float, lag_noise: float, alpha: float) -> float:
    """The squared mean innovation (in units of the innovations' spread) of a held parameter
    (a curvature) whose drift detector's running mean (weight ``alpha``) is ``drift``, where it
    is beyond ``HELD_LAG_SCALE`` times ``lag_noise`` (the moving parameters' threshold,
    ``LAG_Z^2 alpha / (2 - alpha)``) for the frames it has gathered; else 0.

    A held parameter's filter averages every frame since it (re)started: its variance ``pxx``
    is about ``r / n`` after ``n`` frames of variance ``r``, while the drift detector's mean has
    gathered only ``1 - (1 - alpha)^n`` of its weight (it starts at zero).  Frames measured
    with a bias that changes as the contact does (a press through linearisations at earlier
    points, a sphere fitted to an ellipse's frames) leave the average behind them by about
    that mean times the spread, an error its ``r / n`` does not hold: the caller adds the
    returned share of ``pxx + r``.  The test and the mean are corrected for the weight the
    mean has (``n = r / pxx``, at least 1: the filter's own count of frames): a 3-sigma test
    of the mean of ``n`` innovations."""
    if not (drift * drift > 0.0 and pxx > 0.0):
        return 0.0
    q = (1.0 - alpha) ** max(r / pxx, 1.0)
    if not drift * drift > HELD_LAG_SCALE * lag_noise * (1.0 - q * q):
        return 0.0
    m = drift / (1.0 - q)
    return m * m


def _delta_cov(terms: list[list[tuple[int, float]]], ka: int, kb: int, sd: list[float],
               corr: list[list[float]], sys: list[list[float]], has_sys: bool) -> float:
    """The covariance of values ``ka`` and ``kb`` from their gradient terms (``terms[key]``:
    up to two ``(parameter, derivative)``), in the order :meth:`Tracker.estimate`'s
    plain-float version summed them."""
    total = 0.0
    for a, ga in terms[ka]:
        gsa = ga * sd[a]
        for b, gb in terms[kb]:
            total += gsa * (gb * sd[b]) * corr[a][b]
            if has_sys:
                total += ga * gb * sys[a][b]
    return total


#: The models :func:`estimate_numbers` knows, by the code it takes.
MODEL_CODES = {"cylinder": 0, "sphere": 1, "general": 2}
_RAD_TO_DEG = 180.0 / math.pi


def estimate_numbers(model: int, s: np.ndarray, const: np.ndarray, dt: float, excess: float,
                     corr: np.ndarray, sys: np.ndarray, has_sys: bool, lag_noise: float,
                     drift_alpha: float) -> tuple[np.ndarray, np.ndarray, float, int]:
    """The numbers of a tracker's estimate (:meth:`~tactiled.pipeline.contact_filter.Tracker.estimate`):
    the state ``s`` predicted ``dt`` s ahead (0: as it is), each value of
    ``tactiled.fit.params.VALUE_KEYS`` (:func:`~tactiled.fit.params.report_terms` of
    ``model``, a :data:`MODEL_CODES` code; the orientation as psi in radians, for the caller
    to wrap) and its variance by the delta method term by term: the state's variances (each
    moving parameter's lag added where its drift detector's mean, squared, is beyond
    ``lag_noise``, and each held one's: :func:`held_lag`; times ``excess``) with the single
    frame's correlations ``corr``, plus the
    systematic covariance ``sys`` when ``has_sys``; the covariance of r1 and the force.
    Returns ``(values, variances, cov_r1_force, absent)``, ``absent`` a bit mask of the
    values the model does not have (bit i: key i; their value and variance NaN)."""
    rows = s.tolist()
    k = len(rows[X])
    r_, moving = const[C_R].tolist(), const[C_MOVING].tolist()
    if dt != 0.0:
        x = [rows[X][i] + rows[V][i] * dt for i in range(k)]
        pxx = [rows[PXX][i] + dt * (2.0 * rows[PXV][i] + dt * rows[PVV][i]) for i in range(k)]
    else:
        x, pxx = list(rows[X]), list(rows[PXX])
    for i in range(k):
        d = rows[DRIFT][i]
        if moving[i] != 0.0:
            if d * d > lag_noise:
                pxx[i] = pxx[i] + d * d * (pxx[i] + r_[i])
        else:
            pxx[i] = pxx[i] + held_lag(d, pxx[i], r_[i], lag_noise, drift_alpha) * (pxx[i] + r_[i])
    sd = [_sqrt(q) if q >= 0.0 else math.nan for q in (p * excess for p in pxx)]
    values = [math.nan] * 6
    # each value's gradient: up to two (parameter, derivative) terms; none: absent
    terms: list[list[tuple[int, float]]] = [[] for _ in range(6)]
    absent = 0
    # every model ends with ln_f, x0, y0
    f = _exp(x[k - 3])
    values[0], values[1], values[2] = x[k - 2], x[k - 1], f
    terms[0].append((k - 2, 1.0))
    terms[1].append((k - 1, 1.0))
    terms[2].append((k - 3, f))
    if model == 0:  # cylinder: ln_r, psi, ln_f, x0, y0
        r = _exp(x[0])
        values[3], values[5] = r, x[1]
        terms[3].append((0, r))
        terms[5].append((1, _RAD_TO_DEG))
        absent = 1 << 4
    elif model == 1:  # sphere: ln_r, ln_f, x0, y0
        r = _exp(x[0])
        values[3], values[4] = r, r
        terms[3].append((0, r))
        terms[4].append((0, r))
        absent = 1 << 5
    else:  # general: ln_ra, beta, psi, ln_f, x0, y0
        ra, beta = _exp(x[0]), x[1]
        b2 = beta * beta
        psi = x[2]
        if b2 <= 1.0:  # r1 = R_a, r2 = R_a / beta^2 (none for beta = 0)
            values[3] = ra
            terms[3].append((0, ra))
            if b2 > 0.0:
                r2 = ra / b2
                values[4] = r2
                terms[4] += [(0, r2), (1, -2.0 * r2 / beta)]
            else:
                absent = 1 << 4
        else:  # axes swapped: the R2 axis is perpendicular to the fitted psi
            r1 = ra / b2
            values[3], values[4] = r1, ra
            terms[3] += [(0, r1), (1, -2.0 * r1 / beta)]
            terms[4].append((0, ra))
            psi += 0.5 * math.pi
        values[5] = psi
        terms[5].append((2, _RAD_TO_DEG))
    cr, sy = corr.tolist(), sys.tolist()
    var = [_delta_cov(terms, key, key, sd, cr, sy, has_sys) if terms[key] else math.nan
           for key in range(6)]
    cov_rf = _delta_cov(terms, 3, 2, sd, cr, sy, has_sys) if terms[3] else math.nan
    return np.array(values), np.array(var), cov_rf, absent


# -- a tracked frame in one call ------------------------------------------------------------------

#: :meth:`TrackStep.advance`'s answers besides 0 (tracked: the filters updated) and a jump's
#: bit mask (> 0, bit i: parameter i jumped; the filters only predicted, for the caller to
#: restart what jumped)
STEP_UNMEASURED = -1  # (step only) the frame cannot be measured: it needs a fit; nothing changed
STEP_REFIT = -2  # measured, but a parameter jumped on a frame that is no fit's: it needs a fit
STEP_RESTART = -3  # measured after a gap in the clock (or before the filter started): restart at z
#: :class:`TrackStep`'s scalar constants, in the order it takes them
TRACK_CONSTANTS = ("limit", "ln_f", "reset_sigma", "max_log_force_step", "beta_i", "beta_sign",
                   "memory_s", "hold_s", "drift_alpha", "drift_limit", "lag_weight",
                   "lag_significant", "max_gap_s", "model", "has_sys", "lag_noise")


def lag_variance(lag: np.ndarray, weight: float, significant: float) -> np.ndarray:
    """Per parameter, the variance a filter lags a contact that accelerates by: ``lag``'s
    running mean of the innovations (row 0, weight ``weight``) squared, where it is beyond
    ``significant`` of the spread the noise gives that mean (row 1's predicted variance
    times ``w / (2 - w)``); else 0 (:meth:`~tactiled.pipeline.contact_filter.Tracker.estimate`)."""
    m, spread = lag[0], lag[1]
    noise = spread * weight / (2.0 - weight)
    return np.where(m * m > significant * significant * noise, m * m, 0.0)


class TrackStep:
    """One tracked contact's frame in one call (:meth:`step`): measured through its
    linearisation (:func:`measure_point`, with the general model's floor on ``|beta|``),
    the residual buffered, the filters stepped (:func:`filter_frame`) and the lag's running
    means updated, the rate's variance widened by the lag.  Held arrays, written in place:
    ``s`` (6, k, the filters), ``lag`` (2, k: the innovations' running mean, their predicted
    variance), ``z`` (k: the last measurement), ``ebuf`` (n: the residuals not yet folded);
    read: ``c`` (8, k) and the linearisation (``index``, ``at``, ``gain``, ``jacobian``,
    ``weight``); for the estimate (:meth:`estimate`), the single frame's correlations
    ``corr`` and the systematic covariance ``sys`` (k, k), and ``lag_key`` (k: the value of
    ``VALUE_KEYS`` each parameter's lag widens, -1 none).  ``constants``:
    :data:`TRACK_CONSTANTS`' values (``beta_i`` -1: no floor; ``model`` a
    :data:`MODEL_CODES` code).  The core's ``TrackStep`` (core/track_step.cpp) is this, bit
    for bit but for :func:`measure_window`'s sums (tests/native/test_track_step.py)."""

    def __init__(self, s: np.ndarray, lag: np.ndarray, c: np.ndarray, z: np.ndarray,
                 ebuf: np.ndarray, index: np.ndarray, at: np.ndarray, gain: np.ndarray,
                 jacobian: np.ndarray, weight: np.ndarray, corr: np.ndarray, sys: np.ndarray,
                 lag_key: np.ndarray, constants: tuple[float, ...]) -> None:
        self.s, self.lag, self.c, self.z, self.ebuf = s, lag, c, z, ebuf
        self.index, self.at, self.gain, self.jacobian, self.weight = (
            index, at, gain, jacobian, weight)
        self.corr, self.sys, self.lag_key = corr, sys, [int(v) for v in lag_key]
        (self.limit, ln_f, self.reset_sigma, self.max_log_force_step, beta_i, self.beta_sign,
         self.memory_s, self.hold_s, self.drift_alpha, self.drift_limit, self.lag_weight,
         self.lag_significant, self.max_gap_s, model, has_sys,
         self.lag_noise) = (float(v) for v in constants)
        self.ln_f, self.beta_i, self.model, self.has_sys = (
            int(ln_f), int(beta_i), int(model), has_sys != 0.0)
        self.e = np.zeros(index.size)

    def measure(self, frame: np.ndarray, at: np.ndarray) -> bool:
        """``frame`` (flat strain) measured through the linearisation less ``at`` (its
        strains on the window, and what else the caller takes out): True with the
        measurement in ``z`` and its residual kept for :meth:`advance`; False when the frame
        needs a fit (:func:`measure_point`).  Changes nothing else."""
        ok, z, e = measure_point(frame, self.index, at, self.gain, self.jacobian, self.weight,
                                 self.c, self.limit, self.ln_f, self.reset_sigma,
                                 self.max_log_force_step)
        if not ok:
            return False
        if self.beta_i >= 0:  # (the strain has beta^2 only: an elongated contact keeps its axes)
            z[self.beta_i] = self.beta_sign * max(abs(float(z[self.beta_i])), 1.0)
        self.z[:] = z
        self.e[:] = e
        return True

    def advance(self, dt: float, fitted: bool = False) -> int:
        """The filters stepped with ``z``, ``dt`` s after their last frame (NaN: not started):
        unless ``fitted`` (``z`` is then the fit's own point, set by the caller), the measured
        residual is buffered first.  Returns 0 (updated), :data:`STEP_RESTART`,
        :data:`STEP_REFIT` or a jump's bit mask (see :func:`filter_frame`)."""
        if not fitted:
            self.ebuf += self.e
        if not 0.0 < dt < self.max_gap_s:
            return STEP_RESTART
        s, c, z = self.s, self.c, self.z
        moving = c[C_MOVING] != 0.0
        # this frame's innovation against the constant-velocity prediction and its predicted
        # variance (the prediction's plus one frame's), for the moving parameters
        nu = np.where(moving, z - (s[X] + s[V] * dt), 0.0)
        spread = np.where(moving, s[PXX] + 2.0 * dt * s[PXV] + dt * dt * s[PVV] + c[C_R], 0.0)
        # white acceleration of density 36 R dt / tau^4 for a moving parameter: an alpha-beta
        # filter with a window of about tau s (R: one frame's variance, dt: the frame period);
        # a random walk with a memory of hold_s for a curvature
        jumped = filter_frame(z, s, c, dt, 36.0 * dt / self.memory_s ** 4,
                              dt * dt / (self.hold_s * self.hold_s), fitted, self.reset_sigma,
                              self.drift_alpha, self.drift_limit)
        if jumped < 0:
            return STEP_REFIT
        if jumped:
            return jumped
        lag = self.lag
        lag += self.lag_weight * (np.stack((nu, spread)) - lag)
        # a lag goes into the rate's variance (over the filter's memory: it catches up), not
        # the value's, which the reset test reads; the estimate publishes it
        extra = lag_variance(lag, self.lag_weight, self.lag_significant)
        if extra.any():
            s[PVV] += extra / (self.memory_s * self.memory_s)
        return 0

    def step(self, frame: np.ndarray, dt: float) -> int:
        """:meth:`measure` (through the linearisation's own ``at``) and :meth:`advance`;
        :data:`STEP_UNMEASURED` when the frame cannot be measured."""
        if not self.measure(frame, self.at):
            return STEP_UNMEASURED
        return self.advance(dt)

    def estimate(self, dt: float, excess: float) -> tuple[list[float], list[float], float, int]:
        """The estimate's numbers (:func:`estimate_numbers` of the held state, ``dt`` s ahead,
        its variances times ``excess``) with each moving value's lag (:func:`lag_variance`)
        added to its variance, in its unit (the force's: times the force squared; the
        angle's: degrees).  ``(values, variances, cov_r1_force, absent)``, lists of 6."""
        values, var, cov_rf, absent = estimate_numbers(
            self.model, self.s, self.c, dt, excess, self.corr, self.sys, self.has_sys,
            self.lag_noise, self.drift_alpha)
        values, var = values.tolist(), var.tolist()
        extra = lag_variance(self.lag, self.lag_weight, self.lag_significant).tolist()
        for i, key in enumerate(self.lag_key):
            if extra[i] > 0.0 and key >= 0:
                unit = values[2] if key == 2 else _RAD_TO_DEG if key == 5 else 1.0
                var[key] += extra[i] * unit * unit
        return values, var, cov_rf, absent


#: The Python bodies the core is held to (tests/native/test_tracker_core.py), whichever runs.
REFERENCE = native.bind(globals(), ("measure_window", "largest_excess", "fold_residuals",
                                    "linearization_constants", "measure_point", "filter_frame",
                                    "moved_from_point", "estimate_numbers", "TrackStep"))

"""The rubber's hysteresis: learnt from the trail a contact leaves, and taken out of every frame.

Rubber springs back a little late.  A tactel unloaded from a strain ``P`` does not read zero at
once but a residual that decays over a fraction of a second.  Left in the frames, that residual
is a phantom pressure: the trail behind a rolling contact (which the fitter then explains with
the general model, or a larger contact) and a light "contact" after each lift-off.
"""

# **The model.**  Each tactel keeps a peak-hold ``P`` of its compressive strain ``s+ = max(s, 0)``
# that decays with a time constant ``tau``, ``P = max(s+, P exp(-dt / tau))``, and reads the
# residual ``R = f (P - s+)`` on top of ``s``: nothing while loading or holding, after a release
# from ``s_r`` the residual ``f s_r exp(-t / tau)``.  It is the simplest memory that has the two
# facts every elastomer shows (the residual scales with the load released and fades with time),
# with two constants, the fraction ``f`` and ``tau`` (s).
#
# **Learning them** (:class:`HysteresisLearner`) needs no calibration press: the daemon learns
# them in use, from contacts it tracks.  Where a fit's model explains a frame, the tactels
# outside the fit's window read what the model does not explain (``zeroed - predicted``): noise,
# drift, and, behind a contact that moved or eased, the residual.  For each ``tau`` of a grid
# (0.1-5 s), a peak-hold ``P_k`` of the *predicted* compressive strain (noise-free, and blind to
# a held contact's own misfit) gives the regressor ``q_k = P_k - max(predicted, 0)`` (what the
# tactel carried once, less what it carries now).  A
# least-squares fit of the unexplained strain on ``q_k``, beside the predicted load itself (so a
# model that is a few per cent off in scale is not read as hysteresis) and a constant (common
# drift), gives ``f_k`` and its significance ``z_k`` in noise sigmas; the ``tau`` whose ``q_k``
# explains most, refined between grid points, is the estimate.  Sums decay with each step (a
# memory of ``1 / (1 - FORGET)`` steps), so the estimate follows a finger that warms or ages.
#
# **Taking it out** (:class:`HysteresisCompensator`) is switched on only when the estimate is
# significant (``z >= Z_ON`` after ``MIN_STEPS`` steps), its ``tau`` lies inside the grid (at an edge it is a slope of
# something else: drift, a model that misfits) and its fraction is plausible; it goes off again
# below ``Z_OFF``.  A finger without hysteresis stays as it was.  The compensator inverts the
# model frame by frame: where a tactel reads below its peak-hold, ``s = (z - f P) / (1 - f)``,
# and it subtracts ``R = f (P - s)``.  Its peak-hold forgets the noise: it holds a strain less
# ``NOISE_MARGIN`` noise sigmas, so a held contact's noise does not ratchet it up and read as a
# release.
#
# On the simulated finger (``f`` = 0.05, ``tau`` = 0.5 s) the learner finds ``tau`` = 0.52-0.58 s
# and ``f`` = 0.043-0.045 on the moving scene, and compensates from its third second on
# (docs/concepts/calibration.md has the figures, and those on other fingers).
#
# Numpy, a compiled kernel for the learner's step (:func:`tactiled.calibration.fused.learn_hysteresis`)
# and no I/O.  Strains are on the zeroed scale (strain, no unit); times in seconds.

from __future__ import annotations

import math

import numpy as np

from tactiled.calibration.fused import learn_hysteresis

#: The time constants (s) the learner tries: log-spaced, 0.1-5 s.  An estimate at either end
#: is no estimate (a model that misfits on a finger the fit does not match, drift, leans
#: towards the slowest).
TAUS_S = np.geomspace(0.1, 5.0, 10)
#: A tactel's peak-hold counts once it exceeds this many noise sigmas (below, a residual of a
#: few per cent is a fraction of a sigma).
MIN_PEAK_SIGMAS = 5.0
#: The compensator's peak-hold holds the strain less this many noise sigmas (above).
NOISE_MARGIN = 2.0
#: Each learning step multiplies the sums by this: a memory of 1000 steps (~12 s of contact).
FORGET = 0.999
#: The estimate is solved for every this many steps (it moves over hundreds).
SOLVE_EVERY = 10
#: The compensator switches on at this significance (noise sigmas) and off below Z_OFF.
Z_ON = 12.0
Z_OFF = 6.0
#: ... after this many steps (~2.5 s of tracked contact: a first estimate swings) ...
MIN_STEPS = 200
#: ... and only for a fraction in this range.
FRACTION_RANGE = (0.01, 0.5)


class HysteresisCompensator:
    """Takes the residual ``f (P - s+)`` (module docstring) out of zeroed strain frames.

    ``fraction`` 0 (the default) does nothing.  :meth:`residual` is called once per frame, in
    time order, with the frame before compensation.
    """

    def __init__(self, shape: tuple[int, int]) -> None:
        self.shape = tuple(shape)
        self.fraction = 0.0
        self.tau_s = 1.0
        self._peak = np.zeros(self.shape)
        self._active = False  # some peak-hold above MIN_PEAK_SIGMAS

    def set(self, fraction: float, tau_s: float) -> None:
        """Compensate with these constants from the next frame (``fraction`` 0: off)."""
        if not (math.isfinite(fraction) and 0.0 <= fraction < 1.0):
            raise ValueError(f"fraction must lie in [0, 1), got {fraction!r}")
        if not (math.isfinite(tau_s) and tau_s > 0.0):
            raise ValueError(f"tau_s must be a positive time in s, got {tau_s!r}")
        if fraction == 0.0:
            self.reset()
        self.fraction, self.tau_s = float(fraction), float(tau_s)

    def reset(self) -> None:
        """Forget the peaks (after a tare: the baseline the strains were measured from moved)."""
        self._peak.fill(0.0)
        self._active = False

    def residual(self, zeroed: np.ndarray, dt: float, sigma: float) -> np.ndarray | None:
        """The residual to subtract from ``zeroed`` (a frame ``dt`` s after the last; noise
        sigma ``sigma``), or None where there is nothing to subtract."""
        f = self.fraction
        if f == 0.0:
            return None
        floor = MIN_PEAK_SIGMAS * sigma
        if not self._active and float(zeroed.max()) < floor:
            return None  # nothing was loaded, nothing is: the common case costs one max
        peak = self._peak
        if dt > 0.0:
            peak *= math.exp(-dt / self.tau_s)
        # Below its peak a tactel reads z = s + f (P - s), so it carries f (P - s) =
        # f (P - z) / (1 - f), at most f P (s >= 0).  Its peak then stays (s <= P).
        held = (zeroed < peak) & (peak > floor)
        taken = np.minimum((peak - zeroed) * (f / (1.0 - f)), f * peak)
        np.maximum(peak, zeroed - NOISE_MARGIN * sigma, out=peak)
        self._active = bool(float(peak.max()) > floor)
        return np.where(held, taken, 0.0)


class HysteresisLearner:
    """Learns ``(f, tau)`` from the unexplained strain around tracked contacts (module
    docstring): :meth:`learn` at the zeroer's drift steps; :attr:`estimate` is the current
    answer, :meth:`usable` whether to compensate with it."""

    def __init__(self, shape: tuple[int, int]) -> None:
        self.shape = tuple(shape)
        n = int(np.prod(self.shape))
        self._peaks = np.zeros((TAUS_S.size, n))  # of the predicted compressive strain
        self._t: float | None = None
        self._normal = np.zeros((TAUS_S.size, 3, 3))
        self._moment = np.zeros((TAUS_S.size, 3))
        self.steps = 0
        #: (fraction, tau_s, z): the best tau's fraction and significance in noise sigmas, or
        #: None before any step with a trail
        self.estimate: tuple[float, float, float] | None = None

    def reset(self) -> None:
        """Forget the peaks (the baseline moved under them); what was learnt stays."""
        self._peaks.fill(0.0)
        self._t = None

    def learn(self, unexplained: np.ndarray, predicted: np.ndarray, outside: np.ndarray,
              t: float, sigma: float, frames: int = 1) -> None:
        """One step at time ``t`` (s): ``predicted`` is the model's strain on the whole array,
        ``unexplained`` the frame (before compensation) less ``predicted``, learnt from on the
        ``outside`` tactels (boolean; noise sigma ``sigma`` of one frame).  ``frames``: the
        step is the mean of that many frames (noise ``sigma / sqrt(frames)``), weighed as that
        many steps of one frame (inverse variance) and counted so."""
        # (the peak-holds and the normal equations' sums in one compiled pass)
        dt = 0.0 if self._t is None else t - self._t
        self._t = t
        if frames > 1:
            normal, moment = self._normal * FORGET, self._moment * FORGET
        if not learn_hysteresis(self._peaks, TAUS_S, dt,
                                np.ascontiguousarray(predicted, dtype=np.float64).reshape(-1),
                                np.ascontiguousarray(unexplained, dtype=np.float64).reshape(-1),
                                np.ascontiguousarray(outside, dtype=bool).reshape(-1),
                                MIN_PEAK_SIGMAS * sigma, self._normal, self._moment, FORGET):
            return
        if frames > 1:  # the step's sums, added frames - 1 times more
            self._normal += (frames - 1) * (self._normal - normal)
            self._moment += (frames - 1) * (self._moment - moment)
        before, self.steps = self.steps, self.steps + max(int(frames), 1)
        if self.steps // SOLVE_EVERY != before // SOLVE_EVERY or self.estimate is None:
            self.estimate = self._solve(sigma)

    def _solve(self, sigma: float) -> tuple[float, float, float] | None:
        normal = self._normal + np.eye(3) * 1e-18  # a trail seen on one tactel only: finite
        try:
            inverse = np.linalg.inv(normal)
        except np.linalg.LinAlgError:
            return None
        beta = np.einsum("kij,kj->ki", inverse, self._moment)
        fraction = beta[:, 0]
        z = fraction / (sigma * np.sqrt(np.maximum(inverse[:, 0, 0], 1e-300)))
        k = int(np.argmax(z))
        tau = float(TAUS_S[k])
        if 0 < k < TAUS_S.size - 1 and z[k] > 0:
            # refine between grid points: a parabola through z^2 (the strain explained) in log tau
            a, b, c = (float(v) ** 2 for v in z[k - 1:k + 2])
            curve = a - 2.0 * b + c
            if curve < 0.0:
                step = 0.5 * (a - c) / curve
                ratio = float(TAUS_S[1] / TAUS_S[0])
                tau = float(TAUS_S[k]) * ratio ** max(-0.5, min(0.5, step))
        return float(fraction[k]), tau, float(z[k])

    def usable(self, on: bool) -> tuple[float, float] | None:
        """``(f, tau)`` to compensate with, or None: significant (``Z_ON``, or ``Z_OFF`` when
        the compensator is ``on`` already) after ``MIN_STEPS`` steps, ``tau`` inside the grid,
        ``f`` plausible."""
        if self.estimate is None or self.steps < MIN_STEPS:
            return None
        f, tau, z = self.estimate
        interior = TAUS_S[0] < tau < TAUS_S[-1]
        if z >= (Z_OFF if on else Z_ON) and interior and FRACTION_RANGE[0] <= f <= FRACTION_RANGE[1]:
            return f, tau
        return None


class ReleaseSteps:
    """The frames after a release as steps of :class:`HysteresisLearner`: nothing touches, so
    what a frame holds beyond the baseline the contact was measured from is the rubber's
    recovery (with noise, and drift: the learner's constant).  A contact held still leaves no
    trail around it to learn from while it is held; its release shows the recovery whole, on
    every tactel it loaded.  The learner's peak-holds of the load the contact's model predicted,
    decayed since, are the steps' regressors.

    :meth:`frame` takes each frame with no contact, in order (its zeroed strain, before the
    baseline's step; the compensator off), from ``start`` s on; each ``step_s`` of frames is
    one step, their mean (ten frames at 1 kHz: a third of one frame's noise), weighed as
    that many frames (``HysteresisLearner.learn``).  The hold-off's baseline moves towards
    each frame (``weight`` of it: ``Zeroer``'s faster release constant) and so takes part of
    the recovery in: the steps add that movement back."""

    def __init__(self, shape: tuple[int, int], start: float, step_s: float) -> None:
        self.start, self.step_s = float(start), float(step_s)
        self.moved = np.zeros(shape)  # the baseline's movement since the release (strain)
        self._sum = np.zeros(shape)
        self._frames = 0
        self._opened: float | None = None  # time (s) of the open step's first frame

    def frame(self, zeroed: np.ndarray, t: float, weight: float) -> tuple[np.ndarray, int] | None:
        """A frame with no contact at ``t`` s (``zeroed``); the baseline then moves by
        ``weight`` of it.  Returns the step this frame finishes (its mean strain beyond the
        contact's baseline, and its frames), else None."""
        step = None
        if t >= self.start:
            self._sum += zeroed
            self._sum += self.moved
            self._frames += 1
            if self._opened is None:
                self._opened = t
            if t - self._opened >= self.step_s - 1e-9:
                step = (self._sum / self._frames, self._frames)
                self._sum = np.zeros_like(self._sum)
                self._frames, self._opened = 0, None
        self.moved += weight * zeroed
        return step

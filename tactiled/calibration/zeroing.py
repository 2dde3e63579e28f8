"""Zeroing: per-tactel baseline tracking that follows drift but never erases a held contact.

A high-pass filter (subtract a running mean of everything) is the usual drift compensation, and
it fails exactly where a fingertip matters: a grasp held for minutes decays into the baseline and
vanishes.  Here the baseline moves on a contact's tactels only while no contact is detected,
drift is followed around a held contact through its model, and the rubber's hysteresis is taken
out first.  Times are the caller's timestamps in seconds; strains are on the zeroed scale.
"""

# How the baseline moves:
#

# * **idle** (no contact): ``baseline += a * (x - baseline)``, ``a = 1 - exp(-dt / tau_drift)``
#   with ``tau_drift`` = 5 s: slow enough to average noise (an EMA of time constant tau over frames
#   at rate r averages about ``2 tau r`` frames), fast enough for thermal drift;
# * **in contact**: frozen, so the contact's strain is kept however long it is held, except
#   that drift is followed around a contact the caller can predict (below);
# * **after a release**, for ``holdoff`` s (default 1.5 s = 5 ``tau_release``): the faster
#   ``tau_release`` = 0.3 s, so the rubber's hysteresis residual (and drift accumulated while frozen)
#   is absorbed within about a second instead of lingering as a phantom pressure.
#
# ``dt`` is the difference of the caller's timestamps (seconds; device time preferred), so the
# behaviour does not depend on the frame rate; a frame whose ``dt <= 0`` (duplicate or backwards
# clock) does not move the baseline.  The zeroed output of a frame is computed against the baseline
# *before* that frame updates it.
#
# The first frame starts the baseline (an implicit tare: start with the finger unloaded), and
# :meth:`Zeroer.tare` restarts it on demand.  A baseline taken from one frame carries that frame's
# noise, which would double the noise variance of every zeroed frame and multiply the false-contact
# rate; so after a (re)start the baseline is the running *mean* of the frames seen so far until the
# EMA weight catches up (update weight ``max(1/n, a)`` after ``n`` frames: the bias-corrected EMA),
# and for ``settle`` s (default 0.25 s) no contact is reported while the mean forms.  By then the
# baseline's noise is ``sigma/sqrt(n)`` (``n`` = 25 frames at 100 Hz: +2 % on the zeroed noise).
#
# NaN/inf entries are output as 0 and do not touch their tactel's baseline;
# :attr:`Zeroer.nonfinite_frames` counts such frames.
#
# **One implausible frame cannot drag the baseline.**  A no-contact frame on which most tactels
# (more than half) sit beyond ``MAX_STEP_SIGMAS`` (10) noise sigmas of the detector's ``sigma``
# is no physical state of an unloaded finger: a glitch (an ADC returning zero counts for a few
# frames, which the detector rightly does not call a contact).  Outside the running-mean
# start-up, such a frame's pull on each tactel's baseline is clipped to 10 sigma, so it moves
# the baseline by at most ``weight x 10 sigma`` instead of ``weight x`` its full deviation
# (unclipped, 7-39 sigma per glitch frame with the 0.3 s release constant, a pedestal every
# later contact would carry).  Ordinary frames are not clipped: a release residual is a local bump
# and drift is slow, so both are followed exactly.  A genuine step of the whole
# unloaded frame by more than 10 sigma is absorbed at 10 sigma per time constant; ``tare``
# takes it at once.
#
# **Drift is followed around a held contact.**  Frozen whole, the baseline would let drift pile
# up under a long hold: on the simulated finger (drift up to 4e-5 strain/s, a tenth of a noise
# sigma a second) a 1 N grasp held for 40 s would read 7-8 % heavy by its end, and after the
# release the drift alone, 1-3 sigma on every tactel, would keep the matched filter above its exit
# threshold: the finger would never let go.  Which part of a loaded frame is drift, the zeroer
# cannot tell alone (the rubber
# spreads a 1 N contact over the whole array, to -5 sigma eight millimetres off); the contact's
# model can.  :meth:`Zeroer.follow_drift` takes a frame with the strain a fit's model predicts on
# the whole array and the tactels the fit reads (its window).  Where the prediction explains the
# window within noise (a contact that has not moved from it), at most every ``DRIFT_STEP_S``:
#
# * outside the window, each tactel's baseline follows what the model does not explain
#   (``zeroed - predicted``, clipped to ``DRIFT_CLIP_SIGMAS``) with ``tau_drift``, as when idle:
#   there it is drift and noise, and no fit reads those tactels;
# * inside it, the baseline takes the outside tactels' mean pull, the drift common to the finger
#   (temperature moves every tactel the same way, if not by the same amount), never its own
#   tactels' values, which carry the contact.
#
# The daemon calls it with the tracker's linearisation (``tactiled.pipeline.sensor``): for each
# frame the tracker measures, and, untested (``fitted``), for the frame a fit was of, whose fit
# is the best the model explains it by (on a finger that departs from its model no prediction
# explains a frame within noise, and its drift must be followed all the same).  What it
# leaves is each window tactel's own drift against the mean (the simulator's tactels drift by
# 0.5-1 times a common wave: about a sixth of the drift).
#
# **The rubber's hysteresis is taken out before zeroing** (:mod:`tactiled.calibration.hysteresis`):
# at the drift steps a learner estimates the residual a release leaves (its fraction and time
# constant) from the tactels outside the window, and once that estimate is significant a
# compensator subtracts the residual from every frame, so the baseline, the detector and the fit
# all see the frame without it.  ``hysteresis=False`` (the sensor setting) leaves frames as read.

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from tactiled.calibration.detection import ContactDetector
from tactiled.calibration.fused import drift_error, follow_baseline, pull_baseline
from tactiled.calibration.hysteresis import HysteresisCompensator, HysteresisLearner, ReleaseSteps

DEFAULT_TAU_DRIFT = 5.0  # s
DEFAULT_TAU_RELEASE = 0.3  # s
DEFAULT_HOLDOFF = 1.5  # s
DEFAULT_SETTLE = 0.25  # s
MAX_STEP_SIGMAS = 10.0  # a frame's pull on the baseline is clipped to this many noise sigmas
#: Around a held contact drift is followed at most once per this much device time (s): drift
#: is a process of minutes.
DRIFT_STEP_S = 0.01
#: ... and one step's time is at most this (s): a step after a long gap is not the gap's worth
#: of drift taken from one frame (its weight would approach 1 and put that frame's noise in).
MAX_DRIFT_STEP_S = 0.1
#: A tactel's pull on its baseline around a contact is clipped to this many noise sigmas.
DRIFT_CLIP_SIGMAS = 3.0
#: The prediction must explain the fit window's tactels to this mean squared difference (in
#: noise variances).  Noise alone gives 1 (4 on 16 tactels: never in practice); a 1 N cylinder
#: moved 0.2 mm from the prediction adds ~2 (2 N: 0.1 mm adds 1.4), its prediction outside the
#: window then off by up to 2 sigma, of which one step takes a 500th.
DRIFT_EXPLAINED = 4.0
#: After a contact ends, the hysteresis learner takes the frames from this long on (s): the
#: detector lets go of a contact eased off below its exit threshold, and the last of that load
#: (a tenth of a newton and less, on the paper's finger) is gone within tens of milliseconds
#: of a hand's release; learnt as recovery it would read as hysteresis on a rubber without.
RELEASE_SKIP_S = 0.05


class Zeroer:
    """Turns linearised strain (before zeroing) into zeroed strain, frame by frame.

    ``detector`` decides contact on each zeroed frame (default: a :class:`ContactDetector` for
    the default sensor); :meth:`update` may instead be told the contact state.  Time constants
    are in seconds.  ``hysteresis``: learn the rubber's hysteresis at the drift steps and take
    it out of the frames (:mod:`tactiled.calibration.hysteresis`).
    """

    def __init__(
        self,
        shape: tuple[int, int] = (8, 8),
        *,
        tau_drift: float = DEFAULT_TAU_DRIFT,
        tau_release: float = DEFAULT_TAU_RELEASE,
        holdoff: float = DEFAULT_HOLDOFF,
        settle: float = DEFAULT_SETTLE,
        detector: ContactDetector | None = None,
        hysteresis: bool = True,
    ) -> None:
        for name, value in (("tau_drift", tau_drift), ("tau_release", tau_release)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive time in s, got {value!r}")
        for name, value in (("holdoff", holdoff), ("settle", settle)):
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a non-negative time in s, got {value!r}")
        self.shape = tuple(shape)
        self.tau_drift = float(tau_drift)
        self.tau_release = float(tau_release)
        self.holdoff = float(holdoff)
        self.settle = float(settle)
        self.detector = ContactDetector() if detector is None else detector
        if self.detector.shape != self.shape:
            raise ValueError(f"detector shape {self.detector.shape} != zeroer shape {self.shape}")
        self.baseline: np.ndarray | None = None
        #: the variance (strain^2) of each tactel's baseline from the noise of the frames it
        #: averaged: every zeroed frame of a contact carries this same error, so averaging
        #: frames does not remove it (the tracker counts it as systematic)
        self.baseline_var = 0.0
        self.in_contact = False
        self.nonfinite_frames = 0
        self._last_t: float | None = None
        self._release_until = -math.inf
        self._pending_tare = False
        self._frames = 0  # since the last (re)start of the baseline
        self._settle_until = -math.inf
        self._drift_t: float | None = None  # device time drift was last followed in contact
        #: the rubber's hysteresis, learnt at the drift steps and taken out of every frame
        #: (``hysteresis``: whether to; :meth:`set_hysteresis`)
        self.learns_hysteresis = bool(hysteresis)
        self.hysteresis = HysteresisCompensator(self.shape)
        self.hysteresis_learner = HysteresisLearner(self.shape)
        self._residual: np.ndarray | None = None  # what the compensator took from the last frame
        #: the hold-off's frames after the last release, as the learner's steps
        #: (:meth:`begin_release`; None: none kept)
        self._release: ReleaseSteps | None = None
        self._release_learnt = False  # ... of which the learner has taken a step

    @property
    def settling(self) -> bool:
        """True while the baseline is still forming after a (re)start (no contact reported)."""
        return self._last_t is not None and self._last_t < self._settle_until

    def update(self, strain: ArrayLike, t: float, contact: bool | None = None) -> np.ndarray:
        """Zero one ``(rows, cols)`` strain frame taken at time ``t`` (s); returns a new array.

        ``contact``: the caller's decision, or ``None`` to let :attr:`detector` decide on the
        zeroed frame.  Afterwards :attr:`in_contact` holds the decision.
        """
        x = np.asarray(strain, dtype=np.float64)
        if x.shape != self.shape:
            raise ValueError(f"strain frame must have shape {self.shape}, got {x.shape}")
        bad = None
        # argmax/argmin return a NaN if there is one, and never warn (a sum would, on inf - inf).
        flat = x.reshape(-1)
        if not (math.isfinite(flat[flat.argmax()]) and math.isfinite(flat[flat.argmin()])):
            bad = ~np.isfinite(x)
            self.nonfinite_frames += 1
        if self.baseline is None or self._pending_tare:
            self._tare_to(x, bad)
            self._settle_until = t + self.settle
        if bad is not None:
            x = np.where(bad, self.baseline, x)  # output 0 there, baseline untouched
        z = x - self.baseline
        if not z.flags.c_contiguous:  # (the baseline's step below reads and clips it flat)
            z = np.ascontiguousarray(z)
        self._frames += 1
        settling = t < self._settle_until
        dt = t - self._last_t if self._last_t is not None else 0.0
        self._last_t = t
        sigma = self.detector.sigma
        self._residual = self.hysteresis.residual(z, dt, sigma)
        if self._residual is not None:
            z -= self._residual  # (the baseline below then follows the compensated frame)
        if contact is None:
            # While the baseline forms, its own noise would raise false contacts: learn only.
            contact = False if settling else self.detector.update(z)
        self._settle_frame(z, t, dt, contact)
        return z

    def _settle_frame(self, z: np.ndarray, t: float, dt: float, contact: bool) -> None:
        """After the zeroed frame ``z`` (time ``t``, ``dt`` s after the last) was decided:
        the contact state, and the baseline's step towards an untouched frame."""
        if contact:
            if not self.in_contact:
                self._learn_release()
            self.in_contact = True
            return  # frozen: a held contact is never absorbed
        if self.in_contact:
            self.in_contact = False
            self._release_until = t + self.holdoff
            self._drift_t = None
            self.begin_release(t)
        if dt > 0.0:
            self.note_release(z, t, dt)
            if not self.baseline.flags.c_contiguous:  # (stepped in place, flat)
                self.baseline = np.ascontiguousarray(self.baseline)
            tau = self.tau_release if t < self._release_until else self.tau_drift
            # -expm1(-dt/tau) = 1 - exp(-dt/tau), accurate for small dt/tau; 1/n makes the first
            # frames after a (re)start a plain running mean (the bias-corrected EMA).
            ema = -math.expm1(-dt / tau)
            mean = 1.0 / self._frames
            sigma2 = self.detector.sigma ** 2
            if mean >= ema:  # the running mean of the start-up: take the frame whole
                follow_baseline(self.baseline.reshape(-1), z.reshape(-1), mean, 0.0, False)
                self.baseline_var = sigma2 * mean
            else:
                self.baseline_var = (1.0 - ema) ** 2 * self.baseline_var + ema * ema * sigma2
                # an implausible frame (most tactels beyond the limit) pulls clipped
                follow_baseline(self.baseline.reshape(-1), z.reshape(-1), ema,
                                MAX_STEP_SIGMAS * self.detector.sigma, True)

    def follow_drift(self, zeroed: np.ndarray, t: float, predicted: ArrayLike,
                     window: ArrayLike, *, fitted: bool = False) -> bool:
        """Follow drift under a held contact (module docstring): ``zeroed`` is the frame
        :meth:`update` returned at time ``t`` (s), ``predicted`` the strain the contact model
        gives on the whole array (a fit's, near this frame's contact), ``window`` the tactels
        the fit reads (boolean, ``(rows, cols)``).  Nothing moves unless the prediction
        explains the window's tactels within noise (their mean squared difference at most
        ``DRIFT_EXPLAINED`` noise variances: a moving contact's prediction is stale; not
        tested when ``fitted`` says the prediction is a fit of this very frame, the best the
        model explains it by, on a finger that departs from its model too) and
        ``DRIFT_STEP_S`` has passed since the last move; returns True when the baseline moved."""
        if not self.in_contact or self.baseline is None:
            return False
        if self._drift_t is None:
            self._drift_t = t  # the first call of a contact starts the clock
            return False
        elapsed = t - self._drift_t
        if elapsed < DRIFT_STEP_S - 1e-9:  # (frames DRIFT_STEP_S apart differ by a rounding)
            return False
        # (the arithmetic in two compiled passes: tactiled.calibration.fused)
        shape = np.shape(zeroed)
        inside = np.asarray(window, dtype=bool).reshape(-1)
        error = np.empty(inside.size)
        n_in, miss, finite = drift_error(np.asarray(zeroed, dtype=np.float64).reshape(-1),
                                         np.asarray(predicted, dtype=np.float64).reshape(-1),
                                         inside, error)
        n_out = inside.size - n_in
        if n_in == 0 or n_out == 0:
            return False
        sigma = self.detector.sigma
        if not (fitted or miss <= DRIFT_EXPLAINED * n_in * sigma * sigma):
            return False  # (a NaN fails the test too)
        if not finite:
            return False
        self._drift_t = t
        if self.learns_hysteresis and t == self._last_t:  # (the latest frame: _residual is its)
            self._learn_hysteresis(error.reshape(shape), predicted, ~inside, t, sigma)
        if not self.baseline.flags.c_contiguous:  # (stepped in place, flat)
            self.baseline = np.ascontiguousarray(self.baseline)
        pull_baseline(self.baseline.reshape(-1), error, inside, DRIFT_CLIP_SIGMAS * sigma,
                      -math.expm1(-min(elapsed, MAX_DRIFT_STEP_S) / self.tau_drift), n_out)
        return True

    def _learn_hysteresis(self, error: np.ndarray, predicted: ArrayLike, outside: np.ndarray,
                          t: float, sigma: float) -> None:
        """One step of the hysteresis learner on the latest frame (its error before
        compensation), and the compensator set to what it has learnt, or off."""
        raw = error if self._residual is None else error + self._residual
        learner = self.hysteresis_learner
        learner.learn(raw, np.asarray(predicted, dtype=np.float64), outside, t, sigma)
        on = self.hysteresis.fraction > 0.0
        usable = learner.usable(on=on)
        if usable is not None:
            self.hysteresis.set(*usable)
        elif on:
            self.hysteresis.set(0.0, self.hysteresis.tau_s)

    def begin_release(self, t: float) -> None:
        """The contact ended with the frame at ``t`` (s): the frames of the hold-off that
        follows are kept as steps of the hysteresis learner (:meth:`note_release`), learnt
        from when the next contact starts.  Only while the compensator is off: then what the
        frames hold beyond the contact's baseline is the rubber's whole recovery."""
        self._release = None
        if self.learns_hysteresis and self.hysteresis.fraction == 0.0 and self.baseline is not None:
            self._release = ReleaseSteps(self.shape, t + RELEASE_SKIP_S, DRIFT_STEP_S)

    def note_release(self, zeroed: np.ndarray, t: float, dt: float) -> None:
        """A frame with no contact (``zeroed``, at ``t`` s, ``dt`` s after the last) in the
        hold-off after a release, before the baseline's step (:meth:`begin_release`): each
        finished step goes to the hysteresis learner at once; what it learnt is taken up when
        the next contact starts (:meth:`_learn_release`)."""
        steps = self._release
        if steps is None or t >= self._release_until:
            return
        step = steps.frame(zeroed, t, -math.expm1(-dt / self.tau_release))
        if step is not None and self.learns_hysteresis:
            mean, frames = step
            self.hysteresis_learner.learn(mean, np.zeros(self.shape), np.ones(self.shape, dtype=bool),
                                          t, self.detector.sigma, frames)
            self._release_learnt = True

    def _learn_release(self) -> None:
        """A contact starts: the compensator is set to what the learner has learnt from the
        last release (from the next frame on, on every path: a read's frames in one call into
        the core end at a contact's first frame)."""
        self._release = None
        learnt, self._release_learnt = self._release_learnt, False
        if not learnt or not self.learns_hysteresis:
            return
        usable = self.hysteresis_learner.usable(on=False)
        if usable is not None:
            self.hysteresis.set(*usable)

    def set_hysteresis(self, on: bool) -> None:
        """Learn the rubber's hysteresis and take it out (``on``), or leave frames as read
        (the compensator off; what was learnt is kept for when it is on again)."""
        self.learns_hysteresis = bool(on)
        if not on:
            self.hysteresis.set(0.0, self.hysteresis.tau_s)

    def hysteresis_summary(self) -> dict[str, float | int | bool | None]:
        """What the zeroer knows of the rubber's hysteresis: the learnt ``fraction`` and
        ``tau_s`` (s; None before any learning step with a trail), their ``significance`` (noise
        sigmas), the learning ``steps`` taken, and whether it is ``compensating`` (then with
        the learnt constants)."""
        estimate = self.hysteresis_learner.estimate
        fraction, tau, z = (None, None, None) if estimate is None else estimate
        return {"fraction": fraction, "tau_s": tau, "significance": z,
                "steps": self.hysteresis_learner.steps,
                "compensating": self.hysteresis.fraction > 0.0}

    def tare(self, strain: ArrayLike | None = None) -> None:
        """Zero now: the baseline restarts from ``strain`` (a frame with nothing touching), or,
        with no argument, from the next frame :meth:`update` sees; either way it then settles as
        after start-up.  Clears the contact state."""
        self.in_contact = False
        self.detector.reset()
        self._release_until = -math.inf
        self._drift_t = None
        self.hysteresis.reset()  # the peaks were measured from the old baseline
        self.hysteresis_learner.reset()
        self._release = None
        self._release_learnt = False
        if strain is None:
            self._pending_tare = True
            return
        x = np.asarray(strain, dtype=np.float64)
        if x.shape != self.shape:
            raise ValueError(f"strain frame must have shape {self.shape}, got {x.shape}")
        finite = np.isfinite(x)
        self._tare_to(x, None if finite.all() else ~finite)
        self._frames = 1  # the given frame counts as the first of the running mean
        self._settle_until = (self._last_t if self._last_t is not None else -math.inf) + self.settle

    def reset(self) -> None:
        """Forget everything: the next frame re-initialises the baseline."""
        self.baseline = None
        self.in_contact = False
        self.detector.reset()
        self._last_t = None
        self._release_until = -math.inf
        self._pending_tare = False
        self._frames = 0
        self._settle_until = -math.inf
        self._drift_t = None
        self.hysteresis = HysteresisCompensator(self.shape)
        self.hysteresis_learner = HysteresisLearner(self.shape)
        self._residual = None
        self._release = None
        self._release_learnt = False

    def _tare_to(self, x: np.ndarray, bad: np.ndarray | None) -> None:
        self._pending_tare = False
        self._frames = 0
        self.baseline_var = self.detector.sigma ** 2  # one frame's noise
        if bad is None:
            self.baseline = x.copy()
        else:
            old = np.zeros(self.shape) if self.baseline is None else self.baseline
            self.baseline = np.where(bad, old, x)

"""Zeroing: per-tactel baseline tracking that follows drift but never erases a held contact.

A high-pass filter (subtract a running mean of everything) is the usual drift compensation, and
it fails exactly where a fingertip matters: a grasp held for minutes decays into the baseline and
vanishes.  Here the baseline moves only while no contact is detected:

* **idle** (no contact): ``baseline += a * (x - baseline)``, ``a = 1 - exp(-dt / tau_drift)``
  with ``tau_drift`` = 5 s: slow enough to average noise (an EMA of time constant tau over frames
  at rate r averages about ``2 tau r`` frames), fast enough for thermal drift;
* **in contact**: frozen, so the contact's strain is kept however long it is held;
* **after a release**, for ``holdoff`` s (default 1.5 s = 5 ``tau_release``): the faster
  ``tau_release`` = 0.3 s, so the rubber's hysteresis residual (and drift accumulated while frozen)
  is absorbed within about a second instead of lingering as a phantom pressure.

``dt`` is the difference of the caller's timestamps (seconds; device time preferred), so the
behaviour does not depend on the frame rate; a frame whose ``dt <= 0`` (duplicate or backwards
clock) does not move the baseline.  The zeroed output of a frame is computed against the baseline
*before* that frame updates it.

The first frame starts the baseline (an implicit tare: start with the finger unloaded), and
:meth:`Zeroer.tare` restarts it on demand.  A baseline taken from one frame carries that frame's
noise, which would double the noise variance of every zeroed frame and multiply the false-contact
rate; so after a (re)start the baseline is the running *mean* of the frames seen so far until the
EMA weight catches up (update weight ``max(1/n, a)`` after ``n`` frames: the bias-corrected EMA),
and for ``settle`` s (default 0.25 s) no contact is reported while the mean forms.  By then the
baseline's noise is ``sigma/sqrt(n)`` (``n`` = 25 frames at 100 Hz: +2 % on the zeroed noise).

NaN/inf entries are output as 0 and do not touch their tactel's baseline;
:attr:`Zeroer.nonfinite_frames` counts such frames.

**One implausible frame cannot drag the baseline.**  A no-contact frame on which most tactels
(more than half) sit beyond ``MAX_STEP_SIGMAS`` (10) noise sigmas of the detector's ``sigma``
is no physical state of an unloaded finger: a glitch (an ADC returning zero counts for a few
frames, which the detector rightly does not call a contact).  Outside the running-mean
start-up, such a frame's pull on each tactel's baseline is clipped to 10 sigma, so it moves
the baseline by at most ``weight x 10 sigma`` instead of ``weight x`` its full deviation (was
7-39 sigma per glitch frame with the 0.3 s release constant; every contact after it then
carried that pedestal).  Ordinary frames are not clipped: a release residual is a local bump
and drift is slow, so both are followed exactly as before.  A genuine step of the whole
unloaded frame by more than 10 sigma is absorbed at 10 sigma per time constant; ``tare``
takes it at once.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from tactiled.calibration.contact import ContactDetector

DEFAULT_TAU_DRIFT = 5.0  # s
DEFAULT_TAU_RELEASE = 0.3  # s
DEFAULT_HOLDOFF = 1.5  # s
DEFAULT_SETTLE = 0.25  # s
MAX_STEP_SIGMAS = 10.0  # a frame's pull on the baseline is clipped to this many noise sigmas


class Zeroer:
    """Turns linearised strain (before zeroing) into zeroed strain, frame by frame.

    ``detector`` decides contact on each zeroed frame (default: a :class:`ContactDetector` for
    the default sensor); :meth:`update` may instead be told the contact state.  Time constants
    are in seconds.
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
        self._frames += 1
        settling = t < self._settle_until
        if contact is None:
            # While the baseline forms, its own noise would raise false contacts: learn only.
            contact = False if settling else self.detector.update(z)
        dt = t - self._last_t if self._last_t is not None else 0.0
        self._last_t = t
        if contact:
            self.in_contact = True
            return z  # frozen: a held contact is never absorbed
        if self.in_contact:
            self.in_contact = False
            self._release_until = t + self.holdoff
        if dt > 0.0:
            tau = self.tau_release if t < self._release_until else self.tau_drift
            # -expm1(-dt/tau) = 1 - exp(-dt/tau), accurate for small dt/tau; 1/n makes the first
            # frames after a (re)start a plain running mean (the bias-corrected EMA).
            ema = -math.expm1(-dt / tau)
            mean = 1.0 / self._frames
            sigma2 = self.detector.sigma ** 2
            if mean >= ema:  # the running mean of the start-up: take the frame whole
                self.baseline += mean * z
                self.baseline_var = sigma2 * mean
            else:
                self.baseline_var = (1.0 - ema) ** 2 * self.baseline_var + ema * ema * sigma2
                limit = MAX_STEP_SIGMAS * self.detector.sigma
                if np.count_nonzero(np.abs(z) > limit) * 2 > z.size:  # implausible: clip
                    z = np.clip(z, -limit, limit)
                self.baseline += ema * z
        return z

    def tare(self, strain: ArrayLike | None = None) -> None:
        """Zero now: the baseline restarts from ``strain`` (a frame with nothing touching), or,
        with no argument, from the next frame :meth:`update` sees; either way it then settles as
        after start-up.  Clears the contact state."""
        self.in_contact = False
        self.detector.reset()
        self._release_until = -math.inf
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

    def _tare_to(self, x: np.ndarray, bad: np.ndarray | None) -> None:
        self._pending_tare = False
        self._frames = 0
        self.baseline_var = self.detector.sigma ** 2  # one frame's noise
        if bad is None:
            self.baseline = x.copy()
        else:
            old = np.zeros(self.shape) if self.baseline is None else self.baseline
            self.baseline = np.where(bad, old, x)

"""The scene gate: which frames are worth a fit."""

# Fitting costs milliseconds in a worker process; most frames of a hand at rest need none:
#
# * **no contact** (the contact detector says so): publish a no-contact estimate at once;
# * **unchanged**: the frame differs from the last *fitted* frame only by noise, so a new fit
#   would return the same contact within its uncertainty: republish that estimate under the new
#   frame's seq (``gate = "unchanged"``, ``fitted_seq`` = the frame actually fitted), for at
#   most ``MAX_CARRIED`` frames;
# * otherwise **fit**.
#
# "Within noise" is a chi-square test.  With i.i.d. strain noise of standard deviation sigma on
# every tactel, the difference of two frames of the same contact has variance ``2 sigma^2`` per
# tactel, so ``chi2 = sum(d^2) / (2 sigma^2)`` over the ``n`` tactels follows chi-square with
# ``n`` degrees of freedom (mean ``n``, standard deviation ``sqrt(2n)``).  The frame is unchanged
# when ``chi2 <= n + z sqrt(2n)``; with ``z = 3`` (the default) and 64 tactels a static contact
# is refitted on 0.4 % of frames (the chi-square tail beyond 97.9), while a change the fit could resolve (several sigma on the tactels under the
# contact) exceeds it.  Comparing against the last fitted frame, not the previous frame, means
# slow drift accumulates until it triggers a refit instead of creeping by unnoticed.
#
# The gate is a small object of its own so other rules ("too light for curvature", rate
# limits) can be added and tested without the pipeline around it.

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tactiled.pipeline.estimate import GATE_FIT, GATE_NO_CONTACT, GATE_UNCHANGED


#: At most this many frames answered with one fit: a contact that moves slower than the
#: test sees (a roll within the noise) is fitted again after it, so no value stays
#: bit-identical for longer while its contact moves (one fit in 50 frames of a held contact).
MAX_CARRIED = 50


@dataclass(frozen=True)
class GateDecision:
    """What to do with one frame: ``action`` is "fit", "no_contact" or "unchanged";
    ``chi2`` is the unchanged test's statistic when it was computed."""

    action: str
    chi2: float | None = None


class Gate:
    """Decides, frame by frame, whether a zeroed strain frame needs a fit.

    ``sigma``: strain noise of one tactel (1 sigma); ``z``: the unchanged test's threshold in
    standard deviations of chi-square; ``reuse_unchanged=False`` turns that test off.
    """

    def __init__(self, sigma: float, z: float = 3.0, reuse_unchanged: bool = True) -> None:
        self.configure(sigma=sigma, z=z, reuse_unchanged=reuse_unchanged)
        self._reference: np.ndarray | None = None
        self._carried = 0  # frames answered "unchanged" since the reference was fitted
        #: frames found unchanged and fitted all the same: carried, their estimate would have
        #: lost a value to the one rule (the pipeline counts them; ``reuse_refused``)
        self.refused = 0
        #: the last ``decide``'s change since the reference, ``|delta s|^2 / sigma^2``: the
        #: upper bound at ``z`` of its estimate ``2 (chi2 - n)`` (never below 0; inf before a
        #: test): what an estimate carried to that frame must cover
        #: (:func:`tactiled.fit.verdict.carried`)
        self.change = math.inf

    def configure(self, *, sigma: float | None = None, z: float | None = None,
                  reuse_unchanged: bool | None = None) -> None:
        """Change the thresholds (at run time too); the reference frame is kept."""
        if sigma is not None:
            if not (math.isfinite(sigma) and sigma > 0):
                raise ValueError(f"sigma must be a positive strain, got {sigma!r}")
            self.sigma = float(sigma)
        if z is not None:
            if not (math.isfinite(z) and z >= 0):
                raise ValueError(f"z must be a non-negative number, got {z!r}")
            self.z = float(z)
        if reuse_unchanged is not None:
            self.reuse_unchanged = bool(reuse_unchanged)

    @property
    def has_reference(self) -> bool:
        """True when a fitted frame is held to compare new frames with."""
        return self._reference is not None

    def decide(self, strain: np.ndarray, in_contact: bool) -> GateDecision:
        """The decision for one zeroed frame (finite strain) and its contact flag."""
        self.change = math.inf
        if not in_contact:
            return GateDecision(GATE_NO_CONTACT)
        ref = self._reference
        if not self.reuse_unchanged or ref is None or ref.shape != strain.shape:
            return GateDecision(GATE_FIT)
        d = strain - ref
        n = d.size
        chi2 = float(np.dot(d.ravel(), d.ravel())) / (2.0 * self.sigma * self.sigma)
        # the change is estimated by 2 (chi2 - n), whose noise has a standard deviation of
        # 2 sqrt(2 (n + change)) (chi-square of noncentrality change / 2): what an estimate
        # carried to this frame must cover is its upper bound at the test's own z, the change
        # the test cannot tell from none (a contact moving slowly under the noise)
        est = 2.0 * (chi2 - n)
        self.change = max(est + 2.0 * self.z * math.sqrt(2.0 * (n + max(est, 0.0))), 0.0)
        if chi2 <= n + self.z * math.sqrt(2.0 * n) and self._carried < MAX_CARRIED:
            self._carried += 1
            return GateDecision(GATE_UNCHANGED, chi2)
        return GateDecision(GATE_FIT, chi2)

    def fitted(self, strain: np.ndarray) -> None:
        """Make ``strain`` (the frame whose fit was just published) the reference."""
        self._reference = np.array(strain, dtype=np.float64, copy=True)
        self._carried = 0

    def reset(self) -> None:
        """Forget the reference (contact lost, tare): the next contact frame is fitted."""
        self._reference = None

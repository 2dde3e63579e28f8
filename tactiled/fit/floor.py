"""Learning how far a finger departs from its model, from the residuals of its own fits."""

# A single frame cannot show all of a finger's departure from the model: of the model error on a
# window's tactels, the part that looks like a change of the contact's parameters is absorbed by
# the fit and leaves no residual.  What is left shows in chi^2, but on one light frame it is lost
# in the noise, while the estimate is biased all the same.  The departure is a property of the
# finger (gains and tactel positions the model does not know), so it is estimated across fits.
#
# Two kinds of departure, each with its own footprint on a tactel ``i`` (in units of its noise):
# a gain error adds variance ``tau_s^2 z_i^2`` (``z_i`` the tactel's strain), a displaced tactel
# ``tau_g^2 |grad z_i|^2`` (``tau_g`` in mm; the gradient is the strain's slope in the contact's
# position).  A fit's residuals are ``r = M e`` for the readings' errors ``e``, ``M = I - H`` (H the
# hat matrix), so each residual's expected square is ``sum_j M_ij^2 V_j``:
#
#     r_i^2 - M_ii = tau_s^2 sum_j M_ij^2 z_j^2 + tau_g^2 sum_j M_ij^2 |grad z_j|^2  (+ zero-mean)
#
# One frame's sums cannot tell the two kinds apart (both grow with the force); its tactels can
# (gain errors sit on the peak, displacements on the flanks), so every residual of every recent
# fit is one equation, and ``(tau_s^2, tau_g^2)`` is the non-negative least-squares solution over the recent fits
# (exponential weights, memory ``MEMORY`` fits): the method of moments.  It is used only once the
# pooled excess is significant (beyond ``SIGNIFICANCE`` standard deviations of what the noise
# alone gives, after at least ``MIN_FITS`` fits), so a finger that matches its model (or its identified floor) keeps its
# Cramer-Rao bounds exactly.  The fitter caps each fit's excess near what the pool expects, so
# one contact far outside the model does not widen every later estimate.

from __future__ import annotations

import math

import numpy as np

#: Fits the learner remembers (exponential weights with this mean age).
MEMORY = 200
#: Standard deviations of the noise-only excess beyond which the pooled excess is believed.
SIGNIFICANCE = 3.0
#: Fits needed before the pool is used at all: a variance split two ways from a handful of
#: frames (say, the first frames of a press, fitted with a model the data later rejects) says
#: more about those frames than about the finger.  Twenty: until then a mismatched finger's
#: sigmas are a lone frame's, and 50 cost it 5-10 points of coverage over its first 400 fits
#: (measured with `tactiled bench --suite identify`), while the significance test keeps a finger that matches
#: its model at its Cramer-Rao bounds either way.
MIN_FITS = 20


class FloorLearner:
    """Exponentially weighted pool of the fits' excess residuals (see the module docstring)."""

    def __init__(self, memory: int = MEMORY) -> None:
        self.memory = memory
        self._keep = 1.0 - 1.0 / memory
        self._excess = 0.0  # sum of e_f, weighted
        self._null_var = 0.0  # variance of that sum under the noise alone
        self._ata = np.zeros((2, 2))  # sum of [S, G]^T [S, G]
        self._atb = np.zeros(2)  # sum of [S, G] e_f
        self.fits = 0

    def add(self, rows: np.ndarray, excess: np.ndarray, dof: int) -> None:
        """One fit's equations: ``rows`` (n, 2) the footprints ``sum_j M_ij^2 (z_j^2,
        |grad z_j|^2)``, ``excess`` (n,) the ``r_i^2 - M_ii``; ``dof`` its degrees of freedom
        (the summed excess's variance under the noise alone is ``2 dof``)."""
        total = float(np.sum(excess))
        if not (math.isfinite(total) and np.all(np.isfinite(rows))):
            return
        k = self._keep
        self._excess = k * self._excess + total
        self._null_var = k * k * self._null_var + 2.0 * dof
        self._ata = k * self._ata + rows.T @ rows
        self._atb = k * self._atb + rows.T @ excess
        self.fits += 1

    def taus(self) -> tuple[float, float]:
        """``(tau_s^2, tau_g^2)``, or zeros while the pooled excess is not significant."""
        if self.fits < MIN_FITS or self._excess <= SIGNIFICANCE * math.sqrt(self._null_var):
            return 0.0, 0.0
        a, b = self._ata, self._atb
        best, best_cost = (0.0, 0.0), math.inf
        # non-negative least squares in two unknowns: the interior solution or an edge
        cands = []
        det = a[0, 0] * a[1, 1] - a[0, 1] ** 2
        if det > 1e-12 * max(a[0, 0] * a[1, 1], 1e-300):
            x = np.linalg.solve(a, b)
            if x[0] >= 0.0 and x[1] >= 0.0:
                cands.append((float(x[0]), float(x[1])))
        if a[0, 0] > 0.0:
            cands.append((max(b[0] / a[0, 0], 0.0), 0.0))
        if a[1, 1] > 0.0:
            cands.append((0.0, max(b[1] / a[1, 1], 0.0)))
        for c in cands:
            v = np.array(c)
            cost = float(v @ a @ v - 2.0 * v @ b)
            if cost < best_cost:
                best, best_cost = c, cost
        return best

    def reset(self) -> None:
        """Forget every fit (a new finger, or a new calibration)."""
        self.__init__(self.memory)

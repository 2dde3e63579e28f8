"""Each tactel's gain and position on the user's finger, learned from the finger's own fits."""

# A finger nobody identified (``tactiled calibrate --identify``) has tactels whose gains and
# positions depart from the model's.  :mod:`tactiled.fit.floor` widens the uncertainties by the
# size of that departure; it cannot remove the bias it leaves.  A gain error common to the
# tactels under a contact is the worst of it: the fit reads it as a force scale and leaves no
# residual, so a finger whose central tactels happen to read 2.5 % low reports every central
# force 2.5 % low, however wide its sigmas.  One window cannot see that; many can.  Contacts
# land all over the array, a tactel is under a window's peak in one fit and on its flank in
# another, and overlapping windows tie every tactel to its neighbours: the departure of each
# tactel is observable up to what no contact can tell apart (the array's mean gain is a force
# scale, its mean displacement a location).  Astronomers call this a flat field.
#
# The residual model.  In units of each tactel's noise, a fit's residuals (model minus reading)
# are ``r = M e`` with ``M = I - H`` the residual operator of the fit (H the hat matrix) and
# ``e`` the readings' errors.  Tactel ``i`` with gain ``1 + g_i`` and displacement
# ``(dx_i, dy_i)`` mm errs by
#
#     e_i = -m_i g_i + jx_i dx_i + jy_i dy_i   (+ noise)
#
# with ``m_i`` the model's strain there and ``(jx_i, jy_i)`` its slope in the contact's position
# (:mod:`tactiled.physics.kernels` applies displacements to first order the same way).  Stacking
# ``u = (g, dx, dy)`` over the array, each fit adds ``X = M E`` (``E`` the window's columns of
# the error model above) to the normal equations ``N = sum X^T X``, ``b = sum X^T (r + X u_f)``,
# where ``u_f`` is the correction that fit ran with (so ``b`` estimates the whole departure, not
# what was left of it).  Old fits fade with weights of mean age ``MEMORY`` fits.
#
# The estimate.  Each tactel's gain error and displacement are drawn, as far as anyone knows
# before the fits, from zero-mean spreads of variances ``v_g`` and ``v_d``; the estimate is the
# posterior mean ``u = (N + P)^-1 b``, ``P = diag(1/v_g, 1/v_d, 1/v_d)``, with covariance
# ``(N + P)^-1``.  The spreads are themselves estimated from the fits (maximum likelihood by
# expectation-maximisation, ``v <- mean(u_i^2 + cov_ii)`` per kind, a few steps per solve,
# starting wide).  What no contact can tell apart stays with the prior: a gain common to every
# tactel is a force scale (the fit absorbs it exactly), a displacement common to every tactel a
# location; the prior then says "the array reads nominal on average", and the covariance carries
# how well that is known (the spread over ``sqrt(rows*cols)``).  That posterior covariance is
# what the corrections add to each fit's uncertainty (:meth:`FlatField.error_covariance`): the
# residuals cannot show a correction that is wrong along a direction the fit absorbs.
#
# It is switched on only when it says something, and only when what it says is the tactels':
# when ``q = b^T (N + P)^-1 b`` (the chi^2 the corrections take off the pooled fits) exceeds
# what the noise alone gives by ``SIGNIFICANCE`` of its standard deviations (under the noise
# ``b`` has covariance ``N2 = sum w_f^2 X^T X``, taken as ``N`` times the weights' mean), and explains at least ``MIN_EXPLAINED`` of the
# fits' excess chi^2.  Residuals that follow the contacts (a rubber that is not the model's,
# contacts the model does not describe, hysteresis) also look significant, but no set of
# per-tactel corrections explains much of them; nor do they keep plausible spreads (beyond
# ``MAX_GAIN_SPREAD``, ``MAX_SHIFT_SPREAD`` it stands down too).  A finger that matches its
# model (the paper's, or one identified) is never corrected; its fits keep their Cramer-Rao
# bounds exactly.

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tactiled import native

#: Arrays up to this many tactels get a flat field: its normal equations are 3 per tactel
#: square (an 8x8 array: 192, a solve ~2 ms; 16x16: 768, ~0.1 s and 14 MB a finger).
MAX_TACTELS = 256
#: Fits the learner remembers (exponential weights with this mean age): a finger's tactels
#: are stable over hours, so a long memory; still finite, so a drift is followed.
MEMORY = 100_000
#: Fits before the first solve of the normal equations (each costs 1-3 ms for an 8x8 array).
MIN_FITS = 20
#: Solves come after every quarter more fits (a young pool changes fast), at most this far
#: apart (a solve costs a few fits' time; the daemon fits up to ~1000 frames a second).
SOLVE_EVERY = 1000
#: Standard deviations of the noise-only statistic beyond which the departure is believed.
SIGNIFICANCE = 5.0
#: The prior's standard deviations before the fits estimate them: a tactel's relative gain
#: error and its displacement (mm); wide (real fingers: a few %, ~0.1 mm).
PRIOR_GAIN, PRIOR_SHIFT = 0.1, 0.3
#: The largest spreads a flat field believes: tactel gains spread by more than this (relative)
#: or tactels displaced by more than this (mm, a tenth of the pitch) are not what the fits
#: show.  A finger whose rubber differs from the model (the wrong depth or modulus), contacts
#: the model does not describe, or the rubber's hysteresis make the fits' residuals follow the
#: contacts, not the tactels, and per-tactel corrections would only bend the estimates (on
#: the simulator's moving scene, whose finger is the model's, the spreads run to 30 % and
#: 600 um).  The floor learner widens the uncertainties then, and the flat field stands down.
MAX_GAIN_SPREAD, MAX_SHIFT_SPREAD = 0.15, 0.3
#: The share of the fits' excess residuals (chi^2 beyond the noise, pooled) the corrections
#: must explain to be used: a finger's tactels explain 95-99 % of theirs (the benchmark's
#: fingers); residuals that follow the contacts do not (the simulator's demo scene, whose finger
#: is the model's: 54 %, and corrections there cost its force coverage 95 -> 78 %).
MIN_EXPLAINED = 0.8
#: Windows (sets of usable tactels) whose sums and covariance blocks a flat field keeps: an
#: 8x8 array has 25 windows of 4x4 without masked tactels (each block 38 KB).
MAX_WINDOWS = 64
#: Expectation-maximisation steps for the prior's variances at each solve, until ``EM_FITS``
#: fits (then one: the spreads have settled, and each step costs an inversion).
EM_STEPS, EM_FITS = 2, 1000
#: Smallest prior variance (relative gain^2, or mm^2): a kind of departure the fits do not
#: show is held near zero, and the posterior stays finite.
_TINY = 1e-8
#: Why a departure is not the tactels', in the words the flat field stands down with.
_FOLLOW_THE_CONTACTS = ("the residuals follow the contacts, not the tactels (a rubber that is "
                        "not the model's, contacts the model does not describe, hysteresis); "
                        "identifying the finger (tactiled calibrate --identify) removes the first")
#: The lazy exponential weights are renormalised before they pass this.
_RESCALE = 1e100


def _accumulate(ata: np.ndarray, atb: np.ndarray, resid_op: np.ndarray, m: np.ndarray,
                jx: np.ndarray, jy: np.ndarray, r: np.ndarray, u: np.ndarray, idx: np.ndarray,
                w: float) -> float:
    """Add one fit, weighted ``w``, to a window's sums ``ata`` (3k, 3k) and ``atb`` (3k,):
    ``X^T X = E^T M E`` and ``X^T (r + X u) = E^T (r + M E u)`` (M, the residual operator, is a
    symmetric projection; ``E = [diag(-m), diag(jx), diag(jy)]``; ``u[idx]`` the corrections
    the fit ran with).  Returns the excess ``|r0|^2 - tr M`` of the uncorrected residuals
    ``r0``, or NaN (and adds nothing) when a number of the fit is not finite.  Compiled
    (core/flatfield.cpp): in numpy this is ~25 small array operations a fit, 40 % of a
    learning fitter's time."""
    k = m.size
    c = np.empty(3 * k)
    check = 0.0
    for i in range(k):
        c[i] = -m[i]
        c[k + i] = jx[i]
        c[2 * k + i] = jy[i]
    eu = np.empty(k)
    for i in range(k):
        eu[i] = c[i] * u[idx[i]] + c[k + i] * u[idx[k + i]] + c[2 * k + i] * u[idx[2 * k + i]]
        check += c[i] + c[k + i] + c[2 * k + i]
    r0 = np.empty(k)
    total = 0.0
    trace = 0.0
    for i in range(k):
        acc = r[i]
        for j in range(k):
            acc += resid_op[i, j] * eu[j]
            check += resid_op[i, j]
        r0[i] = acc
        total += acc * acc
        trace += resid_op[i, i]
    if not np.isfinite(check + total):
        return np.nan
    for a in range(3):
        for i in range(k):
            ci = w * c[a * k + i]
            atb[a * k + i] += ci * r0[i]
            for b in range(3):
                for j in range(k):
                    ata[a * k + i, b * k + j] += ci * resid_op[i, j] * c[b * k + j]
    return total - trace


#: the Python body (the reference); ``_accumulate`` runs the compiled core's when it is loaded
REFERENCE = native.bind(globals(), {"_accumulate": "accumulate"})


@dataclass
class _Window:
    """The sums of the fits on one set of tactels: ``idx`` their places in ``(g, dx, dy)``."""

    idx: np.ndarray
    ata: np.ndarray
    atb: np.ndarray


class FlatField:
    """The per-tactel departure ``(g, dx, dy)`` of one finger, learned from its fits."""

    def __init__(self, rows: int, cols: int, memory: int = MEMORY) -> None:
        self.rows, self.cols, self.memory = rows, cols, memory
        n = rows * cols
        self._n = n
        self._keep = 1.0 - 1.0 / memory
        # fit f enters with weight w_f = keep^-f (w grows by 1/keep each fit), so the sums
        # N, b (and sum w, sum w^2) over w fade every old fit without touching the matrices
        self._w = 1.0
        self.ata = np.zeros((3 * n, 3 * n))
        self._sw = self._sw2 = 0.0  # sums of the fits' weights and of their squares (over w, w^2)
        self.atb = np.zeros(3 * n)
        self.excess = 0.0
        #: the share of the fits' excess chi^2 (beyond the noise) the corrections explain
        self.explained = 0.0
        self._windows: dict[bytes, _Window] = {}
        self._blocks: dict[bytes, np.ndarray] = {}  # the covariance's block of a window
        #: the prior's variances (relative gain^2, mm^2): wide at first, then estimated
        self._var = (PRIOR_GAIN ** 2, PRIOR_SHIFT ** 2)
        self.fits = 0
        self._next_solve = MIN_FITS
        #: a solve the fits made due and :meth:`catch_up` has not yet run
        self.solve_due = False
        self.active = False
        #: what the last solve found, in words (empty before the first)
        self.note = ""
        #: what the fits run with: the readings divided by ``gain``, the tactels displaced
        #: by ``dx``, ``dy`` mm (each (rows, cols))
        self.gain = np.ones((rows, cols))
        self.inverse_gain = np.ones((rows, cols))
        self.dx = np.zeros((rows, cols))
        self.dy = np.zeros((rows, cols))
        self._u = np.zeros(3 * n)
        #: the posterior covariance of ``(g, dx, dy)`` (3 rows*cols square), once active
        self.covariance: np.ndarray | None = None

    # ------------------------------------------------------------------------------------
    def add(self, tactels: np.ndarray, resid_op: np.ndarray, m: np.ndarray, jx: np.ndarray,
            jy: np.ndarray, r: np.ndarray, weight: float = 1.0) -> None:
        """One fit: ``tactels`` (k,) the flat indices (``row * cols + col``) of its usable
        window tactels, ``resid_op`` (k, k) its residual operator, ``m`` (k,) the model's
        strain, ``jx``, ``jy`` (k,) its slope in the contact's x0, y0 (per mm), ``r`` (k,) the
        residuals (model minus reading); all in units of each tactel's noise.  ``weight``
        (<= 1) down-weights a fit far outside the model."""
        if not weight > 0.0:
            return
        acc, kept = self._window(tactels)
        self._w /= self._keep
        if self._w > _RESCALE:
            self._rescale(1.0 / self._w)
        w = self._w * weight
        excess = _accumulate(acc.ata, acc.atb, resid_op, m, np.ascontiguousarray(jx),
                             np.ascontiguousarray(jy), r, self._u, acc.idx, w)
        if not math.isfinite(excess):
            return  # a fit with a non-finite number in it: nothing was added
        self._sw += w
        self._sw2 += w * w
        if not kept:
            self._fold_one(acc)  # a block of its own (past MAX_WINDOWS)
        # what the noise does not explain of the fit's residuals (uncorrected), pooled
        self.excess += w * excess
        self.fits += 1
        if self.fits >= self._next_solve:
            self._next_solve = self.fits + min(max(self.fits // 4, 1), SOLVE_EVERY)
            # not now: a solve costs a few fits' time, and this fit's answer does not use it
            # (its corrections are already taken); the fitter runs it after the answer
            self.solve_due = True

    def catch_up(self) -> bool:
        """Run the solve the fits made due (:meth:`add` only marks it); True if one ran."""
        if not self.solve_due:
            return False
        self.solve_due = False
        self.solve()
        return True

    def _window(self, tactels: np.ndarray) -> tuple[_Window, bool]:
        """The sums of the fits on these tactels since the last solve: a fit's window
        recurs, so a fit adds to a small block instead of scattering into the array's.  The
        blocks are kept (zeroed at each solve), so what a flat field holds does not rise and
        fall with the windows the contacts visit; past ``MAX_WINDOWS`` of them (windows with
        masked tactels are sets of their own) a block is the fit's alone and goes straight
        into the array's sums.  Returns the block and whether it is kept."""
        key = tactels.tobytes()
        acc = self._windows.get(key)
        if acc is not None:
            return acc, True
        n = self._n
        idx = np.concatenate((tactels, tactels + n, tactels + 2 * n))
        k = idx.size
        acc = _Window(idx, np.zeros((k, k)), np.zeros(k))
        if len(self._windows) < MAX_WINDOWS:
            self._windows[key] = acc
            return acc, True
        return acc, False

    def _rescale(self, s: float) -> None:
        for acc in (self, *self._windows.values()):
            acc.ata *= s
            acc.atb *= s
        self.excess *= s
        self._sw *= s
        self._sw2 *= s * s
        self._w *= s

    def _fold(self) -> None:
        """Add the windows' sums into the array's, and zero them."""
        for acc in self._windows.values():
            self._fold_one(acc)
            acc.ata.fill(0.0)
            acc.atb.fill(0.0)

    def _fold_one(self, acc: _Window) -> None:
        block = np.ix_(acc.idx, acc.idx)
        self.ata[block] += acc.ata
        self.atb[acc.idx] += acc.atb

    def solve(self) -> None:
        """Re-estimate the departure from the pooled fits; switch the correction on once it
        is significant (see the module docstring)."""
        n = self._n
        self._fold()
        s = 1.0 / self._w  # the stored sums times s are the weighted sums
        a = self.ata * s
        b = self.atb * s
        diag = np.diag_indices(3 * n)
        for _ in range(EM_STEPS if self.fits < EM_FITS else 1):
            # the prior's variances (the tactels' spread of gains and of displacements) by
            # maximum likelihood: expectation-maximisation, carried on from solve to solve
            prior = np.concatenate((np.full(n, 1.0 / self._var[0]), np.full(2 * n, 1.0 / self._var[1])))
            ap = a.copy()
            ap[diag] += prior  # kept: the null's traces below need the last prior
            try:
                cov = np.linalg.inv(ap)
            except np.linalg.LinAlgError:
                return
            u = cov @ b
            if not np.all(np.isfinite(u)):
                return
            second = u * u + np.diag(cov)  # E[u_i^2] under the posterior
            # (held below twice the plausible: a departure elsewhere would run them off)
            self._var = (min(max(float(second[:n].mean()), _TINY), 4.0 * MAX_GAIN_SPREAD ** 2),
                         min(max(float(second[n:].mean()), _TINY), 4.0 * MAX_SHIFT_SPREAD ** 2))
        gain_sd, shift_sd = math.sqrt(self._var[0]), math.sqrt(self._var[1])
        if gain_sd > MAX_GAIN_SPREAD or shift_sd > MAX_SHIFT_SPREAD:
            self._stand_down(
                f"the departure is not the tactels' (it would take gains spread by "
                f"{100 * gain_sd:.2g} % and tactels displaced by {1000 * shift_sd:.3g} um): "
                + _FOLLOW_THE_CONTACTS)
            return
        self.note = (f"tactel gains spread by ~{100 * gain_sd:.2g} %, tactels displaced by "
                     f"~{1000 * shift_sd:.3g} um")
        # b ~ N(0, N2) under the noise alone: q = b^T C b (C the covariance; the chi^2 the
        # corrections take off the pooled fits) has mean tr(C N2) and variance
        # 2 tr((C N2)^2).  With the fits alike, N2 = rho N (rho = sum w^2 / sum w), and
        # C N = I - C P (P the prior's diagonal): both traces in O(size^2), no product
        q = float(b @ u)
        rho = s * self._sw2 / self._sw if self._sw > 0.0 else 1.0
        cp = np.diag(cov) * prior
        t1 = 3 * n - float(cp.sum())
        t2 = 3 * n - 2.0 * float(cp.sum()) + float(prior @ (cov * cov) @ prior)
        mean, var = rho * t1, 2.0 * rho * rho * t2
        excess = self.excess * s
        self.explained = (q - mean) / excess if excess > 0.0 else 0.0
        if self.explained < MIN_EXPLAINED:
            if self.active or self.explained > 0.0:
                self._stand_down(
                    f"the departure is not the tactels' (corrections for each tactel would "
                    f"explain {100 * max(self.explained, 0.0):.0f} % of the fits' excess "
                    "residuals): " + _FOLLOW_THE_CONTACTS)
            return
        if not self.active:
            if not q > mean + SIGNIFICANCE * math.sqrt(max(var, 0.0)):
                return
            self.active = True
        g = np.clip(u[:n], -0.5, 0.5)  # a tactel's gain cannot be corrected past half
        self._u = np.concatenate((g, np.clip(u[n:], -1.0, 1.0)))
        shape = (self.rows, self.cols)
        self.gain = (1.0 + g).reshape(shape)
        self.inverse_gain = 1.0 / self.gain
        self.dx = self._u[n:2 * n].reshape(shape)
        self.dy = self._u[2 * n:].reshape(shape)
        self.covariance = cov
        for key, blk in self._blocks.items():  # in place: the same blocks, new values
            idx = self._windows[key].idx
            blk[...] = cov[np.ix_(idx, idx)]

    def _stand_down(self, reason: str) -> None:
        """No correction (the fits run as without a flat field), for ``reason``."""
        self.active = False
        self.note = reason
        self._u = np.zeros(3 * self._n)
        self.gain = np.ones((self.rows, self.cols))
        self.inverse_gain = self.gain
        self.dx = np.zeros((self.rows, self.cols))
        self.dy = self.dx
        self.covariance = None

    def error_covariance(self, tactels: np.ndarray, m: np.ndarray, jx: np.ndarray,
                         jy: np.ndarray) -> np.ndarray | None:
        """The covariance ``E P E^T`` (k, k) of a window's errors that the corrections' own
        uncertainty leaves (``P`` their posterior covariance, ``E`` the error model of the
        module docstring), in units of each tactel's noise; arguments as for :meth:`add`.
        It is what the residuals cannot show: a correction wrong along a direction a fit
        absorbs (a gain common to the window) moves the estimate and leaves no residual.
        None while the correction is off."""
        if self.covariance is None:
            return None
        key = tactels.tobytes()
        p = self._blocks.get(key)
        if p is None:
            idx = self._window(tactels)[0].idx
            p = self.covariance[np.ix_(idx, idx)]
            if key in self._windows:  # kept (and refreshed at each solve) with its sums
                self._blocks[key] = p
        c = np.concatenate((-m, jx, jy))
        k = m.size
        return (p * np.outer(c, c)).reshape(3, k, 3, k).sum(axis=(0, 2))

    def reset(self) -> None:
        """Forget every fit (a new finger, or a new calibration)."""
        self.__init__(self.rows, self.cols, self.memory)

    def summary(self) -> dict[str, float | int | bool]:
        """What it holds, in four numbers (for a worker's health figures): fits pooled,
        whether the correction is on, the gains' RMS departure from 1 and the tactels' RMS
        displacement (um) it applies."""
        return {"fits": self.fits, "active": self.active,
                "gain_rms": float(np.sqrt(np.mean((self.gain - 1.0) ** 2))),
                "shift_rms_um": 1000.0 * float(np.sqrt(np.mean(self.dx ** 2 + self.dy ** 2)))}

    # -- what survives a restart (tactiled.pipeline.learned) -------------------------------
    _SCALARS = ("_w", "_sw", "_sw2", "excess", "explained", "fits", "_next_solve", "active",
                "solve_due")
    _ARRAYS = ("ata", "atb", "gain", "inverse_gain", "dx", "dy", "_u")

    def state(self) -> dict[str, np.ndarray]:
        """Everything learned, as named arrays (``numpy.savez``-ready): the pooled normal
        equations, the estimate the fits run with and its covariance.  The window blocks are
        folded into the array's sums first (what they hold is kept)."""
        self._fold()
        out = {name: np.asarray(getattr(self, name)) for name in self._SCALARS + self._ARRAYS}
        out["var"] = np.asarray(self._var)
        out["shape"] = np.asarray((self.rows, self.cols, self.memory))
        out["note"] = np.asarray(self.note)
        if self.covariance is not None:
            out["covariance"] = self.covariance
        return out

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Carry on from :meth:`state` (of an array of this shape; ``ValueError`` naming
        what does not fit, the field then as it was)."""
        rows, cols, memory = (int(v) for v in state["shape"])
        if (rows, cols) != (self.rows, self.cols):
            raise ValueError(f"learned for a {rows}x{cols} array, not {self.rows}x{self.cols}")
        n3 = 3 * rows * cols
        expect = {"ata": (n3, n3), "atb": (n3,), "_u": (n3,), "gain": (rows, cols),
                  "inverse_gain": (rows, cols), "dx": (rows, cols), "dy": (rows, cols)}
        if "covariance" in state:
            expect["covariance"] = (n3, n3)
        for name, shape in expect.items():
            arr = np.asarray(state[name], dtype=float)
            if arr.shape != shape or not np.all(np.isfinite(arr)):
                raise ValueError(f"{name}: not {shape} finite numbers")
        self.reset()
        self.memory, self._keep = memory, 1.0 - 1.0 / memory
        for name in ("_w", "_sw", "_sw2", "excess", "explained"):
            setattr(self, name, float(state[name]))
        self.fits, self._next_solve = int(state["fits"]), int(state["_next_solve"])
        self.active, self.solve_due = bool(state["active"]), bool(state["solve_due"])
        for name in self._ARRAYS:
            setattr(self, name, np.array(state[name], dtype=float))
        self._var = tuple(float(v) for v in state["var"])
        self.note = str(state["note"])
        self.covariance = np.array(state["covariance"], dtype=float) if "covariance" in state else None

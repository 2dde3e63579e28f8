"""How many contacts a frame holds: each extra one must pay for its parameters (docs/concepts/fitting.md)."""

# The strain of several contacts is the sum of theirs, so a frame is explained contact by
# contact (a greedy matching pursuit): after the contacts accepted so far, the next candidate is
# fitted where the frame less their predicted strain stands highest, outside their cores, and it
# is accepted only when it lowers the whole array's chi^2 (with the noise sigma, and the
# model-error floor where the sensor has one) by more than the Bayesian information criterion
# charges for its parameters,
#
#     chi^2(without) - chi^2(with) > k ln N,
#
# ``k`` the candidate's parameters (a line 4, a sphere 4, a cylinder 5, a general ellipse 6) and
# ``N`` the array's usable tactels.  Noise alone, fitted by a contact at its highest tactel,
# lowers chi^2 by about the largest of N chi-square(1) draws plus one per other parameter
# (~2 ln N + k; 15-17 on a 16x16 pad), under the charge (22-33 there), while a real contact
# whose peak stands 8 sigmas above the noise lowers it by hundreds.  A contact that explains a
# ridge, a line's, explains the ridge's every bump: they are not contacts of their own.  After
# the joint fit every contact must still pay its way with the others fitted (:func:`prune`).

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from tactiled.fit.auto import round_blob
from tactiled.fit.linewindow import runs_across
from tactiled.fit.models import get_model
from tactiled.fit.regions import SIGNIFICANT_Z, SUPPORT_Z, Region
from tactiled.fit.result import FitResult

#: A contact's tactels above this share of its predicted peak are its core: a candidate's
#: window stays out of them (there the accepted contact's small model error outweighs any
#: other contact's strain).
CORE_SHARE = 0.5


class Predictions:
    """A frame's contacts' predicted strains, each computed once: ``predict(res)`` is
    ``fn(res)`` (a strain on the whole array, or None), remembered while ``res`` holds the same
    parameters (a line's costs ~0.6 ms on a 16x16 array)."""

    def __init__(self, fn: Any) -> None:
        self.fn = fn
        self.memo: dict[int, tuple[FitResult, Any, np.ndarray | None]] = {}

    def __call__(self, res: FitResult) -> np.ndarray | None:
        hit = self.memo.get(id(res))
        if hit is not None and hit[0] is res and hit[1] == res.params:
            return hit[2]
        pred = self.fn(res)
        self.memo[id(res)] = (res, res.params, pred)
        return pred


def penalty(res: FitResult, n_tactels: int) -> float:
    """The information criterion's charge for the contact ``res``: ``k ln N``."""
    k = len(res.params) if res.params is not None else get_model(res.model or "sphere").size
    return k * math.log(max(n_tactels, 2))


def chi2(left: np.ndarray, sd: np.ndarray, usable: np.ndarray) -> float:
    """chi^2 of the residual frame ``left`` over the usable tactels, each by its sd."""
    z = left[usable] / sd[usable]
    return float(np.dot(z, z))


def region_of(fitter: Any, pred: np.ndarray) -> Region:
    """A contact's region from its predicted strain: its peak, and the tactels where it
    stands above the noise (``SUPPORT_Z`` sigmas)."""
    idx = np.unravel_index(int(np.argmax(pred)), pred.shape)
    peak = float(pred[idx])
    return Region((int(idx[0]), int(idx[1])), peak, pred > max(SUPPORT_Z * fitter.sigma, 1e-300))


def select(fitter: Any, strain: np.ndarray, flat: np.ndarray, model: str, usable: np.ndarray,
           first: FitResult, most: int, deadline: float | None,
           predict: Any, raw: Any) -> list[tuple[FitResult, np.ndarray]]:
    """The contacts the frame pays for, ``first`` (the frame fitted as one contact) first,
    each with its predicted strain: at most ``most``.  ``predict(res)`` is a result's strain
    on the whole array (after the flat field), ``raw`` takes such a strain back to the frame's
    scale; a candidate is sought only where the strain left unexplained stands above
    ``SIGNIFICANT_Z`` sigmas."""
    pred = predict(first)
    if pred is None:
        return []
    sd = fitter._tactel_sd(flat)
    n = int(usable.sum())
    total = pred.copy()
    accepted = [(first, pred)]
    cores = pred > CORE_SHARE * float(pred.max())
    floor = SIGNIFICANT_Z * fitter.sigma
    while len(accepted) < most:
        if deadline is not None and time.perf_counter() > deadline:
            break
        left = flat - total
        free = usable & ~cores
        if not free.any() or float(np.max(left[free])) <= floor:
            break
        budget = None if deadline is None else max(deadline - time.perf_counter(), 0.0)
        rest = strain - raw(total)
        cand_model, round_first = model, False
        if model == "auto" and fitter.sensor.geometry.flat:
            across, band = runs_across(fitter, fitter.flattened(rest), free)
            if across:
                cand_model = "cylinder"  # a ridge across the array: a line, no ellipse search
            else:  # a ball's round blob: the sphere alone, if it explains it
                round_first = band is not None and round_blob(band)
        with fitter.selector.among_several(round_blob=round_first):
            cand = fitter.fit(rest, cand_model, mask=free, budget_s=budget)
        cand_pred = predict(cand) if cand.contact else None
        if cand_pred is None:
            break
        gain = chi2(left, sd, usable) - chi2(left - cand_pred, sd, usable)
        if not gain > penalty(cand, n):
            break  # the highest unexplained place is no contact: none lower is either
        accepted.append((cand, cand_pred))
        total += cand_pred
        cores |= cand_pred > CORE_SHARE * float(cand_pred.max())
    return accepted


def unexplained(fitter: Any, flat: np.ndarray, usable: np.ndarray, res: FitResult,
                predict: Any) -> bool:
    """The frame less ``res``'s strain still stands, outside its core, above ``SIGNIFICANT_Z``
    sigmas: strain that one contact does not explain."""
    pred = predict(res)
    if pred is None:
        return False
    free = usable & ~(pred > CORE_SHARE * float(pred.max()))
    return bool(free.any()) and float(np.max((flat - pred)[free])) > SIGNIFICANT_Z * fitter.sigma


def pays_against(fitter: Any, flat: np.ndarray, usable: np.ndarray, one: np.ndarray,
                 kept: list[tuple[FitResult, np.ndarray]]) -> bool:
    """Do the contacts ``kept`` (each with its predicted strain) explain the frame better
    than the single contact whose strain is ``one`` (fitted on all the tactels it presses)
    by more than the information criterion charges for every contact beyond the first?"""
    sd = fitter._tactel_sd(flat)
    n = int(usable.sum())
    total = sum(p for _, p in kept)
    gain = chi2(flat - one, sd, usable) - chi2(flat - total, sd, usable)
    return gain > sum(penalty(r, n) for r, _ in kept[1:])


def could_pay_against(fitter: Any, flat: np.ndarray, usable: np.ndarray, one: np.ndarray,
                      kept: list[tuple[FitResult, np.ndarray]]) -> bool:
    """Could the contacts ``kept`` beyond the first pay against the single contact whose
    strain is ``one`` (:func:`pays_against`), before their joint fit?  What they can gain is
    bounded by the strain ``one`` leaves over their footprints (the tactels where their
    predicted strain stands ``SUPPORT_Z`` sigmas above the noise): a residual chi^2 there
    within the information criterion's charge for them is the noise, which no further contact
    pays for (a cheap check: the joint fit of contacts that then fail is the costly part)."""
    sd = fitter._tactel_sd(flat)
    n = int(usable.sum())
    floor = max(SUPPORT_Z * fitter.sigma, 1e-300)
    footprint = np.zeros(flat.shape, bool)
    for _, p in kept[1:]:
        footprint |= p > floor
    bound = chi2(flat - one, sd, usable & footprint)
    return bound > sum(penalty(r, n) for r, _ in kept[1:])


def prune(fitter: Any, flat: np.ndarray, usable: np.ndarray, results: list[FitResult],
          predict: Any) -> list[FitResult]:
    """``results`` less each contact that, the others fitted, no longer pays its
    information criterion (the weakest first, one at a time)."""
    out = list(results)
    sd = fitter._tactel_sd(flat)
    n = int(usable.sum())
    while len(out) > 1:
        preds = [predict(r) for r in out]
        total = sum(p for p in preds if p is not None)
        left = flat - total
        base = chi2(left, sd, usable)
        gains = [math.inf if p is None else chi2(left + p, sd, usable) - base - penalty(r, n)
                 for r, p in zip(out, preds)]
        worst = int(np.argmin(gains))
        if gains[worst] > 0.0:
            break
        out.pop(worst)
    return out

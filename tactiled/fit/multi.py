"""Several contacts on one array: each pressed region fitted, the neighbours' strain accounted for."""

# The physics is linear in the pressure, so the strain of several contacts is the sum of their
# strains.  :func:`fit_contacts` fits the frame as one contact first (:meth:`Fitter.fit`: a
# one-contact frame gets the same result bit for bit), then looks at the frame's other separate
# regions (:func:`tactiled.fit.regions.find_regions`): those whose peak that contact's strain
# leaves unexplained are contacts of their own.  With several, each contact is fitted on the frame less its neighbours' predicted strain (block coordinate descent on the
# joint least-squares problem: ``SWEEPS`` passes, each contact refitted from where the last pass
# left it), with the neighbours' cores left out of its window while their own fits are rough.
# When every contact was there in the last frame (``warm``), their last fits predict the
# neighbours' strain from the start and one pass does.
#
# Each contact's sigmas are those of the joint model: the fitter's own (its window, its
# model-error floor) times the ratio of the joint Cramer-Rao bound, where the neighbours'
# parameters are unknown too, to the bound with them known, both on the union of the contacts'
# windows (:func:`joint_bounds`).  Far apart the ratio is 1; contacts whose strains overlap share
# information and each one's sigmas widen accordingly.  No I/O.

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from tactiled.fit.auto import round_blob
from tactiled.fit.budget import stopped_by_budget
from tactiled.fit.linearize import SeveralLinearizations
from tactiled.fit.models import get_model
from tactiled.fit.params import VALUE_KEYS
from tactiled.fit.pointstrain import point_strain
from tactiled.fit.regions import (
    ABSORBED_SHARE,
    SIGNIFICANT_Z,
    Region,
    find_regions,
)
from tactiled.fit.linewindow import bounding_window, runs_across
from tactiled.fit.result import FitResult
from tactiled.fit.selection import (CORE_SHARE, Predictions, could_pay_against, pays_against,
                                    prune, region_of, select, unexplained)
from tactiled.fit.wide import wide_fit
from tactiled.fit.warm import SEVERAL, nearest_start
from tactiled.physics.contact import LineContact

#: Passes over the contacts (the first fits each from cold, the second from the first).
SWEEPS = 2
#: What a result says when it is one of several.
SEVERAL_REASON = "one of {n} contacts on this array: fitted with its neighbours' strain removed"
MERGED_REASON = ("another pressed place within the cover's spread of this one, or strain this "
                 "contact does not explain that no second contact pays for: several contacts "
                 "too close to tell apart, reported as one")


def predicted_strain(fitter: Any, res: FitResult) -> np.ndarray | None:
    """The strain ``res`` predicts on the whole array, as the fits read frames (after the
    flat field), or None when it predicts nothing (no contact, a withheld place)."""
    if not res.contact or res.params is None or res.model is None:
        return None
    m = fitter.model
    if res.line is not None or (fitter.sensor.geometry.flat and res.model == "cylinder"):
        v, line = res.values, res.line or {}
        if v.get("x_mm") is None or v.get("y_mm") is None or not line.get("load_n_per_mm"):
            return None
        p = res.params
        try:
            contact = LineContact(math.exp(p[0]), math.degrees(p[1]),
                                  float(line["load_n_per_mm"]), float(v["x_mm"]), float(v["y_mm"]))
            return m.predict(contact, m.xs_full, m.ys_full)
        except (ValueError, OverflowError):
            return None  # a line too wide to integrate (a radius the frame leaves open)
    return point_strain(fitter, res.model, res.params)


def _raw(fitter: Any, flat_strain: np.ndarray) -> np.ndarray:
    """A strain as the fits read it, back to the frame's own scale (the flat field's gains)."""
    f = fitter.flat
    return flat_strain / f.inverse_gain if f is not None and f.active else flat_strain


def fit_contacts(fitter: Any, strain: np.ndarray, model: str = "cylinder",
                 mask: np.ndarray | None = None, warm: tuple[str, tuple[float, ...]] | None = None,
                 budget_s: float | None = None) -> list[FitResult]:
    """Every contact of a zeroed strain frame, the highest peak's first (see the module's doc).

    When every separate region (:func:`find_regions`) is a different one of the contacts
    the last frame held (``warm`` of several, each region's peak within the cover's spread of
    one), they are fitted as several at once, each from where it was.  Otherwise the frame is
    fitted as one contact first, exactly as :meth:`Fitter.fit` does
    (``fitter.fit(strain, model, mask=mask, warm=warm, budget_s=budget_s)``).  Each other
    separate region (:func:`find_regions`) whose peak that contact's strain leaves unexplained
    (:func:`_unexplained`) is a contact of its own: then every contact is fitted with its
    neighbours' strain removed, one FitResult each, every one carrying ``reasons["contacts"]``,
    ``budget_s`` bounding them all together.  Otherwise the one fit is the answer, labelled
    ``merged`` when its region holds a second maximum that the fit does not explain (two
    contacts closer than the cover spreads them).
    """
    # a line's band is made once per strain and mask; a point fit's profile tests run only on
    # the results published (Fitter.deferring: most of those a frame of several seeks are refitted)
    with fitter.line.frames.kept(), fitter.deferring():
        return [fitter.finish(r) for r in _fit_contacts(fitter, strain, model, mask, warm, budget_s)]


def _fit_contacts(fitter: Any, strain: np.ndarray, model: str, mask: np.ndarray | None,
                  warm: tuple[str, tuple[float, ...]] | None, budget_s: float | None) -> list[FitResult]:
    """:func:`fit_contacts`' body."""
    t0 = time.perf_counter()
    flat = fitter.flattened(strain)
    regions = find_regions(flat, fitter.sigma, mask)
    starts = [_start_for(fitter, reg, warm) for reg in regions]
    if _all_held(warm, starts):
        return _fit_several(fitter, np.asarray(strain, dtype=float), model, mask, regions,
                            budget_s, starts)
    first_warm = warm
    if warm is not None and warm[0] == SEVERAL:  # the last frame's contact at the highest peak
        first_warm = starts[0] if starts else None
    first_model, round_first = model, False
    # the first of several separate regions is fitted as one of several contacts (below);
    # if one contact is found after all, it is fitted again as Fitter.fit does
    several = model == "auto" and first_warm is None and len(regions) > 1
    flat_array = fitter.sensor.geometry.flat
    if several and flat_array:
        # a ridge across the array beside other contacts is a line: fitted as one, without
        # auto's search of the ellipses that its neighbours' strain in its band would start;
        # a round blob beside them that the sphere explains is a ball, without auto's scouts
        across, seen = runs_across(fitter, flat, mask)
        if across and any(not seen[reg.peak_idx] for reg in regions):
            first_model = "cylinder"
        round_first = not across and seen is not None and round_blob(seen)
    with fitter.selector.among_several(several, round_first):
        res = fitter.fit(strain, first_model, mask=mask, warm=first_warm, budget_s=budget_s)
    usable = np.isfinite(flat) if mask is None else np.asarray(mask, dtype=bool) & np.isfinite(flat)
    predict = Predictions(lambda r: predicted_strain(fitter, r))
    kept: list = []
    # one region that its one contact leaves standing out of the noise beyond its core may
    # hold two (crossing cylinders, a ball against a line): a second is sought there, and kept
    # if it pays its way.  (A line the noise explains on its band, every tactel that sees it,
    # is not checked: its whole-array strain is the costliest prediction.)
    one = (len(regions) == 1 and res.contact and res.chi2 is not None
           and not (res.line is not None and fitter._consistent(res))
           and unexplained(fitter, flat, usable, res, predict))
    # a point contact the budget stopped on its window, alone on the array, may be wider
    # than it (a hard press on a fine array): it is fitted on all it presses, from cold
    stopped = (len(regions) == 1 and res.contact and not res.converged
               and stopped_by_budget(res))
    wide = (wide_fit(fitter, strain, flat, usable, mask, res, budget_s, t0)
            if (one or stopped) and _is_point(fitter, res) else None)
    explains = wide is not None and not unexplained(fitter, flat, usable, wide, predict)
    if res.contact and (len(regions) > 1 or one):
        deadline = None if budget_s is None else t0 + budget_s
        with fitter.selector.among_several():
            kept = select(fitter, np.asarray(strain, dtype=float), flat, model, usable, res,
                          max(len(regions), 2), deadline, predict, lambda s: _raw(fitter, s))
    if len(kept) > 1 and wide is not None and predict(wide) is not None and not could_pay_against(
            fitter, flat, usable, predict(wide), kept):
        kept = []  # the one fitted on all it presses leaves the others' footprints to the noise
    if len(kept) > 1:
        left = None if budget_s is None else max(budget_s - (time.perf_counter() - t0), 0.0)
        found = _fit_several(fitter, np.asarray(strain, dtype=float), model, mask,
                             [region_of(fitter, p) for _, p in kept], left,
                             [None] * len(kept), first=[r for r, _ in kept], predict=predict)
        paying = prune(fitter, flat, usable, found, predict)
        # a contact whose place the one rule withholds, wholly or along one axis (a position's
        # sigma beyond the array), is strain the others leave unexplained, not a contact found
        out = [r for r in paying if _located(r)]
        if wide is not None and len(out) > 1 and not pays_against(
                fitter, flat, usable, predict(wide), [(r, predict(r)) for r in out]):
            out = []  # the contacts do not pay against the one fitted on all it presses
        if len(out) > 1:
            elapsed = (time.perf_counter() - t0) * 1e3
            for r in out:
                r.fit_ms = elapsed  # the whole frame's: the contacts' choice and fits together
                if len(out) < len(found):
                    r.reasons["contacts"] = SEVERAL_REASON.format(n=len(out))
            return out
        if wide is None:  # the joint fit left one contact paying its way: it alone, fitted alone
            alone = fitter.finish(fitter.fit(strain, model, mask=mask, warm=first_warm, budget_s=left))
            if len(out) < len(paying) and alone.contact:
                alone.label = "merged"
                alone.reasons["contacts"] = MERGED_REASON
            return [alone]
    if wide is not None and (one or explains):
        # one contact, fitted on all it presses; merged where even so it leaves strain standing
        res, one = wide, not explains
    if round_first or (several and not flat_array):  # one contact: Fitter.fit's answer
        res = fitter.fit(strain, model, mask=mask, warm=first_warm, budget_s=budget_s)
    fitter.finish(res)
    if res.contact and regions and (
            (regions[0].absorbed and _merged(fitter, flat, res, regions[0]))
            or one):
        res.label = "merged"
        res.reasons["contacts"] = MERGED_REASON
    return [res]


def _chosen_on_the_whole(fitter: Any, res: FitResult) -> bool:
    """A general ellipse on a curved array, refitted with its neighbours' strain removed in
    the model chosen on the whole frame: the cylinder is tried again there
    (:meth:`tactiled.fit.auto.ModelSelector.simpler`)."""
    return (res.contact and res.model == "general" and res.params is not None
            and not fitter.sensor.geometry.flat)


def _located(r: FitResult) -> bool:
    """The contact has a place: a line (its position across is its offset), or a point
    contact whose centre the one rule publishes, both coordinates (one withheld leaves the
    contact anywhere along a line across the array: no place, as none)."""
    return r.line is not None or (r.values.get("x_mm") is not None and r.values.get("y_mm") is not None)


def _all_held(warm: Any, starts: list[tuple[str, tuple[float, ...]] | None]) -> bool:
    """Every pressed region is a contact of the last frame's several (``warm``), each a
    different one: the frame holds the same contacts, to be fitted as several at once from
    where they were.  (Fitted first as one contact, such a frame's model search runs cold
    on a window the neighbours' strain makes inconsistent with any one contact, only to find
    the others again.)"""
    return (warm is not None and warm[0] == SEVERAL and len(starts) > 1
            and all(st is not None for st in starts)
            and len({(st[0], tuple(st[1])) for st in starts}) == len(starts))


def _merged(fitter: Any, flat: np.ndarray, res: FitResult, region: Region) -> bool:
    """A second maximum the cover merged into ``region`` that the one contact ``res`` does not
    explain (its strain there stands out as the maximum did: two contacts fitted as one); a
    ridge sampled as several bumps is explained by its contact."""
    pred = predicted_strain(fitter, res)
    if pred is None:
        return False
    floor = SIGNIFICANT_Z * fitter.sigma
    for (m, n), height in region.absorbed_at:
        rest = float(flat[m, n] - pred[m, n])
        if rest > floor and rest > ABSORBED_SHARE * height:
            return True
    return False


def _start_for(fitter: Any, region: Region, warm: Any) -> tuple[str, tuple[float, ...]] | None:
    """The warm start of the last frame's contact at ``region``'s peak, if any: ``warm`` is
    one contact's ``(model, params)`` or several's ``(SEVERAL, (...))``."""
    if warm is None or not warm[1]:
        return None
    warms = warm[1] if warm[0] == SEVERAL else (warm,)
    m, n = region.peak_idx
    imp = fitter.sensor.impulse
    return nearest_start(tuple(warms), float(fitter.model.xs_full[m]), float(fitter.model.ys_full[n]),
                         max(imp.depth_x, imp.depth_y))


def warm_of(results: list[FitResult]) -> tuple[str, Any] | None:
    """What the next frame's fit starts from: one contact's ``(model, params)`` when it
    converged, several's ``(SEVERAL, ((model, params), ...))``."""
    if len(results) == 1:
        r = results[0]
        return (r.model, r.params) if r.converged and r.params is not None and r.model else None
    each = tuple((r.model, r.params) for r in results if r.contact and r.params is not None and r.model)
    return (SEVERAL, each) if each else None


def _fit_several(fitter: Any, strain: np.ndarray, model: str, mask: np.ndarray | None,
                 regions: list[Region], budget_s: float | None,
                 starts: list[tuple[str, tuple[float, ...]] | None],
                 first: list[FitResult] | None = None, predict: Any = None) -> list[FitResult]:
    """Each contact (one per region) fitted on the frame less the others' strain; ``first``:
    each one's fit so far (:func:`tactiled.fit.selection.select`'s), which one pass refines;
    ``predict``: a result's strain on the whole array (default :func:`predicted_strain`)."""
    if predict is None:
        predict = lambda r: predicted_strain(fitter, r)  # noqa: E731
    t0 = time.perf_counter()
    k = len(regions)
    usable = np.ones(strain.shape, bool) if mask is None else np.asarray(mask, dtype=bool)
    preds: list[np.ndarray | None] = [None] * k
    results: list[FitResult | None] = [None] * k
    if first is not None:
        results = list(first)
        preds = [predict(r) for r in first]
    # every contact held since the last frame: its neighbours' strain is known from their
    # last fits at once, and one pass does what the cold start's two do
    if all(st is not None for st in starts):
        preds = [point_strain(fitter, *st) for st in starts]  # type: ignore[misc]
    warm_all = all(p is not None for p in preds)
    sweeps = 1 if warm_all or first is not None else SWEEPS
    frozen = fitter.frozen
    fitter.frozen = True  # a frame less a model is no evidence of the tactels' gains
    try:
        for sweep in range(sweeps):
            for i, reg in enumerate(regions):
                if first is not None and i == k - 1:
                    continue  # the last chosen was fitted on the frame less all the others
                others = [j for j in range(k) if j != i]
                residual = strain.copy()
                m = usable.copy()
                for j in others:
                    if preds[j] is not None:
                        residual -= _raw(fitter, preds[j])
                        if sweep or warm_all or first is not None:
                            m &= ~(regions[j].tactels & (preds[j] > CORE_SHARE * regions[j].peak))
                        else:
                            m &= ~regions[j].tactels
                    else:
                        m &= ~regions[j].tactels
                left = None
                if budget_s is not None:
                    left = max(budget_s - (time.perf_counter() - t0), 0.0) / max(
                        (sweeps - sweep) * k - i, 1)
                prev = results[i]
                warm = (starts[i] if prev is None else None if prev.params is None or prev.model is None
                        else (prev.model, prev.params))
                fit_model = (prev.model if first is not None and prev is not None and prev.model
                             else model if model == "auto" or prev is None else prev.model or model)
                res = fitter.fit(residual, fit_model, mask=m, warm=warm, budget_s=left)
                if first is not None and model == "auto" and _chosen_on_the_whole(fitter, res):
                    # its model was chosen with its neighbours' strain in its window: where
                    # the cylinder explains the window less theirs, the cylinder (auto's rule
                    # among several on a curved array, ModelSelector.plain)
                    if left is not None:  # what the refit left of this contact's share
                        left = max(left - res.fit_ms * 1e-3, 0.0)
                    if left is None or left > 0.0:
                        with fitter.selector.instead_of(res):
                            plain = fitter.fit(residual, model, mask=m, budget_s=left)
                        if plain.contact:
                            res = plain
                if prev is not None and not res.contact:
                    res = prev  # the refinement lost it: keep the first pass's
                results[i] = res
                preds[i] = predict(res)
    finally:
        fitter.frozen = frozen
    out = [fitter.finish(r) for r in results if r is not None]
    deadline = None if budget_s is None else t0 + budget_s
    for group in _overlapping(fitter, out):
        _refine_jointly(fitter, strain, usable, out, group, deadline, predict)
    _widen_by_neighbours(fitter, out, usable)
    elapsed = (time.perf_counter() - t0) * 1e3
    for r in out:
        r.reasons["contacts"] = SEVERAL_REASON.format(n=k)
        r.fit_ms = elapsed
    return out


# -- the tracker's linearisations --------------------------------------------------------------

def linearize_several(fitter: Any, strain: np.ndarray, contacts: list[tuple[str, tuple[float, ...]]],
                      mask: np.ndarray | None = None) -> SeveralLinearizations | None:
    """Each point contact of ``contacts`` (``(model, internal params)``) linearised on the
    frame less the others' strain at their parameters, with the others' cores (their strain
    above ``CORE_SHARE`` of its peak) out of its window, as the last pass of
    :func:`_fit_several` fits it; None when one has no linearisation (a line contact, a
    singular window): such a frame's contacts are fitted, not tracked."""
    from tactiled.fit.linearize import linearize, whole_array

    strain = np.asarray(strain, dtype=float)
    usable = np.ones(strain.shape, bool) if mask is None else np.asarray(mask, dtype=bool)
    preds = []
    for model, params in contacts:
        if model not in ("cylinder", "sphere", "general") or (
                fitter.sensor.geometry.flat and model == "cylinder"):
            return None  # a line contact has no centre to track
        pred = whole_array(fitter, get_model(model), np.asarray(params, dtype=float))
        if pred is None:
            return None
        preds.append(pred)
    lins = []
    for i, (model, params) in enumerate(contacts):
        residual = strain.copy()
        m = usable.copy()
        for j, pred in enumerate(preds):
            if j != i:
                residual -= _raw(fitter, pred)
                m &= ~(pred > CORE_SHARE * float(pred.max()))
        lin = linearize(fitter, residual, model, np.asarray(params, dtype=float), m, whole=preds[i])
        if lin is None:
            return None
        lins.append(lin)
    return SeveralLinearizations(tuple(lins))


# -- neighbours fitted jointly ---------------------------------------------------------------

def _is_point(fitter: Any, r: FitResult) -> bool:
    return bool(r.contact and r.params is not None and r.model and r.line is None
                and not (fitter.sensor.geometry.flat and r.model == "cylinder"))


def _overlapping(fitter: Any, results: list[FitResult]) -> list[list[int]]:
    """Groups (indices into ``results``) of two or more point contacts whose windows overlap,
    directly or through a third."""
    idx = [i for i, r in enumerate(results) if _is_point(fitter, r) and r.window is not None]
    parent = {i: i for i in idx}

    def find(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    for a in idx:
        for b in idx:
            if a < b and _windows_meet(results[a].window, results[b].window):
                parent[find(b)] = find(a)
    groups: dict[int, list[int]] = {}
    for i in idx:
        groups.setdefault(find(i), []).append(i)
    return [g for g in groups.values() if len(g) > 1]


def _windows_meet(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> bool:
    return not (a[0] + a[2] <= b[0] or b[0] + b[2] <= a[0] or a[1] + a[3] <= b[1] or b[1] + b[3] <= a[1])


def _refine_jointly(fitter: Any, strain: np.ndarray, usable: np.ndarray, results: list[FitResult],
                    group: list[int], deadline: float | None, predict: Any = None) -> None:
    """Fit the contacts ``group`` together on the union of their windows, the model the sum of
    their strains (the others' predicted strain removed), and move each to the joint
    solution: its values from there, its sigmas kept (they are widened for the shared
    information afterwards); ``predict``: a result's strain on the whole array (default
    :func:`predicted_strain`; the frame's memo, so a line's is not computed again)."""
    from tactiled.fit.search import bounds_of as _bounds
    from tactiled.fit.search import steps_of as _steps
    from tactiled.fit.solver import levenberg_marquardt

    shape = usable.shape
    tact = np.zeros(shape, bool)
    for i in group:
        tact |= _window_mask(shape, results[i].window)
    tact &= usable
    if not tact.any():
        return
    r0, c0, nr, nc = bounding_window(tact)  # the model evaluated on the windows' box alone
    box = (slice(r0, r0 + nr), slice(c0, c0 + nc))
    xs, ys = fitter.model.xs_full[box[0]], fitter.model.ys_full[box[1]]
    rows = tact[box].ravel()
    flat = fitter.flattened(strain)
    target = flat[box].ravel()[rows].copy()
    for j, r in enumerate(results):
        if j not in group:
            pred = predicted_strain(fitter, r) if predict is None else predict(r)
            if pred is not None:
                target -= pred[box].ravel()[rows]
    sd = fitter._tactel_sd(target)
    models = [get_model(results[i].model) for i in group]
    sizes = [m.size for m in models]
    p0 = np.concatenate([np.asarray(results[i].params, dtype=float) for i in group])
    lo = np.concatenate([_bounds(m)[0] for m in models])
    hi = np.concatenate([_bounds(m)[1] for m in models])
    steps = np.concatenate([_steps(m) for m in models])

    def residual(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pred = np.zeros(target.size)
        jac = np.empty((target.size, p.size))
        at = 0
        for m, n in zip(models, sizes):
            phys, dphys = m.physical(p[at:at + n])
            val, j6, _ = fitter.model.strain_and_jacobian(*phys, xs, ys)
            pred += np.asarray(val).ravel()[rows]
            jac[:, at:at + n] = np.asarray(j6).reshape(-1, 6)[rows] @ dphys
            at += n
        return (pred - target) / sd, jac / sd[:, None]

    before = float(np.sum(residual(p0)[0] ** 2))
    sol = levenberg_marquardt(residual, p0, max_step=steps, max_iter=30, atol=1e-4,
                              deadline=deadline, bounds=(lo, hi))
    if not (np.all(np.isfinite(sol.p)) and sol.cost <= before):
        return
    at = 0
    for i, m, n in zip(group, models, sizes):
        r = results[i]
        p = sol.p[at:at + n]
        at += n
        values, _ = m.report(p)
        for key, v in values.items():
            if r.values.get(key) is not None and v is not None:
                r.values[key] = v
        r.params = tuple(float(v) for v in p)
        r.chi2 = sol.cost
        phys, _ = m.physical(p)
        ell, _ = fitter.model.ellipse(*phys[:4])
        if r.ellipse is not None:
            r.ellipse = {"a_mm": ell.a, "b_mm": ell.b, "theta_deg": math.degrees(ell.theta) % 180.0}


# -- the joint bound -------------------------------------------------------------------------

def _point_jacobian(fitter: Any, model: str, params: tuple[float, ...],
                    window: tuple[int, int, int, int] | None = None) -> np.ndarray | None:
    """d(strain on the whole array, or on ``window``)/d(internal parameters), ``(tactels,
    size)``; None for a contact that is not a point contact of a known model."""
    try:
        phys, dphys = get_model(model).physical(np.asarray(params, dtype=float))
    except (ValueError, KeyError):
        return None  # (as point_contact: no point contact)
    m = fitter.model
    xs, ys = m.xs_full, m.ys_full
    if window is not None:
        r0, c0, nr, nc = window
        xs, ys = xs[r0:r0 + nr], ys[c0:c0 + nc]
    _, jac, _ = m.strain_and_jacobian(*(float(v) for v in phys), xs, ys)
    return jac.reshape(-1, 6) @ dphys


def _window_mask(shape: tuple[int, int], win: tuple[int, int, int, int] | None) -> np.ndarray:
    out = np.zeros(shape, bool)
    if win is not None:
        r0, c0, nr, nc = win
        out[r0:r0 + nr, c0:c0 + nc] = True
    return out


def joint_bounds(fitter: Any, contacts: list[tuple[str, tuple[float, ...]]],
                 tactels: np.ndarray) -> tuple[list[dict[str, float | None]], list[dict[str, float | None]]] | None:
    """The Cramer-Rao bounds (user units, ``VALUE_KEYS``) of each point contact
    ``(model, internal params)`` on the usable ``tactels`` (a boolean frame): ``(joint,
    alone)``, joint with every contact's parameters unknown, alone with the others' known.
    None when a contact is not a point contact or the information is singular.  (Computed
    once per frame of several contacts: each contact's Jacobian on the tactels' box once,
    every inverse and delta-method variance with one floating-point guard.)"""
    if not tactels.any():
        return None
    win = bounding_window(tactels)  # the tactels' box: the Jacobians there alone
    r0, c0, nr, nc = win
    rows = tactels[r0:r0 + nr, c0:c0 + nc].ravel()
    sd = fitter._tactel_sd(np.zeros(int(rows.sum()))) if hasattr(fitter, "_tactel_sd") else None
    scale = np.reshape(1.0 / (sd if sd is not None else fitter.sigma), (-1, 1))
    blocks = []
    for m, p in contacts:
        jac = _point_jacobian(fitter, m, p, win)
        if jac is None:
            return None
        blocks.append(jac[rows] * scale)
    full = np.hstack(blocks)
    size = full.shape[1]
    # the joint information and, block-diagonal, each contact's alone: inverted in one call
    info = np.zeros((2, size, size))
    info[0] = full.T @ full
    grad = np.full((6 * len(blocks), size), np.nan)  # each contact's rows: its own block
    start = 0
    for i, ((m, p), b) in enumerate(zip(contacts, blocks)):
        n = b.shape[1]
        info[1, start:start + n, start:start + n] = b.T @ b
        grad[6 * i:6 * i + 6, :] = 0.0
        grad[6 * i:6 * i + 6, start:start + n] = get_model(m).report(np.asarray(p, dtype=float))[1]
        start += n
    with np.errstate(invalid="ignore"):
        try:
            cov = np.linalg.inv(info)
        except np.linalg.LinAlgError:
            return None
        var = np.einsum("ki,sij,kj->sk", grad, cov, grad)
    joint = [_user_std(var[0, 6 * i:6 * i + 6]) for i in range(len(blocks))]
    alone = [_user_std(var[1, 6 * i:6 * i + 6]) for i in range(len(blocks))]
    return joint, alone


def _user_std(var: np.ndarray) -> dict[str, float | None]:
    """1-sigma of each user value from its variance (delta method, ``VALUE_KEYS``' order);
    None for a value the model lacks (its gradient row is NaN: a NaN variance) or a
    negative variance."""
    return {key: math.sqrt(v) if v >= 0.0 and v < math.inf else None
            for key, v in zip(VALUE_KEYS, var.tolist())}


def _widen_by_neighbours(fitter: Any, results: list[FitResult], usable: np.ndarray) -> None:
    """Each contact's sigmas times (joint bound / bound with the neighbours known), on the
    union of the windows: the information its neighbours' unknowns take from it."""
    point = [r for r in results if _is_point(fitter, r)]
    if len(point) < 2:
        return
    shape = usable.shape
    union = np.zeros(shape, bool)
    for r in point:
        union |= _window_mask(shape, r.window)
    bounds = joint_bounds(fitter, [(r.model, r.params) for r in point], union & usable)
    if bounds is None:
        return
    for r, joint, alone in zip(point, *bounds):
        for key in VALUE_KEYS:
            s, j, a = r.std.get(key), joint.get(key), alone.get(key)
            if s is not None and j is not None and a:
                r.std[key] = s * max(j / a, 1.0)


def strongest(results: list[FitResult]) -> int:
    """Index of the contact with the largest force (a line contact, whose total force does not
    exist, by its peak strain after every point contact of any force)."""
    def key(i: int) -> tuple[int, float, float]:
        r = results[i]
        f = r.values.get("force_n")
        return (int(r.contact), -1.0 if f is None else f, r.peak or 0.0)
    return max(range(len(results)), key=key)


def contacts_json(results: list[FitResult]) -> dict[str, Any]:
    """The ``tactiled fit`` line of a frame's contacts: the strongest contact's keys at the top
    (what a single-contact client reads), and with several, ``contacts``: every contact's,
    the strongest first."""
    first = strongest(results)
    top = results[first].to_json_dict()
    if len(results) > 1:
        rest = [r.to_json_dict() for i, r in enumerate(results) if i != first]
        top["contacts"] = [dict(top), *rest]
    return top

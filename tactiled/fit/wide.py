"""A contact wider than the fit's window: fitted on every tactel it presses.

A point fit reads a small square window round the peak (4x4 by default: the paper's, and a
millisecond's fit).  A hard press on a fine array (10-25 N ellipsoids on the 12x32 mat, a
contact ellipse 15-30 mm long at 2 mm pitch) presses tens of tactels beyond it: the window's
fit, extrapolated, leaves strain standing above the noise there, which the several-contacts
search would take for a second contact, and a cold search on the small window wanders into
ever longer ellipses until the budget stops it.  Such a contact is fitted again on the window
of every tactel it presses (:func:`pressed_window`), its work budget scaled to that window
(``Fitter.on_window``), from where its window's fit left it when that converged, else from
the pressed tactels' moments (:func:`moment_start`): their centroid, and the Hertz ellipse
whose semi-axes and direction their second moments give (a Hertz pressure's second moment
along an axis of semi-axis ``a`` is ``a^2 / 5``).  No I/O.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from tactiled.fit.budget import stopped_by_budget
from tactiled.fit.linewindow import bounding_window, ridge_band
from tactiled.fit.models import get_model
from tactiled.fit.regions import SIGNIFICANT_Z
from tactiled.fit.result import FitResult
from tactiled.fit.start import force_estimate
from tactiled.physics.hertz import contact_ellipse

#: A Hertz pressure's second moment along an axis of semi-axis ``a``, over ``a^2``.
HERTZ_MOMENT = 0.2
#: Gauss-Newton steps of the moments' ellipse (each a Hertz solve, no quadrature).
ELLIPSE_STEPS = 30


def pressed_tactels(fitter: Any, flat: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """The tactels 8-connected to the frame's peak that stand above ``SIGNIFICANT_Z`` sigmas
    (the strain a contact must explain), grown by one tactel on every side (the flanks)."""
    clean = np.ascontiguousarray(np.where(usable, flat, 0.0), dtype=float)
    m, n = np.unravel_index(int(np.argmax(clean)), clean.shape)
    return ridge_band(clean, np.ascontiguousarray(usable, dtype=np.bool_), int(m), int(n),
                      SIGNIFICANT_Z * fitter.sigma)


def pressed_window(fitter: Any, flat: np.ndarray, usable: np.ndarray,
                   res: FitResult) -> tuple[int, int, int, int] | None:
    """The bounding box of :func:`pressed_tactels`; None when it lies within ``res``'s own
    window (nothing beyond it to fit)."""
    if not flat.size or res.window is None:
        return None
    tactels = pressed_tactels(fitter, flat, usable)
    if not tactels.any():
        return None
    win = bounding_window(tactels)
    r0, c0, nr, nc = res.window
    if win[0] >= r0 and win[1] >= c0 and win[0] + win[2] <= r0 + nr and win[1] + win[3] <= c0 + nc:
        return None
    return win


def moment_start(fitter: Any, model: str, flat: np.ndarray, tactels: np.ndarray) -> np.ndarray | None:
    """An internal parameter vector of ``model`` from the strain's moments over ``tactels``
    (see the module's doc); None when they give no ellipse."""
    w = np.where(tactels, np.clip(flat, 0.0, None), 0.0)
    total = float(w.sum())
    if not total > 0.0:
        return None
    m = fitter.model
    X, Y = np.meshgrid(m.xs_full, m.ys_full, indexing="ij")
    cx, cy = float((w * X).sum() / total), float((w * Y).sum() / total)
    dx, dy = X - cx, Y - cy
    cov = np.array([[(w * dx * dx).sum(), (w * dx * dy).sum()],
                    [(w * dx * dy).sum(), (w * dy * dy).sum()]]) / total
    vals, vecs = np.linalg.eigh(cov)
    if not vals[0] > 0.0:
        return None
    a, b = math.sqrt(vals[1] / HERTZ_MOMENT), math.sqrt(vals[0] / HERTZ_MOMENT)
    theta = math.atan2(vecs[1, 1], vecs[0, 1]) % math.pi
    force = force_estimate(flat, fitter.sensor, cx, cy)
    curv = _curvatures(fitter, a, b, theta, force)
    if curv is None:
        return None
    ka, kb, psi = curv
    r1, r2 = 1.0 / max(ka, kb), 1.0 / min(ka, kb)
    if model == "sphere":
        r1 = r2 = math.sqrt(r1 * r2)
    return get_model(model).from_values(r1, r2, math.degrees(psi), force, cx, cy)


def _curvatures(fitter: Any, a: float, b: float, theta: float,
                force: float) -> tuple[float, float, float] | None:
    """The curvatures ``(kappa_a, kappa_b, psi)`` whose Hertz ellipse at ``force`` has the
    semi-axes ``a >= b`` and major-axis direction ``theta``: Gauss-Newton on their logs and
    the angle, from a ball of the ellipse's mean size."""
    m = fitter.model
    target = np.array([math.log(a), math.log(b), theta])
    u = np.array([0.0, 0.0, theta])
    ell, _ = m.ellipse(1.0, 1.0, theta, force)
    u[:2] = 3.0 * math.log(math.sqrt(ell.a * ell.b) / math.sqrt(a * b))  # a ~ kappa^(-1/3)
    u[1] -= 0.1  # off the ball, where the direction is undefined
    for _ in range(ELLIPSE_STEPS):
        ka, kb = math.exp(u[0]), math.exp(u[1])
        try:
            ell, jac = m.ellipse(ka, kb, u[2], force, jac=True)
        except ValueError:
            return None
        r = np.array([math.log(ell.a), math.log(ell.b),
                      (ell.theta - target[2] + 0.5 * math.pi) % math.pi - 0.5 * math.pi]) - \
            np.array([target[0], target[1], 0.0])
        if float(np.max(np.abs(r))) < 1e-3:
            break
        j = np.asarray(jac)[:, :3] * np.array([ka, kb, 1.0])  # d/d(ln ka, ln kb, psi)
        j[0] /= ell.a
        j[1] /= ell.b
        try:
            step = np.linalg.lstsq(j, -r, rcond=None)[0]
        except np.linalg.LinAlgError:
            return None
        u += np.clip(step, -1.0, 1.0)
    return (math.exp(u[0]), math.exp(u[1]), u[2]) if np.all(np.isfinite(u)) else None


def wide_fit(fitter: Any, strain: np.ndarray, flat: np.ndarray, usable: np.ndarray,
             mask: np.ndarray | None, res: FitResult, budget_s: float | None,
             t0: float) -> FitResult | None:
    """The point contact ``res`` fitted again on the window of every tactel it presses: from
    where it is when its fit converged, else from the pressed tactels' moments.  None when
    ``res`` has nothing beyond its window, or the wider fit finds no contact."""
    win = pressed_window(fitter, flat, usable, res)
    if win is None or res.model is None:
        return None
    start = None
    warm = (res.model, res.params) if res.converged or not stopped_by_budget(res) else None
    if warm is None:
        start = moment_start(fitter, res.model, flat, pressed_tactels(fitter, flat, usable))
    left = None if budget_s is None else max(budget_s - (time.perf_counter() - t0), 0.0)
    with fitter.on_window(win):
        wide = fitter.fit(strain, res.model, start=start, mask=mask, warm=warm, budget_s=left)
    return wide if wide.contact and wide.params is not None else None

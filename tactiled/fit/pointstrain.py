"""A point contact's strain on the whole array from a model's internal parameters: what the
several-contact fit (:mod:`tactiled.fit.multi`) subtracts for a neighbour and what the line's
band (:mod:`tactiled.fit.linewindow`) compares the line with.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tactiled.fit.models import get_model


def point_contact(model: str, params: tuple[float, ...]) -> tuple[float, ...] | None:
    """``(kappa_a, kappa_b, psi, F, x0, y0)`` of a point contact's internal parameters."""
    try:
        phys, _ = get_model(model).physical(np.asarray(params, dtype=float))
    except (ValueError, KeyError):
        return None
    return tuple(float(v) for v in phys)


def point_strain(fitter: Any, model: str, params: tuple[float, ...],
                 window: tuple[int, int, int, int] | None = None) -> np.ndarray | None:
    """The strain on the whole array of a point contact's internal parameters (None: not a
    point contact, or no valid contact); with ``window`` ``(row0, col0, rows, cols)``, on
    that window alone (the same numbers, each tactel's strain computed alike)."""
    phys = point_contact(model, params)
    if phys is None:
        return None
    ka, kb, psi, force, x0, y0 = phys
    m = fitter.model
    try:
        ell, _ = m.ellipse(ka, kb, psi, force)
    except ValueError:
        return None
    xs, ys = m.xs_full, m.ys_full
    if window is not None:
        r0, c0, nr, nc = window
        xs, ys = xs[r0:r0 + nr], ys[c0:c0 + nc]
    return m.strain_from_ellipse(ell, force, x0, y0, xs, ys)

"""Warm starts of several contacts: the tag a worker's answer carries and how a new frame's
regions pick theirs.  Light (no scipy): the main process imports it."""

from __future__ import annotations

import math

#: ``warm[0]`` of a frame of several contacts: ``(SEVERAL, ((model, params), ...))``.
SEVERAL = "several"


def nearest_start(warms: tuple[tuple[str, tuple[float, ...]], ...], x_mm: float, y_mm: float,
                  gate_mm: float) -> tuple[str, tuple[float, ...]] | None:
    """The point contact of ``warms`` whose centre (its parameters' last two, mm) is nearest
    ``(x_mm, y_mm)`` within ``gate_mm``; None when none is (a new contact starts cold)."""
    best, best_d = None, gate_mm
    for model, params in warms:
        if model not in ("cylinder", "sphere", "general") or (model == "cylinder" and len(params) < 5):
            continue  # (a cylinder of 4 parameters is a line contact: it has no centre)
        d = math.hypot(params[-2] - x_mm, params[-1] - y_mm)
        if d <= best_d:
            best, best_d = (model, params), d
    return best

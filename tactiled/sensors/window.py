"""Which fit window suits an array: the Fisher information each window size keeps.

A fit reads a square window of tactels around the contact (docs/concepts/fitting.md).  A larger
window holds more of the contact's information and costs more per fit.  :func:`information`
gives, per window size and parameter, the share of the largest window's Fisher information it
keeps; :func:`recommended` the smallest size keeping :data:`KEEP` of it for every parameter.
"""

# The reference contacts are a sphere and a cylinder (a line on a flat array) of radius twice the
# cover's depth, pressed at the array's middle to a peak of 60 noise sigmas; the share kept is
# ``(sigma_largest / sigma_N)^2`` from the Cramer-Rao bounds.  On the paper's finger the
# recommended window is its 4x4.

from __future__ import annotations

import math

from tactiled.sensors.model import SensorModel

#: Share of the largest window's information a recommended window keeps, for every parameter.
KEEP = 0.9
#: Window sides compared (a fit's cost grows with the window's tactels).
SIZES = range(3, 9)
#: The reference contacts' peak strain, in noise sigmas.
PEAK_SNR = 60.0


def _reference(sensor: SensorModel):
    from tactiled.physics.contact import Contact, LineContact
    from tactiled.physics.strain import StrainModel, scaled_to_peak

    model = StrainModel(sensor)
    g = sensor.geometry
    # off the grid's symmetry by a fraction of a pitch, as a contact usually is
    cx, cy = 0.5 * g.span_x + 0.3 * g.dx, 0.5 * g.span_y + 0.2 * g.dy
    r = 2.0 * max(sensor.impulse.depth_x, sensor.impulse.depth_y)
    sigma = sensor.noise.sigma
    peak = PEAK_SNR * sigma
    sphere = scaled_to_peak(model, lambda s: Contact(r, r, 0.0, s, cx, cy), peak)
    if g.flat:
        cyl = scaled_to_peak(model, lambda s: LineContact(r, 70.0, 0.1 * s, cx, cy), peak)
    else:
        cyl = scaled_to_peak(model, lambda s: Contact(r, math.inf, 70.0, s, cx, cy), peak)
    return model, sphere, cyl


def information(sensor: SensorModel) -> dict[int, dict[str, float]]:
    """Per window side (up to the array's larger side), the share of the largest window's
    Fisher information kept about each reference parameter (``sphere/r1_mm`` ...)."""
    from tactiled.fit.fitter import FitOptions, Fitter
    from tactiled.fit.models import get_model

    model, sphere, cyl = _reference(sensor)
    g = sensor.geometry
    sizes = [n for n in SIZES if n <= max(g.rows, g.cols)] or [max(g.rows, g.cols)]
    sds: dict[int, dict[str, float]] = {}
    for n in sizes:
        f = Fitter(sensor, FitOptions(window=n), warm=False)
        c = f.cramer_rao(model.predict(sphere), "sphere", get_model("sphere").from_values(
            sphere.r1, sphere.r2, 0.0, sphere.force, sphere.x0, sphere.y0))
        row = {"sphere/r1_mm": c["r1_mm"], "sphere/force_n": c["force_n"]}
        if g.flat:
            # a square window of side n on the ridge (a line's own fit uses its band instead)
            c = f.line_cramer_rao(model.predict(cyl), cyl, window=n)
            row.update({"line/r1_mm": c["r1_mm"], "line/load_n_per_mm": c["load_n_per_mm"],
                        "line/angle_deg": c["angle_deg"]})
        else:
            c = f.cramer_rao(model.predict(cyl), "cylinder", get_model("cylinder").from_values(
                cyl.r1, cyl.r2, cyl.psi_deg, cyl.force, cyl.x0, cyl.y0))
            row.update({"cylinder/r1_mm": c["r1_mm"], "cylinder/force_n": c["force_n"],
                        "cylinder/angle_deg": c["angle_deg"]})
        sds[n] = row
    best = sds[sizes[-1]]
    return {n: {k: (best[k] / v) ** 2 if v and best[k] else 0.0 for k, v in row.items()}
            for n, row in sds.items()}


def recommended(sensor: SensorModel, keep: float = KEEP) -> int:
    """The smallest window side keeping ``keep`` of the largest window's information about
    every reference parameter."""
    info = information(sensor)
    for n, row in info.items():
        if min(row.values()) >= keep:
            return n
    return max(info)

"""The line model: a cylinder on a flat array (docs/concepts/model.md, "Other arrays"; docs/concepts/fitting.md).

Internal vector ``[ln R, psi, ln P, c]``: the cylinder's radius (mm), the line's direction
(radians from +x toward +y), its load per length (N/mm) and its signed offset (mm) along the
normal ``n = (-sin psi, cos psi)`` from a reference point (the fit window's centre).
"""

# The user-unit report gives ``r1_mm``, ``angle_deg`` and the line's point nearest the array's
# centre as ``x_mm``, ``y_mm``; ``load_n_per_mm`` and ``offset_mm`` (the signed distance of the
# line from the array's centre along ``n``) come in the result's ``line`` table.  The total force
# and the position along the line do not exist for a line longer than the array: ``force_n`` is
# None with that reason.

from __future__ import annotations

import math

import numpy as np

from tactiled.sensors.model import SensorModel
from tactiled.fit.params import wrap_deg
from tactiled.physics.line import (across_rule, along_line, half_width, line_points, line_residual,
                                   line_strain_points)

PARAMS = ("ln_r", "psi", "ln_p", "c")
#: Step caps of the solver (ln R, rad, ln P, mm).
STEPS = np.array([1.0, 0.5, 1.0, 2.0])
#: Radii (mm) the cold starts try, smallest first.
START_RADII = (4.0, 25.0)
#: The pressed tactels (above half the peak) lie on one lattice line when their second moment
#: across their major axis is under this share of the squared pitch: their moments then give
#: the line's direction along that lattice line, and nothing of its tilt either way.
COLLINEAR_SHARE = 0.01
FORCE_REASON = ("line contact: a cylinder on a flat array touches along a line longer than the "
                "array, whose total force is not observable; its load per length is "
                "line.load_n_per_mm")


class LineProblem:
    """The line model on one window: residuals, starts and the report.

    ``xs``, ``ys`` are the window's grid (mm) and ``ex``, ``ey`` each tactel's displacement
    from it (flattened row-major), ``target`` their strains, ``valid`` the usable ones,
    ``inv_scale`` each residual's weight; the reference point of the offset ``c`` is the
    tactels' mean position (``ref``).  The fitter's search evaluates the same residual
    compiled (``tactiled.fit.compiled``, kind ``LINE``); this class serves its Python
    fallback, the bounds at the truth, the starts and the report.
    """

    def __init__(self, sensor: SensorModel, xs: np.ndarray, ys: np.ndarray, ex: np.ndarray,
                 ey: np.ndarray, target: np.ndarray, valid: np.ndarray, inv_scale: np.ndarray,
                 tol: float = 1e-9) -> None:
        self.sensor = sensor
        imp = sensor.impulse
        self.imp = np.array((imp.depth_x, imp.nu_x, imp.depth_y, imp.nu_y))
        self.dmin = min(imp.depth_x, imp.depth_y)
        self.modulus = sensor.material.modulus
        self.k = sensor.material.compliance
        self.tol = tol
        f = np.ascontiguousarray
        px, py, rx, ry = line_points(f(xs, dtype=float), f(ys, dtype=float), f(ex, dtype=float),
                                     f(ey, dtype=float))
        self.px, self.py, self.ref = px, py, (rx, ry)
        self.target = f(target, dtype=float)
        self.valid = f(valid, dtype=np.bool_)
        self.inv_scale = f(inv_scale, dtype=float)
        g = sensor.geometry
        self.centre = (0.5 * g.span_x, 0.5 * g.span_y)
        #: set by :meth:`starts`: the lattice line the pressed tactels lie on (its direction,
        #: rad, and their centroid, mm), or None where they span more than one (:meth:`mirrored`)
        self.axis: tuple[float, float, float] | None = None

    def strains(self, p: np.ndarray) -> np.ndarray:
        """The model's strains at the window's tactels for internal vector ``p``."""
        r, psi, load, c = math.exp(p[0]), float(p[1]), math.exp(p[2]), float(p[3])
        b = half_width(load, r, self.k)
        u, w = across_rule(b, self.dmin, self.tol)
        cx = self.ref[0] - c * math.sin(psi)
        cy = self.ref[1] + c * math.cos(psi)
        return line_strain_points(load, b, psi, cx, cy, self.px, self.py, self.imp, self.modulus, u, w)

    def residual_and_jacobian(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residuals ``(strain - target) * inv_scale`` (0 where not valid) and their exact
        Jacobian in ``p`` (:func:`tactiled.physics.line.line_residual`); ValueError for a
        line too wide to integrate."""
        p = np.asarray(p, dtype=float)
        u, w = across_rule(half_width(math.exp(p[2]), math.exp(p[0]), self.k), self.dmin, self.tol)
        return line_residual(p, self.px, self.py, self.ref[0], self.ref[1], self.imp, self.modulus,
                             self.k, u, w, self.target, self.valid, self.inv_scale)

    def starts(self, clean: np.ndarray, xs: np.ndarray, ys: np.ndarray, peak: float) -> list[np.ndarray]:
        """Cold starts: the line's direction from the second moments of the pressed region
        (strain above half the peak) of the whole frame, its offset through the peak, and the
        load that gives the peak strain, for each of :data:`START_RADII`."""
        s = np.where(clean >= 0.5 * peak, clean, 0.0)
        g = self.sensor.geometry
        X, Y = np.asarray(xs, dtype=float)[:, None], np.asarray(ys, dtype=float)[None, :]  # broadcast
        w = s.sum()
        mx, my = (s * X).sum() / w, (s * Y).sum() / w
        cxx = (s * (X - mx) ** 2).sum() / w
        cyy = (s * (Y - my) ** 2).sum() / w
        cxy = (s * (X - mx) * (Y - my)).sum() / w
        psi = 0.5 * math.atan2(2.0 * cxy, cxx - cyy)  # the major axis: along the line
        minor = 0.5 * (cxx + cyy - math.hypot(cxx - cyy, 2.0 * cxy))
        self.axis = (psi, mx, my) if minor <= COLLINEAR_SHARE * min(g.dx, g.dy) ** 2 else None
        c = -math.sin(psi) * (mx - self.ref[0]) + math.cos(psi) * (my - self.ref[1])
        unit = along_line(0.0, 0.0, math.cos(psi), math.sin(psi), self.imp)  # strain per N/mm * E
        load = max(peak * self.modulus / max(unit, 1e-9), 1e-6)
        return [np.array([math.log(r), psi, math.log(load), c]) for r in START_RADII]

    def mirrored(self, p: np.ndarray) -> np.ndarray | None:
        """The line ``p`` reflected about the lattice line its pressed tactels lie on
        (:attr:`axis`, set by :meth:`starts`; the point where it crosses that line stays):
        a start in the other valley of its angle's likelihood.  A ridge along one row of
        tactels tells its tilt either way only by the faint strain beside it, so a line tilted
        a few degrees off that row has two valleys of nearly equal depth, mirror images, and
        a cold start on the row's direction lies on the ridge between them (on a 6x4 pad of
        4 mm pitch: a 5 mm line at 83 deg fitted at 95 deg on 20 of 25 frames).  None where
        the tactels span more than one lattice line or ``p`` lies along it."""
        if self.axis is None:
            return None
        psi0, mx, my = self.axis
        psi = float(p[1])
        tilt = (psi - psi0 + 0.5 * math.pi) % math.pi - 0.5 * math.pi
        if abs(tilt) < 1e-6:
            return None
        # where the line crosses the lattice line (the reflection leaves it in place)
        rx, ry = mx - self.ref[0], my - self.ref[1]
        t = (float(p[3]) - (-math.sin(psi) * rx + math.cos(psi) * ry)) / -math.sin(tilt)
        xx, xy = rx + t * math.cos(psi0), ry + t * math.sin(psi0)
        q = np.array(p, dtype=float)
        q[1] = psi - 2.0 * tilt
        q[3] = -math.sin(q[1]) * xx + math.cos(q[1]) * xy
        return q

    def report(self, p: np.ndarray, cov: np.ndarray | None) -> tuple[dict, dict, dict]:
        """``(values, std, line)``: the user-unit values (``VALUE_KEYS``), their 1-sigma
        bounds from the internal covariance ``cov`` (None: unknown), and the line's own
        table (``load_n_per_mm``, ``offset_mm`` and their sigmas)."""
        r, psi, load, c = math.exp(p[0]), float(p[1]), math.exp(p[2]), float(p[3])
        # the reported offset is along the normal of the reported angle (psi modulo pi):
        # turning psi by pi turns the normal, and the offset's sign with it
        flip = -1.0 if math.floor(psi / math.pi) % 2 else 1.0
        nx, ny = -math.sin(psi), math.cos(psi)
        ax, ay = self.centre
        # offset from the array's centre, and the line's point nearest it
        off = c + nx * (self.ref[0] - ax) + ny * (self.ref[1] - ay)
        fx, fy = ax + off * nx, ay + off * ny
        values = {"x_mm": fx, "y_mm": fy, "force_n": None, "r1_mm": r, "r2_mm": None,
                  "angle_deg": wrap_deg(psi)}
        # gradients of (x, y, r1, angle, load, offset) in (ln R, psi, ln P, c)
        doff_dpsi = -ny * (self.ref[0] - ax) + nx * (self.ref[1] - ay)
        g = np.zeros((6, 4))
        g[0, 1] = doff_dpsi * nx + off * (-ny)
        g[0, 3] = nx
        g[1, 1] = doff_dpsi * ny + off * nx
        g[1, 3] = ny
        g[2, 0] = r
        g[3, 1] = 180.0 / math.pi
        g[4, 2] = load
        g[5, 1] = doff_dpsi
        g[5, 3] = 1.0
        std: dict[str, float | None] = dict.fromkeys(values)
        g[5] *= flip
        line: dict[str, float | None] = {"load_n_per_mm": load, "offset_mm": flip * off,
                                         "load_n_per_mm_std": None, "offset_mm_std": None}
        if cov is not None:
            sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", g, cov, g), 0.0))
            std.update(x_mm=float(sd[0]), y_mm=float(sd[1]), r1_mm=float(sd[2]),
                       angle_deg=float(sd[3]))
            line["load_n_per_mm_std"] = float(sd[4])
            line["offset_mm_std"] = float(sd[5])
        return values, std, line

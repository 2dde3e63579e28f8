"""Predicted tactel strains: the impulse response convolved with the Hertz pressure (eq. 13).

    strain[m, n] = (1/E) * integral h_x(X_m - x) h_y(Y_n - y) p(x, y) dx dy
"""

# Mapping the contact ellipse onto the unit disk, ``x = x0 + a u cos(theta) - b v sin(theta)``,
# ``y = y0 + a u sin(theta) + b v cos(theta)``, the Jacobian ``a b`` cancels the pressure's
# ``3F/(2 pi a b)``, so
#
#     strain = 3F/(2 pi E) * integral over the unit disk sqrt(1 - u^2 - v^2) h_x(...) h_y(...).
#
# With ``v = sqrt(1 - u^2) s`` that is ``integral (1 - u^2) du integral sqrt(1 - s^2) ds``: a
# Gauss-Jacobi(1, 1) rule in u times a Gauss-Chebyshev (second kind) rule in s integrates the
# square-root edge of the pressure exactly and converges geometrically for the smooth kernel.
# The node counts follow from the kernel's pole at distance ``d`` (the rubber depth) from the real
# axis: ``n = ln(1/tol) / (2 ln rho)``, ``rho = d/a + sqrt(1 + (d/a)^2)``, so knife edges use a few
# nodes and near-plane contacts many.  Node positions depend smoothly on (a, b, theta, x0, y0), so
# derivatives are exact chain rules through ``h'`` (no finite differences).

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from tactiled.sensors.model import SensorModel
from tactiled.physics.contact import Contact, LineContact
from tactiled.physics.hertz import Ellipse, contact_ellipse, ellipse_core
from tactiled.physics.impulse import line_response, line_response_and_slope
from tactiled.physics.kernels import quadrature, quadrature_points, strain_with_jacobian, window_residual
from tactiled.physics.quadrature_rules import DEFAULT_TOL, disk_rule, nodes_for


class StrainModel:
    """Forward model for one sensor: contact -> predicted strains at chosen tactels.

    ``tol`` is the quadrature's relative accuracy target (the forward model's accuracy knob).
    """

    def __init__(self, sensor: SensorModel | None = None, tol: float = DEFAULT_TOL) -> None:
        self.sensor = sensor or SensorModel()
        self.tol = tol
        imp = self.sensor.impulse
        self._dx, self._nux = imp.depth_x, imp.nu_x
        self._dy, self._nuy = imp.depth_y, imp.nu_y
        self._dmin = min(imp.depth_x, imp.depth_y)
        self._imp = np.array((imp.depth_x, imp.nu_x, imp.depth_y, imp.nu_y))
        self._scale = 3.0 / (2.0 * math.pi * self.sensor.material.modulus)
        self._rf = self.sensor.geometry.finger_radius
        self._k = self.sensor.material.compliance
        g = self.sensor.geometry
        self.xs_full = np.arange(g.rows) * g.dx
        self.ys_full = np.arange(g.cols) * g.dy
        #: Tactel displacements from the grid, (rows, cols) mm each; None on the nominal grid.
        self.shift: tuple[np.ndarray, np.ndarray] | None = None
        if not self.sensor.positions.nominal:
            ex, ey = self.sensor.positions.arrays(g.rows, g.cols)
            for arr in (ex, ey):
                arr.setflags(write=False)
            self.shift = (ex, ey)

    # -- geometry ---------------------------------------------------------------------------
    def ellipse(
        self, kappa_a: float, kappa_b: float, psi: float, force: float, jac: bool = False
    ) -> tuple[Ellipse, list[list[float]] | None]:
        """Hertz ellipse on this finger (see :func:`tactiled.physics.hertz.contact_ellipse`)."""
        return contact_ellipse(kappa_a, kappa_b, psi, force, self._rf, self._k, jac)

    def _rule(self, ell: Ellipse) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return disk_rule(nodes_for(ell.a, self._dmin, self.tol), nodes_for(ell.b, self._dmin, self.tol))

    # -- strains ----------------------------------------------------------------------------
    def strain_from_ellipse(
        self, ell: Ellipse, force: float, x0: float, y0: float, xs: np.ndarray, ys: np.ndarray
    ) -> np.ndarray:
        """Strains ``(len(xs), len(ys))`` at tactel coordinates ``xs`` (mm along x), ``ys``."""
        u, v, w = self._rule(ell)
        val = quadrature(
            x0, y0, ell.a, ell.b, ell.theta, u, v, w, xs, ys,
            self._dx, self._nux, self._dy, self._nuy,
        )
        return (self._scale * force) * val

    def strain_from_ellipse_numpy(
        self, ell: Ellipse, force: float, x0: float, y0: float, xs: np.ndarray, ys: np.ndarray
    ) -> np.ndarray:
        """numpy expression of :meth:`strain_from_ellipse` (reference for the compiled loop)."""
        u, v, w = self._rule(ell)
        c, s = math.cos(ell.theta), math.sin(ell.theta)
        au, bv = ell.a * u, ell.b * v
        xq = x0 + au * c - bv * s
        yq = y0 + au * s + bv * c
        hx = line_response(xs[:, None] - xq, self._dx, self._nux)
        hy = line_response(ys[:, None] - yq, self._dy, self._nuy)
        return (self._scale * force) * ((hx * w) @ hy.T)

    def strain_and_jacobian(
        self,
        kappa_a: float,
        kappa_b: float,
        psi: float,
        force: float,
        x0: float,
        y0: float,
        xs: np.ndarray,
        ys: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, Ellipse]:
        """Strains ``(Mx, Ny)`` and their Jacobian ``(Mx, Ny, 6)`` with respect to
        ``(kappa_a [1/mm], kappa_b [1/mm], psi [rad], F [N], x0 [mm], y0 [mm])``."""
        ell, hj = self.ellipse(kappa_a, kappa_b, psi, force, jac=True)
        u, v, w = self._rule(ell)
        geo = np.array((x0, y0, ell.a, ell.b, ell.theta, force, self._scale))
        value, jac = strain_with_jacobian(geo, hj, u, v, w, xs, ys, self._imp)
        return value, jac, ell

    def residual_function(
        self,
        physical,
        xs: np.ndarray,
        ys: np.ndarray,
        target: np.ndarray,
        valid: np.ndarray,
        inv_scale: float | np.ndarray,
        window: tuple[int, int, int, int] | None = None,
    ):
        """A closure ``p -> (r, J)`` for the solver: scaled residuals over the valid
        tactels of a window and their Jacobian in a model's parameters.  ``physical(p)`` maps
        the parameters to ``(kappa_a, kappa_b, psi, F, x0, y0)`` and its (6, k) Jacobian.

        ``inv_scale`` multiplies each residual (a scalar, or one per window tactel, flattened);
        ``window`` ``(r0, c0, rows, cols)`` locates ``xs x ys`` on the array, so that tactels
        displaced from the grid (the sensor's ``positions``) are evaluated where they are."""
        ellipse_core_, rf, comp, imp, scale = ellipse_core, self._rf, self._k, self._imp, self._scale
        rule, tol, dmin = disk_rule, self.tol, self._dmin
        valid = np.ascontiguousarray(valid, dtype=np.bool_)
        inv_scale = np.ascontiguousarray(np.broadcast_to(np.asarray(inv_scale, dtype=float), valid.shape))
        ex, ey = self.window_shift(window, xs.shape[0], ys.shape[0])
        return self.window_residual_function(physical, xs, ys, target, valid, inv_scale, ex, ey)

    def window_residual_function(self, physical, xs: np.ndarray, ys: np.ndarray, target: np.ndarray,
                                 valid: np.ndarray, inv_scale: np.ndarray, ex: np.ndarray, ey: np.ndarray,
                                 charge=None):
        """:meth:`residual_function` on arrays already prepared (contiguous, one entry per
        window tactel, ``valid`` boolean): the fitter's per-frame fast path.  ``charge``, if
        given, is called as ``charge(nodes_u, nodes_s, tactels)`` before each evaluation (the
        fit's budget; it may raise to refuse it)."""
        ellipse_core_, rf, comp, imp, scale = ellipse_core, self._rf, self._k, self._imp, self._scale
        rule, tol, dmin = disk_rule, self.tol, self._dmin
        hj = np.empty((3, 4))

        def residual(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            (ka, kb, psi, force, x0, y0), dphys = physical(p)
            a, b, theta, _ = ellipse_core_(ka, kb, psi, force, rf, comp, hj)
            if a < 0.0:
                raise ValueError("infinite line contact")
            nu, ns = nodes_for(a, dmin, tol), nodes_for(b, dmin, tol)
            if charge is not None:
                charge(nu, ns, target.size)
            u, v, w = rule(nu, ns)
            geo = np.array((x0, y0, a, b, theta, force, scale))
            return window_residual(geo, hj, dphys, u, v, w, xs, ys, imp, target, valid, inv_scale, ex, ey)

        return residual

    def window_shift(
        self, window: tuple[int, int, int, int] | None, rows: int, cols: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """The displacements (mm) of a window's tactels from the grid, flattened row-major
        (zeros on the nominal grid or without a ``window``)."""
        if self.shift is None or window is None:
            zeros = np.zeros(rows * cols)
            return zeros, zeros
        r0, c0, nr, nc = window
        ex, ey = self.shift
        return (np.ascontiguousarray(ex[r0:r0 + nr, c0:c0 + nc].ravel()),
                np.ascontiguousarray(ey[r0:r0 + nr, c0:c0 + nc].ravel()))

    def _chain(
        self, value: np.ndarray, d_geo: np.ndarray, hj: list[list[float]], force: float,
        ell: Ellipse,
    ) -> tuple[np.ndarray, np.ndarray, Ellipse]:
        """Chain ``d/d(x0, y0, a, b, theta)`` through the Hertz Jacobian to the 6 inputs."""
        kf = self._scale * force
        h = hj  # (3, 4): d(a, b, theta)/d(kappa_a, kappa_b, psi, F)
        jac = np.empty(value.shape + (6,))
        jac[..., :4] = kf * np.tensordot(d_geo[2:5], h, axes=(0, 0))
        jac[..., 3] += self._scale * value
        jac[..., 4] = kf * d_geo[0]
        jac[..., 5] = kf * d_geo[1]
        return kf * value, jac, ell

    def strain_and_jacobian_numpy(
        self,
        kappa_a: float,
        kappa_b: float,
        psi: float,
        force: float,
        x0: float,
        y0: float,
        xs: np.ndarray,
        ys: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, Ellipse]:
        """numpy expression of :meth:`strain_and_jacobian` (reference for the compiled loop)."""
        ell, hj = self.ellipse(kappa_a, kappa_b, psi, force, jac=True)
        u, v, w = self._rule(ell)
        c, s = math.cos(ell.theta), math.sin(ell.theta)
        au, bv = ell.a * u, ell.b * v
        dxq = au * c - bv * s  # xq - x0
        dyq = au * s + bv * c  # yq - y0
        hx, dhx = line_response_and_slope(xs[:, None] - (x0 + dxq), self._dx, self._nux)
        hy, dhy = line_response_and_slope(ys[:, None] - (y0 + dyq), self._dy, self._nuy)
        gy = hx * w  # pairs with hy (value) and dhy (y-motion of nodes)
        gx = dhx * w  # pairs with hy (x-motion of nodes)
        value = gy @ hy.T
        # Node motion per unit change of (x0, y0, a, b, theta): (d xq, d yq).
        ones, zeros = np.ones_like(u), np.zeros_like(u)
        alpha = np.stack([ones, zeros, u * c, -v * s, -dyq])
        beta = np.stack([zeros, ones, u * s, v * c, dxq])
        # d value / d node-x = -h_x' (argument is X - xq); likewise for y.
        d_geo = -((gx * alpha[:, None, :]) @ hy.T + (gy * beta[:, None, :]) @ dhy.T)
        return self._chain(value, d_geo, hj, force, ell)

    def predict(self, contact: Contact, xs: np.ndarray | None = None, ys: np.ndarray | None = None,
                moved: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """Predicted strain for a :class:`Contact`, on the whole array by default (each
        tactel where the sensor's ``positions`` put it, further displaced by ``moved``, a
        ``(dx, dy)`` pair of ``(rows, cols)`` arrays in mm, if given), else on the grid
        ``xs x ys``."""
        if isinstance(contact, LineContact) or (self._rf == math.inf and contact.kappa_b == 0.0):
            return self._predict_line(contact, xs, ys, moved)
        ell, _ = self.ellipse(contact.kappa_a, contact.kappa_b, contact.psi, contact.force)
        if xs is None and ys is None and (self.shift is not None or moved is not None):
            # tactels off the grid: each evaluated exactly where it sits
            shape = (self.xs_full.size, self.ys_full.size)
            ex, ey = self.shift if self.shift is not None else (np.zeros(shape), np.zeros(shape))
            if moved is not None:
                ex, ey = ex + moved[0], ey + moved[1]
            px = np.ascontiguousarray((self.xs_full[:, None] + ex).ravel())
            py = np.ascontiguousarray((self.ys_full[None, :] + ey).ravel())
            u, v, w = self._rule(ell)
            val = quadrature_points(contact.x0, contact.y0, ell.a, ell.b, ell.theta, u, v, w,
                                    px, py, self._imp)
            return (self._scale * contact.force) * val.reshape(ex.shape)
        xs = self.xs_full if xs is None else np.ascontiguousarray(xs, dtype=float)
        ys = self.ys_full if ys is None else np.ascontiguousarray(ys, dtype=float)
        return self.strain_from_ellipse(ell, contact.force, contact.x0, contact.y0, xs, ys)


    def tactel_points(self, moved: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Every tactel's ``(x, y)`` in mm, ``(rows, cols)`` each, where the sensor's
        ``positions`` (and ``moved``, if given) put it."""
        px = np.broadcast_to(self.xs_full[:, None], (self.xs_full.size, self.ys_full.size)).astype(float)
        py = np.broadcast_to(self.ys_full[None, :], px.shape).astype(float)
        if self.shift is not None:
            px, py = px + self.shift[0], py + self.shift[1]
        if moved is not None:
            px, py = px + moved[0], py + moved[1]
        return px, py

    def grid_points(self) -> tuple[np.ndarray, np.ndarray]:
        """The nominal grid's ``(x, y)`` of every tactel, mm, ``(rows, cols)`` each (read-only,
        made once: a frame of several contacts predicts a line on the whole grid several
        times)."""
        grid = getattr(self, "_grid", None)
        if grid is None:
            grid = np.meshgrid(self.xs_full, self.ys_full, indexing="ij")
            for arr in grid:
                arr.setflags(write=False)
            self._grid = grid = (grid[0], grid[1])
        return grid

    def _predict_line(self, contact, xs, ys, moved) -> np.ndarray:
        """:meth:`predict` of a line contact (a cylinder on a flat array)."""
        from tactiled.physics.line import line_strain

        if not isinstance(contact, LineContact):
            raise ValueError("a cylinder on a flat array is a line contact: give a LineContact "
                             "(load per length), not a total force")
        if xs is None and ys is None:
            px, py = self.tactel_points(moved)
        elif (xs is None or xs is self.xs_full) and (ys is None or ys is self.ys_full):
            px, py = self.grid_points()
        else:
            gx = self.xs_full if xs is None else np.asarray(xs, dtype=float)
            gy = self.ys_full if ys is None else np.asarray(ys, dtype=float)
            px, py = np.meshgrid(gx, gy, indexing="ij")
        return line_strain(contact.load, contact.r1, contact.psi_deg, contact.x0, contact.y0, px, py,
                           self._imp, self.sensor.material.modulus, self._k, self.tol)


def predict_strain(contact: Contact, sensor: SensorModel | None = None) -> np.ndarray:
    """Predicted strain frame ``(rows, cols)`` for ``contact`` on ``sensor`` (default: docs/concepts/model.md's)."""
    return StrainModel(sensor).predict(contact)


def scaled_to_peak(model: StrainModel, make: Callable[[float], Any], peak: float) -> Any:
    """The contact ``make(scale)`` whose noise-free peak strain on ``model`` is ``peak``
    (strain units; a reference contact ``n`` noise sigmas strong is ``peak = n * sigma``),
    within about 1 %: two passes of the scale, the peak being nearly linear in the load."""
    scale = 1.0
    for _ in range(2):
        scale *= peak / float(model.predict(make(scale)).max())
    return make(scale)

"""Identification: a finger's own rubber constants, tactel responses and positions, from presses
of known contacts, by maximum likelihood.  No I/O.

All parameters are estimated jointly by damped Gauss-Newton; the 1-sigma bounds are the
Cramer-Rao bounds of the presses, and what the presses cannot determine is held, not guessed.
"""

# Each press ``p`` gives every tactel's raw counts ``y[p, i]``; the press's contact is known
# (indentor radii and orientation, force, centre).  The model of a reading is
#
#     y[p, i] = o[i] + G[i] * s_i(contact_p; theta) + noise
#
# with ``theta`` the rubber's constants ``(depth_x, nu_x, depth_y, nu_y, modulus)``, ``s_i`` the
# contact model's strain at tactel ``i`` where it really sits (its displacement ``(ex[i], ey[i])``
# from the nominal pitch, taken to first order as in the fitter), ``o[i]`` its counts at zero
# load and ``G[i]`` its counts per unit strain.  All of it (5 + 4 per tactel parameters) is
# estimated jointly by damped Gauss-Newton on the weighted squared residuals; the weights are the
# inverse variances of a reading, ``sigma_c^2 + G^2 (a^2 + (r s)^2)``: the count noise plus the
# **model-error floor** ``(a, r)`` (absolute and relative, in strain), itself estimated by maximum
# likelihood from the residuals and then used to re-weight (two rounds).  The 1-sigma bounds come
# from the inverse of the weighted normal matrix: the Cramer-Rao bound of the presses.
#
# What the presses cannot determine is held rather than guessed:
#
# * a rubber constant whose 1-sigma bound exceeds :data:`HOLD_LIMIT` is held at the nominal value
#   (the sensor description's cover; the paper's finger's by default)
#   (the report says so, with the bound it would have had);
# * a tactel's position whose 1-sigma bound exceeds :data:`POSITION_SIGMA_LIMIT` stays on the grid;
# * a tactel whose model strain never spans :data:`MIN_STRAIN_SPAN` keeps the median gain and is
#   flagged ``unexercised``.
#
# The overall gain of the tactels and the modulus trade against each other except through the
# contact's size (``a^3 ~ F / E``): both are estimated, and their bounds say how well the presses
# told them apart.  Finally, each tactel's table (offset, gain and shape) is built by the
# lookup-table builder from the counts against the identified model's strains, so a response that
# is not a straight line keeps its shape.

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import minimize

from tactiled.calibration.lut import LookupTable
from tactiled.calibration.identified import FingerModel
from tactiled.calibration.presses import PressSet
from tactiled.sensors.model import (
    COVER_KEYS,
    COVER_RANGES,
    Geometry,
    ImpulseResponse,
    Material,
    ModelError,
    NoiseModel,
    SensorModel,
    TactelPositions,
    cover_constants,
)
from tactiled.errors import CalibrationError
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel

#: The rubber's constants, in the order of the parameter vector.
RUBBER = COVER_KEYS
#: Constants estimated in logarithm (positive, scale-like); the others directly.
_LOG = {"depth_x": True, "nu_x": False, "depth_y": True, "nu_y": False, "modulus": True}
#: A constant whose 1-sigma bound exceeds this is held at the nominal value: relative for
#: depths and modulus (10 %), absolute for the ratios nu (0.1).
HOLD_LIMIT = {"depth_x": 0.1, "nu_x": 0.1, "depth_y": 0.1, "nu_y": 0.1, "modulus": 0.1}
#: A tactel's position is used when the presses pin it to better than this (1 sigma, mm).
POSITION_SIGMA_LIMIT = 0.05
#: A tactel whose model strain spans less than this over the presses is unexercised.
MIN_STRAIN_SPAN = 0.005
#: Loaded presses needed at the least (the constants need many contacts to be told apart).
MIN_LOADED = 20
#: A contact centre further than this beyond the outermost tactels is refused, mm.
MAX_CENTRE_OUTSIDE = 10.0

Progress = Callable[[str], None]


@dataclass
class Identification:
    """What identification found.  Constants in mm, N/mm^2; gains in counts per unit strain,
    offsets in counts at zero strain; ``sigma`` 1-sigma bounds (None for a held constant)."""

    sensor: SensorModel
    table: LookupTable
    constants: dict[str, float]
    sigma: dict[str, float | None]
    held: dict[str, str]
    gains: np.ndarray
    offsets: np.ndarray
    gain_sigma: np.ndarray
    position_sigma: np.ndarray  # (rows, cols, 2) mm; NaN where the position is held
    positions_held: np.ndarray  # (rows, cols) bool
    unexercised: np.ndarray  # (rows, cols) bool
    noise_strain: float  # the presses' own noise, strain (averaged presses)
    model_error: ModelError
    iterations: int
    converged: bool
    message: str
    presses_loaded: int
    presses_unloaded: int
    rms_strain: float  # RMS residual of the loaded presses, strain
    notes: list[str] = field(default_factory=list)

    @property
    def model(self) -> FingerModel:
        """The identified model, as a calibration file carries it."""
        return FingerModel(self.sensor.impulse, self.sensor.material, self.sensor.positions,
                           self.model_error, dict(self.sigma), dict(self.held), self.report())

    def report(self) -> dict:
        """The informational ``identification`` record of the calibration file."""
        return {
            "noise_strain": self.noise_strain,
            "rms_strain": self.rms_strain,
            "presses": {"loaded": self.presses_loaded, "unloaded": self.presses_unloaded},
            "iterations": self.iterations,
            "positions_used": int((~self.positions_held).sum()),
            "notes": list(self.notes),
        }


# --------------------------------------------------------------------------------------------
# Input checks


def check_contacts(presses: PressSet, geometry: Geometry) -> np.ndarray:
    """The presses' contacts, validated against themselves and the array: a boolean mask of the
    loaded presses.  Raises :class:`CalibrationError` naming the press index and the reason."""
    k = presses.contacts
    if k is None:
        raise CalibrationError("press file has no 'contacts' array (needed by --identify)")
    if presses.counts.shape[1:] != (geometry.rows, geometry.cols):
        raise CalibrationError(f"counts are {presses.counts.shape[1:]} tactels, the sensor has "
                               f"{(geometry.rows, geometry.cols)}")
    loaded = k[:, 3] != 0.0
    lo_x, hi_x = -MAX_CENTRE_OUTSIDE, geometry.span_x + MAX_CENTRE_OUTSIDE
    lo_y, hi_y = -MAX_CENTRE_OUTSIDE, geometry.span_y + MAX_CENTRE_OUTSIDE
    for p in range(k.shape[0]):
        r1, r2, angle, force, x, y = (float(v) for v in k[p])
        if math.isnan(force) or force < 0.0 or math.isinf(force):
            raise CalibrationError(f"press {p}: force_n must be a finite force >= 0 N, got {force!r}")
        if force == 0.0:
            continue
        for name, v in (("r1_mm", r1), ("angle_deg", angle), ("x_mm", x), ("y_mm", y)):
            if not math.isfinite(v):
                raise CalibrationError(f"press {p}: {name} must be finite, got {v!r}")
        if math.isnan(r2):
            raise CalibrationError(f"press {p}: r2_mm must be a radius (inf for a cylinder), got nan")
        if not r1 > 0.0:
            raise CalibrationError(f"press {p}: r1_mm must be a positive radius, got {r1!r}")
        if not r2 >= r1:
            raise CalibrationError(f"press {p}: r2_mm ({r2!r}) must be >= r1_mm ({r1!r})")
        if not (lo_x <= x <= hi_x and lo_y <= y <= hi_y):
            raise CalibrationError(
                f"press {p}: centre ({x:g}, {y:g}) mm is far off the array (x {lo_x:g}..{hi_x:g}, "
                f"y {lo_y:g}..{hi_y:g} mm)")
    if int(loaded.sum()) < MIN_LOADED:
        raise CalibrationError(f"only {int(loaded.sum())} loaded presses: identification needs at "
                               f"least {MIN_LOADED} (docs/howto/calibration.md says how many to record)")
    return loaded


# --------------------------------------------------------------------------------------------
# The forward model over all presses


def _sensor(theta: np.ndarray, geometry: Geometry) -> SensorModel:
    v = _values(theta)
    return SensorModel(geometry=geometry,
                       impulse=ImpulseResponse(v["depth_x"], v["nu_x"], v["depth_y"], v["nu_y"]),
                       material=Material(v["modulus"]))


def _values(theta: np.ndarray) -> dict[str, float]:
    return {k: float(math.exp(t) if _LOG[k] else t) for k, t in zip(RUBBER, theta)}


def _internal(values: dict[str, float]) -> np.ndarray:
    return np.array([math.log(values[k]) if _LOG[k] else values[k] for k in RUBBER])


def _strains(theta: np.ndarray, contacts: list[Contact | None], geometry: Geometry,
             slopes: bool) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Grid strains ``(N, T)`` of every press for constants ``theta`` and, with ``slopes``,
    their derivatives with respect to the tactel's position along x and y (``-d/dx0``)."""
    model = StrainModel(_sensor(theta, geometry))
    n, t = len(contacts), geometry.rows * geometry.cols
    s = np.zeros((n, t))
    dx = np.zeros((n, t)) if slopes else None
    dy = np.zeros((n, t)) if slopes else None
    xs, ys = model.xs_full, model.ys_full
    for p, c in enumerate(contacts):
        if c is None:
            continue
        if slopes:
            val, jac, _ = model.strain_and_jacobian(c.kappa_a, c.kappa_b, c.psi, c.force, c.x0, c.y0, xs, ys)
            s[p] = val.ravel()
            dx[p] = -jac[..., 4].ravel()
            dy[p] = -jac[..., 5].ravel()
        else:
            s[p] = model.predict(c, xs, ys).ravel()
    return s, dx, dy


def _contact_list(presses: PressSet, loaded: np.ndarray) -> list[Contact | None]:
    out: list[Contact | None] = []
    for p, row in enumerate(presses.contacts):
        if not loaded[p]:
            out.append(None)
            continue
        r1, r2, angle, force, x, y = (float(v) for v in row)
        out.append(Contact(r1, r2, angle % 180.0, force, x, y))
    return out


# --------------------------------------------------------------------------------------------
# The estimator


@dataclass
class _State:
    theta: np.ndarray  # (5,) internal rubber parameters
    off: np.ndarray  # (T,) counts
    gain: np.ndarray  # (T,) counts per strain
    ex: np.ndarray  # (T,) mm
    ey: np.ndarray  # (T,) mm


class _Problem:
    """The weighted least-squares problem over all presses (see the module docstring)."""

    def __init__(self, y: np.ndarray, contacts: list[Contact | None], geometry: Geometry) -> None:
        self.y = y
        self.contacts = contacts
        self.geometry = geometry
        self.n, self.t = y.shape
        self.fd_step = 1e-5

    def evaluate(self, st: _State, derivs: bool):
        """Model strains at the tactels' positions, residuals in counts, and (with ``derivs``)
        the pieces of the Jacobian."""
        s, dxs, dys = _strains(st.theta, self.contacts, self.geometry, slopes=True)
        s_eff = s + st.ex * dxs + st.ey * dys
        resid = self.y - (st.off + st.gain * s_eff)
        if not derivs:
            return s_eff, resid, None
        dtheta = np.empty((self.n, self.t, len(RUBBER)))
        for j in range(len(RUBBER)):
            h = self.fd_step
            up, dn = st.theta.copy(), st.theta.copy()
            up[j] += h
            dn[j] -= h
            s_up = _strains(up, self.contacts, self.geometry, slopes=False)[0]
            s_dn = _strains(dn, self.contacts, self.geometry, slopes=False)[0]
            dtheta[..., j] = (s_up - s_dn) / (2.0 * h)
        # d model / d (offset, gain, ex, ey) per tactel, and d model / d theta
        jt = np.stack([np.ones_like(s_eff), s_eff, st.gain * dxs, st.gain * dys], axis=-1)
        kt = st.gain[None, :, None] * dtheta
        return s_eff, resid, (jt, kt)

    @staticmethod
    def normal(w: np.ndarray, resid: np.ndarray, jt: np.ndarray, kt: np.ndarray):
        """The weighted normal matrix ``H`` and gradient ``g`` over the parameter vector
        ``[offset, gain, ex, ey] per tactel..., theta``."""
        t = jt.shape[1]
        a = np.einsum("pti,ptj,pt->tij", jt, jt, w)
        b = np.einsum("pti,ptj,pt->tij", jt, kt, w)
        c = np.einsum("pti,ptj,pt->ij", kt, kt, w)
        gt = np.einsum("pti,pt->ti", jt, w * resid)
        gk = np.einsum("pti,pt->i", kt, w * resid)
        k = kt.shape[2]
        size = 4 * t + k
        h = np.zeros((size, size))
        for i in range(t):
            h[4 * i:4 * i + 4, 4 * i:4 * i + 4] = a[i]
            h[4 * i:4 * i + 4, 4 * t:] = b[i]
            h[4 * t:, 4 * i:4 * i + 4] = b[i].T
        h[4 * t:, 4 * t:] = c
        g = np.concatenate([gt.ravel(), gk])
        return h, g


def _apply(st: _State, step: np.ndarray) -> _State:
    t = st.off.size
    d = step[:4 * t].reshape(t, 4)
    return _State(st.theta + step[4 * t:], st.off + d[:, 0], st.gain + d[:, 1],
                  st.ex + d[:, 2], st.ey + d[:, 3])


def _solve(prob: _Problem, st: _State, w: np.ndarray, free: np.ndarray, max_iter: int,
           say: Progress, stage: str) -> tuple[_State, np.ndarray, int, bool, str]:
    """Damped Gauss-Newton on the free parameters; returns the state, the covariance of the
    free parameters (``H^-1`` over the full vector, zero rows for fixed ones), iterations,
    converged, message."""
    _, resid, parts = prob.evaluate(st, derivs=True)
    cost = float(np.sum(w * resid**2))
    lam = 1e-3
    it = 0
    converged, message = False, "maximum iterations reached"
    idx = np.flatnonzero(free)
    for it in range(1, max_iter + 1):
        h, g = prob.normal(w, resid, *parts)
        hf, gf = h[np.ix_(idx, idx)], g[idx]
        diag = np.maximum(np.diag(hf), 1e-12 * max(float(np.max(np.diag(hf))), 1e-300))
        accepted = False
        while lam < 1e10:
            try:
                delta = np.linalg.solve(hf + lam * np.diag(diag), gf)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            step = np.zeros(free.size)
            step[idx] = delta
            predicted = float(2.0 * gf @ delta - delta @ hf @ delta)
            if predicted <= 1e-10 * cost:
                converged, message = True, "predicted decrease below 1e-10 of the cost"
                break
            trial = _apply(st, step)
            try:
                _, r_new, _ = prob.evaluate(trial, derivs=False)
                c_new = float(np.sum(w * r_new**2))
            except ValueError:
                c_new = math.inf
            if math.isfinite(c_new) and c_new < cost:
                st, cost = trial, c_new
                lam = max(lam / 3.0, 1e-12)
                accepted = True
                break
            lam *= 10.0
        if converged:
            break
        if not accepted:
            message = "no step reduces the cost (damping exhausted)"
            break
        _, resid, parts = prob.evaluate(st, derivs=True)
        say(f"{stage}: iteration {it}, weighted cost {cost:.6g}")
        if predicted <= 1e-8 * cost:
            converged, message = True, "relative decrease below 1e-8"
            break
    h, _ = prob.normal(w, resid, *parts)
    cov = np.zeros_like(h)
    hf = h[np.ix_(idx, idx)]
    try:
        cov[np.ix_(idx, idx)] = np.linalg.inv(hf)
    except np.linalg.LinAlgError:
        cov[np.ix_(idx, idx)] = np.linalg.pinv(hf)
    return st, cov, it, converged, message


def _floor(resid_strain: np.ndarray, s: np.ndarray, loaded: np.ndarray,
           dof_scale: float) -> tuple[float, float, float, list[str]]:
    """Maximum-likelihood noise and model-error floor from residuals in strain:
    ``var = noise^2 + a^2 + (r s)^2``.  Unloaded presses measure the noise alone; without
    them ``a`` cannot be told from the noise and is reported as 0.  Returns
    ``(noise, a, r, notes)``."""
    notes: list[str] = []
    r_un = resid_strain[~loaded]
    noise2 = float(np.mean(r_un**2)) * dof_scale if r_un.size else None
    rl = resid_strain[loaded].ravel()
    sl = s[loaded].ravel()

    def nll(q: np.ndarray) -> float:
        c0, rel2 = math.exp(q[0]), math.exp(q[1])
        var = c0 + rel2 * sl * sl
        return float(np.sum(np.log(var) + rl * rl / var))

    base = float(np.mean(rl**2)) * dof_scale
    best = minimize(nll, np.array([math.log(max(base, 1e-16)), math.log(1e-6)]), method="Nelder-Mead",
                    options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 400})
    c0, rel = math.exp(best.x[0]) * dof_scale, math.sqrt(math.exp(best.x[1]) * dof_scale)
    if rel < 1e-4:
        rel = 0.0
    if noise2 is None:
        notes.append("no unloaded presses: the absolute model-error floor cannot be told from the "
                     "noise and is taken as 0")
        return math.sqrt(c0), 0.0, rel, notes
    a = math.sqrt(max(c0 - noise2, 0.0))
    return math.sqrt(noise2), a, rel, notes


def identify(
    presses: PressSet,
    geometry: Geometry | None = None,
    *,
    knots: int = 8,
    max_iter: int = 40,
    progress: Progress | None = None,
    nominal: SensorModel | None = None,
    nominal_name: str = "the paper's",
) -> Identification:
    """Identify the finger from ``presses`` (with ``contacts``); see the module docstring.

    ``nominal`` (a sensor description's model; default the paper's finger) gives the cover's
    constants the search starts from and a constant the presses cannot determine is held at
    (``nominal_name`` says whose they are in the report).

    Raises :class:`CalibrationError` for contacts that contradict themselves or the array, too
    few loaded presses, or an identification that does not converge."""
    say = progress or (lambda _msg: None)
    g = geometry or (nominal.geometry if nominal is not None
                     else Geometry(rows=presses.shape[0], cols=presses.shape[1]))
    loaded = check_contacts(presses, g)
    contacts = _contact_list(presses, loaded)
    if g.flat and any(c is not None and c.kappa_b == 0.0 for c in contacts):
        raise CalibrationError(
            "a cylinder pressed on a flat array touches along a line longer than the array, whose "
            "total force is not defined: identify a flat array from presses of spheres or "
            "ellipsoids (r2_mm finite)")
    y = presses.counts.reshape(len(presses), -1).astype(float)
    t = y.shape[1]
    prob = _Problem(y, contacts, g)
    imp0 = nominal.impulse if nominal is not None else ImpulseResponse()
    mat0 = nominal.material if nominal is not None else Material()
    paper = cover_constants(imp0, mat0)
    theta = _internal(paper)

    # Start: offsets from the unloaded presses (else the lowest reading), gains by least squares.
    s0, _, _ = _strains(theta, contacts, g, slopes=False)
    if (~loaded).any():
        off = np.median(y[~loaded], axis=0)
    else:
        off = np.min(y, axis=0)
    den = np.sum(s0 * s0, axis=0)
    gain = np.where(den > 0, np.sum(s0 * (y - off), axis=0) / np.maximum(den, 1e-300), 1.0)
    span = s0[loaded].max(axis=0) - s0[loaded].min(axis=0)
    unexercised = span < MIN_STRAIN_SPAN
    if unexercised.all():
        raise CalibrationError(
            f"no tactel's model strain spans {MIN_STRAIN_SPAN:g} over the presses: vary the force "
            "and the position (docs/howto/calibration.md)")
    med_gain = float(np.median(gain[~unexercised]))
    gain = np.where(unexercised | ~(gain > 0), med_gain, gain)
    st = _State(theta, off, gain, np.zeros(t), np.zeros(t))

    # Which parameters are free: positions and gains of unexercised tactels are not.
    free = np.ones(4 * t + len(RUBBER), bool)
    per = free[:4 * t].reshape(t, 4)
    per[unexercised, 1:] = False
    held: dict[str, str] = {}
    notes: list[str] = []
    if unexercised.any():
        notes.append(f"{int(unexercised.sum())} tactels unexercised (model strain spans < "
                     f"{MIN_STRAIN_SPAN:g}): median gain, nominal position")

    w = np.ones_like(y)
    iterations = 0
    noise = a = rel = 0.0
    cov = np.zeros((free.size, free.size))
    converged, message = False, ""
    for rnd in range(2):
        st, cov, its, converged, message = _solve(prob, st, w, free, max_iter, say,
                                                   f"round {rnd + 1}")
        iterations += its
        # hold what the presses do not determine, then solve again without it
        changed = False
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        for j, k in enumerate(RUBBER):
            col = 4 * t + j
            if not free[col]:
                continue
            bound = sd[col] if not _LOG[k] else sd[col]  # relative for log parameters
            if not (bound <= HOLD_LIMIT[k]) or not _in_range(k, _values(st.theta)[k]):
                free[col] = False
                st.theta[j] = _internal(paper)[j]
                what = "relative " if _LOG[k] else ""
                held[k] = (f"not determined by these presses ({what}1-sigma bound "
                           f"{bound:.3g} > {HOLD_LIMIT[k]:g}): held at {nominal_name} value {paper[k]:g}")
                changed = True
        psd = sd[:4 * t].reshape(t, 4)[:, 2:]
        for i in range(t):
            if per[i, 2] and not (max(psd[i]) <= POSITION_SIGMA_LIMIT):
                per[i, 2:] = False
                st.ex[i] = st.ey[i] = 0.0
                changed = True
        if changed:
            st, cov, its, converged, message = _solve(prob, st, w, free, max_iter, say,
                                                       f"round {rnd + 1} (held)")
            iterations += its
        if not converged:
            raise CalibrationError(f"identification did not converge: {message}")
        # the model-error floor from the residuals, then re-weight
        s_eff, resid, _ = prob.evaluate(st, derivs=False)
        n_free = int(free.sum())
        dof_scale = y.size / max(y.size - n_free, 1)
        resid_strain = resid / st.gain
        noise, a, rel, fnotes = _floor(resid_strain, s_eff, loaded, dof_scale)
        var_strain = noise**2 + a**2 + (rel * s_eff) ** 2
        # readings are whole counts: never believe one better than its rounding (1/12 count^2)
        w = 1.0 / (st.gain**2 * var_strain + 1.0 / 12.0)
        say(f"round {rnd + 1}: noise {noise:.3g} strain, model-error floor {a:.3g} strain + "
            f"{100 * rel:.3g} % of the strain")
    notes.extend(fnotes)

    # 1-sigma bounds in user units
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    values = _values(st.theta)
    sigma: dict[str, float | None] = {}
    for j, k in enumerate(RUBBER):
        col = 4 * t + j
        if not free[col]:
            sigma[k] = None
            continue
        sigma[k] = float(sd[col] * values[k]) if _LOG[k] else float(sd[col])
    psd = sd[:4 * t].reshape(t, 4)
    positions_held = ~per[:, 2]
    pos_sigma = np.where(positions_held[:, None], np.nan, psd[:, 2:])
    ex = np.where(positions_held, 0.0, st.ex)
    ey = np.where(positions_held, 0.0, st.ey)
    model_error = ModelError(strain=min(a, 0.1), relative=min(rel, 1.0))
    rows, cols = g.rows, g.cols
    sensor = replace(
        _sensor(st.theta, g),
        positions=TactelPositions.from_arrays(ex.reshape(rows, cols), ey.reshape(rows, cols))
        if (~positions_held).any() else TactelPositions(),
        model_error=model_error,
        noise=NoiseModel(),
    )
    s_eff, resid, _ = prob.evaluate(st, derivs=False)
    rms = float(np.sqrt(np.mean((resid / st.gain)[loaded] ** 2)))
    table = _table(presses, s_eff, st, unexercised, knots)
    say(f"identified in {iterations} iterations; RMS residual {rms:.3g} strain")
    return Identification(
        sensor=sensor, table=table, constants=values, sigma=sigma, held=held,
        gains=st.gain.reshape(rows, cols), offsets=st.off.reshape(rows, cols),
        gain_sigma=psd[:, 1].reshape(rows, cols),
        position_sigma=pos_sigma.reshape(rows, cols, 2), positions_held=positions_held.reshape(rows, cols),
        unexercised=unexercised.reshape(rows, cols), noise_strain=noise, model_error=model_error,
        iterations=iterations, converged=converged, message=message,
        presses_loaded=int(loaded.sum()), presses_unloaded=int((~loaded).sum()),
        rms_strain=rms, notes=notes,
    )


def _in_range(key: str, value: float) -> bool:
    lo, hi = COVER_RANGES[key]
    return lo <= value <= hi


def _table(presses: PressSet, s_eff: np.ndarray, st: _State, unexercised: np.ndarray,
           knots: int) -> LookupTable:
    """Each tactel's counts -> strain table: the lookup-table builder's piecewise-linear fit
    of the counts against the identified model's strains (offset, gain and shape), or the
    identified straight line where the builder cannot do better (few distinct strains)."""
    from tactiled.calibration.builder import build_table

    rows, cols = presses.shape
    ref = PressSet(presses.counts, s_eff.reshape(presses.counts.shape), presses.sensor_id)
    linear = LookupTable.linear(rows, cols, st.gain.reshape(rows, cols), st.off.reshape(rows, cols),
                                sensor_id=presses.sensor_id or 0)
    try:
        built = build_table(ref, knots=knots).table
    except CalibrationError:
        return linear
    # keep the builder's shape only where it does not leave the straight line by less than
    # the noise: a table of noise wiggles would only add error
    return built if _shape_matters(built, linear, presses, s_eff) else linear


def _shape_matters(built: LookupTable, linear: LookupTable, presses: PressSet, s_eff: np.ndarray) -> bool:
    """True when the built tables fit the presses clearly better than the straight lines
    (a 10 % lower RMS residual in strain)."""
    c = presses.counts.astype(float)
    target = s_eff.reshape(c.shape)
    r_lin = float(np.sqrt(np.mean((linear.to_strain(c) - target) ** 2)))
    r_pl = float(np.sqrt(np.mean((built.to_strain(c) - target) ** 2)))
    return r_pl < 0.9 * r_lin


def format_report(res: Identification) -> str:
    """The human report ``tactiled calibrate --identify`` prints."""
    units = {"depth_x": "mm", "nu_x": "", "depth_y": "mm", "nu_y": "", "modulus": "N/mm^2"}
    lines = [f"identified from {res.presses_loaded} loaded and {res.presses_unloaded} unloaded presses "
             f"in {res.iterations} iterations", "", "| constant | value | 1-sigma | held because |", "|---|---|---|---|"]
    for k in RUBBER:
        sd = res.sigma.get(k)
        note = res.held.get(k, "")
        lines.append(f"| {k} | {res.constants[k]:.5g} {units[k]} | "
                     f"{'held' if sd is None else f'{sd:.2g}'} | {note} |")
    used = int((~res.positions_held).sum())
    pos_sd = res.position_sigma[~res.positions_held]
    lines += [
        "",
        f"tactel gains: median {np.median(res.gains):.6g} counts per unit strain, spread "
        f"{100 * np.std(res.gains) / np.median(res.gains):.2g} % (1-sigma each ~"
        f"{100 * np.median(res.gain_sigma / res.gains):.2g} %)",
        f"tactel positions: {used} of {res.positions_held.size} identified"
        + (f" (median 1-sigma {1000 * np.median(pos_sd):.3g} um, largest displacement "
           f"{1000 * max(np.abs(res.sensor.positions.ex + res.sensor.positions.ey)):.3g} um)"
           if used and res.sensor.positions.ex else "")
        + ("" if used == res.positions_held.size else
           f"; the rest held on the grid (1-sigma above {1000 * POSITION_SIGMA_LIMIT:g} um)"),
        f"press noise: {res.noise_strain:.3g} strain; RMS residual of loaded presses "
        f"{res.rms_strain:.3g} strain",
        f"model-error floor: {res.model_error.strain:.3g} strain + {100 * res.model_error.relative:.3g} % "
        "of the strain (added to the sensor noise in every fit)",
    ]
    lines += [f"note: {n}" for n in res.notes]
    return "\n".join(lines)

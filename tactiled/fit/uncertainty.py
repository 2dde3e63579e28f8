"""What a fit's values are worth: their Cramer-Rao sigmas, widened where the frame says so, and
what is withheld before the one rule (:func:`tactiled.fit.verdict.judge_values`) sees them.

Uncertainties are the Cramer-Rao bound ``sigma^2 (J^T J)^-1`` with J the Jacobian of the window
strains and sigma the sensor's noise, carried to user units by the delta method; a fit whose
residuals exceed the noise, or that its budget stopped short, has them widened; a value its
own sigma says is unknown is withheld with the reason.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from tactiled.fit import budget as fit_budget
from tactiled.fit.budget import EXHAUSTED
from tactiled.fit.models import VALUE_KEYS, Model
from tactiled.fit.params import (
    MAX_ANGLE_SIGMA,
    POOR_RELATIVE_SIGMA,
    RADIUS_LIMITS,
    TOO_LIGHT,
    UNOBSERVABLE_RELATIVE_SIGMA,
    radius_tied_force,
)
from tactiled.fit.search import _chi2_limit
from tactiled.fit.solver import SolveResult
from tactiled.physics.kernels import cramer_rao as crb_kernel

if TYPE_CHECKING:
    from tactiled.fit.fitter import Fitter

#: Singular values below this fraction of the largest make J^T J numerically singular.
SINGULAR_CONDITION = 1e12
#: Above this the fit is reported but flagged as ill-conditioned.
ILL_CONDITION = 1e7

#: A contact whose major axis lies within this angle (degrees) of the finger axis and which is
#: longer than LINE_CONTACT_LENGTH times the array along it is a line contact (see
#: line_contact).  The rubber runs on past the array, so a contact somewhat longer than
#: the array still lies on the finger (flagged, not withheld); 1.5x is where it runs off it.
LINE_CONTACT_ANGLE = 30.0
LINE_CONTACT_LENGTH = 1.5

#: A fit's excess residual feeds the floor learner capped at this multiple of what it expects.
OUTLIER_FACTOR = 10.0

def covariance(jraw: np.ndarray, sigma: float) -> tuple[np.ndarray | None, float | None]:
    """``sigma^2 (J^T J)^-1`` of a Jacobian of strains, and J's condition number; None for a
    singular J."""
    try:
        sv = np.linalg.svd(jraw, compute_uv=False)
    except np.linalg.LinAlgError:
        return None, None
    if sv.size == 0 or not np.all(np.isfinite(sv)) or sv[-1] <= 0.0:  # size 0: no evaluation
        return None, None
    condition = float(sv[0] / sv[-1])
    if condition > SINGULAR_CONDITION:
        return None, condition
    return sigma * sigma * np.linalg.inv(jraw.T @ jraw), condition


def birge(cov: np.ndarray, chi2: float, dof: int, reasons: dict[str, str]) -> np.ndarray:
    """``cov`` times ``chi2 / dof`` (the Birge ratio squared) when chi^2 exceeds what the noise
    gives ``MISMATCH_LEVEL`` of the time for ``dof`` degrees of freedom, saying so in
    ``reasons["uncertainty"]``: residuals that large are errors the noise sigma does not
    count, and the estimate scatters by them (a line's window, where the tactel-level floor
    of :func:`mismatch` is not fitted)."""
    if dof < 1 or not chi2 > _chi2_limit(dof):
        return cov
    reasons["uncertainty"] = (f"residuals exceed the noise (chi^2 {chi2:.3g} for {dof} degrees of "
                              f"freedom): uncertainties widened {math.sqrt(chi2 / dof):.3g}x to match")
    return cov * (chi2 / dof)


def bounds(fitter: Fitter, model: Model, p: np.ndarray, jraw: np.ndarray, reasons: dict[str, str]
) -> tuple[dict[str, float | None], dict[str, float | None], float | None]:
    """User-unit values at ``p``, their Cramer-Rao 1-sigma bounds from ``jraw`` (the
    Jacobian of the window strains, unnormalised) and the condition number of J."""
    values, grad = model.report(p)
    std: dict[str, float | None] = dict.fromkeys(VALUE_KEYS)
    sd, condition = crb_kernel(jraw if jraw.flags.c_contiguous else np.ascontiguousarray(jraw),
                               grad, fitter.sigma)
    if not math.isfinite(condition) or condition > SINGULAR_CONDITION:
        for k in VALUE_KEYS:
            reasons[k] = "Jacobian singular: parameter not identifiable from this window"
        return values, std, (condition if math.isfinite(condition) else None)
    for k, v in zip(VALUE_KEYS, sd.tolist()):
        if v >= 0.0 and values.get(k) is not None:  # NaN (no such quantity) fails
            std[k] = v
    if condition > ILL_CONDITION:
        reasons["condition"] = f"ill-conditioned fit (condition number {condition:.3g})"
    return values, std, condition


def tied_force(fitter: Fitter, model: Model, sol: SolveResult, values: dict[str, float | None],
                std: dict[str, float | None]) -> str | None:
    """Why the force rests on a radius the window does not resolve
    (:func:`tactiled.fit.params.radius_tied_force`), or None: the radius's 1-sigma bound
    as reported, the correlation from the Cramer-Rao covariance at the solution."""
    r, sd_r, sd_f = values.get("r1_mm"), std.get("r1_mm"), std.get("force_n")
    if r is None or sd_r is None or sd_f is None or sd_r < r or sol.jacobian.size == 0:
        return None  # the common case: the radius is bounded away from zero
    try:
        cov = np.linalg.inv(sol.jacobian.T @ sol.jacobian)
    except np.linalg.LinAlgError:
        return None
    _, grad = model.report(sol.p)
    g_f, g_r = grad[VALUE_KEYS.index("force_n")], grad[VALUE_KEYS.index("r1_mm")]
    # the correlation only: the common scale of the covariance cancels
    c_ff, c_rr, c_rf = g_f @ cov @ g_f, g_r @ cov @ g_r, g_r @ cov @ g_f
    if not (c_ff > 0.0 and c_rr > 0.0):
        return None
    return radius_tied_force(r, sd_r, sd_f, float(c_rf / math.sqrt(c_rr * c_ff)) * sd_r * sd_f)


def unsettled(fitter: Fitter, sol: SolveResult, peak: float, values: dict[str, float | None],
               std: dict[str, float | None], reasons: dict[str, str]) -> None:
    """A fit its budget stopped is not at the least-squares minimum.  How far it is, the
    Gauss-Newton step at the stopping point says: it would lower chi^2 by ``D``, and moves
    each value by at most ``sqrt(D)`` of its Cramer-Rao sigma (Cauchy-Schwarz in the
    metric ``J^T J``).  Within ``MAX_REMAINING_CHI2`` every sigma becomes
    ``(1 + sqrt(D))`` times itself, covering that distance on top of the minimum's own
    error; beyond it (where the linear picture that bound rests on fails) the values are
    withheld."""
    if sol.jacobian.size == 0 or not math.isfinite(sol.cost):
        remaining = math.inf
    else:
        step = np.linalg.lstsq(sol.jacobian, -sol.residual, rcond=None)[0]
        moved = sol.jacobian @ step
        remaining = float(moved @ moved) * (peak / fitter.sigma) ** 2
    said = sol.message if sol.message.startswith(EXHAUSTED) else f"{EXHAUSTED} ({sol.message})"
    why = f"{said}: the fit stopped short of the least-squares minimum"
    if not math.isfinite(remaining) or remaining > fit_budget.MAX_REMAINING_CHI2:
        for k in VALUE_KEYS:
            if values.get(k) is not None:
                values[k] = None
                std[k] = None
                reasons[k] = f"{why} (chi^2 {remaining:.3g} above it): not a measurement"
        reasons["fit"] = f"{why} (chi^2 {remaining:.3g} above it): values withheld"
        return
    widen = 1.0 + math.sqrt(remaining)
    for k in VALUE_KEYS:
        if std.get(k) is not None:
            std[k] *= widen
    reasons["fit"] = (f"{why} (chi^2 {remaining:.3g} above it): uncertainties widened "
                      f"{widen:.3g}x to cover the distance")


def mismatch(fitter: Fitter, model: Model, sol: SolveResult, peak: float, zdata: np.ndarray,
              chi2: float, std: dict[str, float | None], reasons: dict[str, str],
              win: tuple[int, int, int, int], valid: np.ndarray, learn: bool = True) -> None:
    """Widen the uncertainties of a fit when residuals say the finger departs from its
    model (see :mod:`tactiled.fit.floor`): by what the sensor's recent fits have shown
    together, and by this frame's own excess when its chi^2 is beyond what the noise gives
    ``MISMATCH_LEVEL`` of the time.  Tactel ``i`` then has variance
    ``V_i = 1 + tau_s^2 z_i^2 + tau_g^2 |grad z_i|^2`` (units of its noise), and the
    covariance becomes the sandwich ``A^-1 J^T V J A^-1``, ``A = J^T J``: what the estimate
    really scatters by under that variance."""
    n, k = sol.jacobian.shape
    dof = n - k
    if dof < 1:
        return
    flagged = chi2 > _chi2_limit(dof)
    if not (flagged or fitter.options.learn_floor):
        return  # the common case of a lone fit that matches its model: nothing to do
    z = peak / fitter.sigma
    jz = sol.jacobian * z  # residual Jacobian in units of each tactel's sd
    rz = sol.residual * z
    try:
        ainv = np.linalg.inv(jz.T @ jz)
    except np.linalg.LinAlgError:
        return
    resid_op = np.eye(n) - jz @ ainv @ jz.T  # M = I - H: residuals are M times the errors
    lev = np.diag(resid_op).copy()  # M_ii = 1 - h_ii
    m2 = zdata * zdata
    g2 = jz[:, -2] ** 2 + jz[:, -1] ** 2  # every model's last two parameters are x0, y0
    msq = resid_op * resid_op
    rows = np.stack((msq @ m2, msq @ g2), axis=1)
    excess_i = rz * rz - lev
    excess = float(excess_i.sum())
    s_f, g_f = float(rows[:, 0].sum()), float(rows[:, 1].sum())
    ts, tg = fitter.floor.taus()
    corrections = None  # what the flat field's own uncertainty adds to the window's errors
    if not fitter.options.learn_floor:
        ts = tg = 0.0
    else:
        learning = learn and not fitter.frozen  # not from a fit its budget stopped short
        if learning:
            weight = feed_floor(fitter, rows, excess_i, excess, s_f, g_f, dof, ts, tg)
        if fitter.flat is not None:
            r0, c0, nr, nc = win
            ii, jj = np.divmod(np.flatnonzero(valid), nc)
            tactels = (r0 + ii) * fitter.flat.cols + (c0 + jj)
            args = (tactels, zdata + rz, jz[:, -2], jz[:, -1])
            corrections = fitter.flat.error_covariance(*args)  # of the corrections in use
            if learning:
                fitter.flat.add(*args[:1], resid_op, *args[1:], rz, weight)
    source = f"the sensor's last ~{fitter.floor.memory} fits"
    if flagged:
        expected = ts * s_f + tg * g_f
        if expected <= 0.0:  # nothing pooled yet: this frame's excess as gain-like error
            ts, tg = max(excess, 0.0) / max(s_f, 1e-300), 0.0
            source = "this frame's residuals"
        elif excess > expected:
            ts, tg = ts * excess / expected, tg * excess / expected
            source = "this frame's residuals"
    if ts <= 0.0 and tg <= 0.0 and corrections is None:
        return
    var = 1.0 + ts * m2 + tg * g2
    cov = ainv @ (jz.T * var) @ jz @ ainv
    if corrections is not None:
        cov += ainv @ jz.T @ corrections @ jz @ ainv
    _, grad = model.report(sol.p)
    for i, key in enumerate(VALUE_KEYS):
        if std.get(key) is None:
            continue
        v = float(grad[i] @ cov @ grad[i])
        if math.isfinite(v) and v > std[key] ** 2:
            std[key] = math.sqrt(v)
    reasons["uncertainty"] = (
        f"residuals exceed the noise (from {source}; chi^2 here {chi2:.3g} for {dof} degrees "
        f"of freedom): the finger departs from its model by ~{100 * math.sqrt(ts):.2g} % of "
        f"the strain and ~{1000 * math.sqrt(tg):.2g} um of tactel position"
        + ("" if corrections is None else
           " beyond the tactel gains and positions learned from its fits (and their own uncertainty)")
        + "; uncertainties widened to match"
        + (f" (flat field: {fitter.flat.note})" if corrections is not None else ""))


def feed_floor(fitter: Fitter, rows: np.ndarray, excess_i: np.ndarray, excess: float, s_f: float, g_f: float,
           dof: int, ts: float, tg: float) -> float:
    """Feed one fit to the floor learner.  Every fit feeds it (leaving out the flagged
    ones, the heavy frames, would bias it low), scaled down to a cap near what the pool
    already expects, so one contact far outside the model (an edge the size of the array)
    moves it by a bounded step.  Returns the scale (<= 1), for the flat field's weight."""
    cap = OUTLIER_FACTOR * (ts * s_f + tg * g_f + math.sqrt(2.0 * dof))
    scale = 1.0
    if excess > cap:
        scale = cap / excess
        excess_i = excess_i * scale
    fitter.floor.add(rows, excess_i, dof)
    return scale


def unobservable(fitter: Fitter, values: dict, std: dict, reasons: dict[str, str]) -> None:
    """Withhold what the data cannot pin down rather than report confident nonsense.

    A radius or force whose Cramer-Rao sigma exceeds ``POOR_RELATIVE_SIGMA`` of it is
    flagged; beyond ``UNOBSERVABLE_RELATIVE_SIGMA`` (or beyond the options' withholding
    threshold, for a radius), or an orientation uncertain by more than ``MAX_ANGLE_SIGMA``,
    it becomes None with the reason.  (A vanishing radius can look "certain" in absolute
    terms: its sigma shrinks with it; relative sigma is the honest test.)
    """
    g = fitter.sensor.geometry
    x, y = values.get("x_mm"), values.get("y_mm")
    inside = (
        x is not None and y is not None
        and -g.dx <= x <= g.span_x + g.dx and -g.dy <= y <= g.span_y + g.dy
    )
    if not inside:
        reasons["model"] = "contact centre outside the array: only the tail of the response is seen"
    withhold = fitter.options.withhold_relative_sigma
    for k in ("r1_mm", "r2_mm", "force_n"):
        v, sd = values.get(k), std.get(k)
        if v is None:
            continue
        rel = (sd / v) if (sd is not None and v > 0) else math.inf
        is_radius = k != "force_n"
        what = "radius" if is_radius else "force"
        # beyond 100 times the value the figure is noise of a degenerate solve (it differed
        # in its leading digits between CPUs): say so, not the digits
        pct = ("unbounded" if math.isinf(rel) else "over 10000 %" if rel > 100.0
               else f"{100 * rel:.0f} %")
        cause = TOO_LIGHT if inside and is_radius else "not observable from this window"
        degenerate = rel > UNOBSERVABLE_RELATIVE_SIGMA or (
            is_radius and not RADIUS_LIMITS[0] <= v <= RADIUS_LIMITS[1])
        if degenerate or (is_radius and withhold is not None and rel > withhold):
            values[k] = None
            std[k] = None
            reasons[k] = f"{cause}: the Cramer-Rao sigma of the {what} is {pct} of it"
        elif rel > POOR_RELATIVE_SIGMA:
            reasons[k] = f"poorly determined ({cause}): the Cramer-Rao sigma is {pct} of it"
    a, sa = values.get("angle_deg"), std.get("angle_deg")
    if a is not None and (sa is None or sa > MAX_ANGLE_SIGMA):
        values["angle_deg"] = None
        std["angle_deg"] = None
        reasons["angle_deg"] = "orientation not observable: Cramer-Rao sigma above 45 deg"


def line_contact(fitter: Fitter, ell, values: dict, std: dict, reasons: dict[str, str]) -> bool:
    """The paper's stated failure case (secs. 5, 8.2): an indentor nearly parallel to the
    finger axis (or nearly flat) makes a Hertz ellipse longer than the finger.  The planar model assumes the
    contact lies on an infinite plane; the real finger ends, and in the window the contact
    is a ridge of constant section, so its radius, its total force and its centre along the
    ridge are not measurable.  Those become None with the reason; the ridge's direction
    and its position across the finger stay.  Returns True for such a line contact.

    Any other contact longer than the array is kept but flagged (``reasons["model"]``).
    """
    g = fitter.sensor.geometry
    c, s = abs(math.cos(ell.theta)), abs(math.sin(ell.theta))
    extent = c * g.span_x + s * g.span_y  # the array's length along the major axis
    if 2.0 * ell.a <= extent:
        return False
    along_finger = c >= math.cos(math.radians(LINE_CONTACT_ANGLE))
    if not (along_finger and 2.0 * ell.a > LINE_CONTACT_LENGTH * extent):
        reasons["model"] = (
            f"contact ellipse {2 * ell.a:.1f} mm long exceeds the array ({extent:.1f} mm along "
            "it): outside the planar model"
        )
        return False
    why = (f"line contact along the finger axis (an indentor nearly parallel to it, or nearly "
           f"flat): the Hertz ellipse ({2 * ell.a:.1f} mm) runs off the array ({extent:.1f} mm), "
           "where the planar model does not hold (paper secs. 5, 8.2)")
    reasons["model"] = why
    for k, what in (("r1_mm", "radius not observable"), ("r2_mm", "radius not observable"),
                    ("force_n", "part of the contact lies beyond the array"),
                    ("x_mm", "the centre along the line is not defined")):
        if values.get(k) is not None or k == "r1_mm":
            values[k] = None
            std[k] = None
            reasons[k] = f"{what}: {why}"
    return True


def label(fitter: Fitter, values: dict[str, float | None], model_name: str) -> str:
    """Paper Table 2 vocabulary: 'edge' (R1 < 1 mm), 'plane' (both radii beyond the
    array's span), else the model name."""
    r1, r2 = values.get("r1_mm"), values.get("r2_mm")
    if r1 is not None and r1 < 1.0:
        return "edge"
    if r1 is not None and r1 > fitter._span and (r2 is None or r2 > fitter._span):
        return "plane"
    return model_name

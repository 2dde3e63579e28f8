"""The model selector (``model="auto"``): the line or cylinder, the sphere and the general
ellipse, ranked by BIC with known noise, ``chi^2 + k ln n`` (Schwarz; docs/concepts/fitting.md).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

import numpy as np

from tactiled.fit import compiled, search
from tactiled.fit.linewindow import RIDGE_ELONGATION, chi2_on_band, spread
from tactiled.fit.models import get_model
from tactiled.fit.result import FitResult

if TYPE_CHECKING:
    from tactiled.fit.fitter import Fitter

#: What a round blob's sphere says (:meth:`ModelSelector.sphere_alone`), as auto says of a line
#: that explains its band
ROUND_MESSAGE = "a round blob the sphere explains to the noise: no other model tried"
#: What a contact among several on a curved array says when its cylinder explains its window
#: (:meth:`ModelSelector.plain`)
PLAIN_MESSAGE = "the cylinder explains the window to the noise: the general ellipse not tried"


class ModelSelector:
    """Chooses among the fitter's models for one frame."""

    def __init__(self, fitter: Fitter) -> None:
        self.fitter = fitter
        #: a contact sought among several: on a curved array the cylinder is scouted
        #: (:meth:`among_several`) ...
        self.several = False
        #: ... and where its strain is a round blob, the sphere is tried alone first
        self.round = False
        #: the sphere's scout :meth:`sphere_alone` made last (:meth:`round_choice` goes on from it)
        self.round_scout: FitResult | None = None
        #: a general ellipse whose cylinder an auto fit tries instead (:meth:`instead_of`)
        self.general: FitResult | None = None

    @contextmanager
    def among_several(self, on: bool = True, round_blob: bool = False) -> Iterator[None]:
        """While open (``on``), a cold auto fit is one contact's among several: on a curved
        array its cylinder is a scout, as a flat array's line is, ranked by its chi^2 and
        solved fully only if it is the answer (its sigmas, profile tests and model-error check
        made once, not for every contact a frame of several seeks); with ``round_blob``
        (:func:`round_blob`) the sphere is tried alone first (:meth:`sphere_alone`)."""
        before = self.several, self.round
        self.several, self.round = on, on and round_blob
        try:
            yield
        finally:
            self.several, self.round = before

    @contextmanager
    def instead_of(self, general: FitResult) -> Iterator[None]:
        """While open, an auto fit tries only the cylinder in place of the general ellipse
        ``general`` (a full solve on the same strain and mask), from its point
        (:meth:`simpler`): the cylinder where it explains the window to the noise, else a
        result that is no contact (``general`` stands)."""
        before = self.general
        self.general = general
        try:
            yield
        finally:
            self.general = before

    def fit(self, strain: np.ndarray, mask: np.ndarray | None,
            warm: tuple[str, tuple[float, ...]] | None = None) -> FitResult:
        """Fit all three models and keep the lowest BIC with known noise,
        ``chi^2 + k ln n`` (Schwarz): a parameter must buy more than ``ln n`` of chi^2.

        With ``warm`` (the previous frame's model and parameters) only that model is fitted,
        from there, and kept if its chi^2 is consistent with the noise.  A line the scout
        ruled out has its profile tests run only if it is the answer
        (:meth:`tactiled.fit.linefit.LineFit.tested`)."""
        line = self.fitter.line
        with line.frames.kept():  # the line's band, read again by criteria
            return line.tested(self.choose(strain, mask, warm))

    def choose(self, strain: np.ndarray, mask: np.ndarray | None,
               warm: tuple[str, tuple[float, ...]] | None = None) -> FitResult:
        """:meth:`fit`'s choice, before a scouted line's profile tests."""
        f = self.fitter
        if self.general is not None:
            return self.simpler(strain, mask, self.general)
        if warm is not None and warm[0] in ("cylinder", "sphere", "general") and warm[1]:
            p_warm = np.asarray(warm[1], dtype=float)
            kept = (f._fit_cylinder(strain, p_warm, mask) if warm[0] == "cylinder"
                    else f._fit_model(strain, get_model(warm[0]), p_warm, mask))
            # (an ellipse running off a flat array is the line: chosen afresh, as a cold fit would)
            if kept.contact and kept.chi2 is not None and kept.peak and search.consistent(f, kept) \
                    and not self.runs_off(kept):
                kept.message = f"model {warm[0]} kept from the previous frame; {kept.message}"
                return kept
        if self.round and warm is None:
            alone = self.sphere_alone(strain, mask)
            if alone is not None:
                return alone
            rounded = self.round_choice(strain, mask)
            if rounded is not None:
                return rounded
        held = f._budget.hold(0.5) if f._budget is not None else None
        flat = f.sensor.geometry.flat
        point_scout = self.several and not flat  # the cylinder scouted (among_several)
        cyl = f.line.fit(strain, None, mask, scout_first=True) if flat \
            else f._fit_model(strain, get_model("cylinder"), None, mask, scouting=point_scout)
        scouted = flat and f.line.scouted and cyl.params is not None
        if held is not None:
            f._budget.release(held)
        if not cyl.contact or cyl.chi2 is None or cyl.params is None or f._out_of_time():
            return self.solved(strain, mask, cyl) if point_scout else cyl
        if f.line.explains(cyl):
            cyl.message = f"the line explains the window to the noise: no other model tried; {cyl.message}"
            return cyl
        fits = [cyl]
        ln_r, psi, ln_f, x0, y0 = f.line.as_point(cyl)
        sph = f._fit_model(strain, get_model("sphere"), np.array([ln_r, ln_f, x0, y0]), mask,
                              scouting=True)
        fits.append(sph)
        if f._out_of_time():
            return self.cut_short(cyl, fits, self.solved(strain, mask, cyl) if point_scout else None)
        if point_scout:  # among several on a curved array: the general only where needed
            plain = self.plain(fits, cyl, strain, mask)
            if plain is not None:
                return plain
        gen_model = get_model("general")
        gen_starts: list[tuple[np.ndarray, float | None]] = [
            (np.array([ln_r, 0.2, psi, ln_f, x0, y0]), None)]
        if sph.params is not None:
            s_ln_r, s_ln_f, sx, sy = sph.params
            # nearly the sphere's own contact: about the sphere's chi^2 (Budget.grant_cost)
            gen_starts.append((np.array([s_ln_r, 0.95, 0.5 * math.pi, s_ln_f, sx, sy]), sph.chi2))
        gens = [f._fit_model(strain, gen_model, p0, mask, scouting=True, start_chi2=c0)
                for p0, c0 in gen_starts]
        fits.append(min(gens, key=lambda r: r.chi2 if r.chi2 is not None else math.inf))
        if f._out_of_time():
            return self.cut_short(cyl, [cyl, sph, *gens],
                                  self.solved(strain, mask, cyl) if point_scout else None)
        crit = self.criteria(fits, cyl, strain, mask)
        best = min(fits, key=lambda r: crit[r.model])
        if best.model == "general" and best.params is not None and not f._out_of_time():
            # The general's two extra parameters must buy their ln n each against the sphere
            # at its best, not against a scout that stopped in another valley (started from
            # the cylinder's point it can end far above the noise on a weak ball: chi^2 190
            # where the sphere from the general's own point reaches 30). The sphere from there.
            ln_ra, _, _, g_ln_f, gx, gy = best.params
            again = f._fit_model(strain, get_model("sphere"),
                                    np.array([ln_ra, g_ln_f, gx, gy]), mask, scouting=True)
            if again.chi2 is not None and (sph.chi2 is None or again.chi2 < sph.chi2):
                again.iterations += sph.iterations
                again.evaluations += sph.evaluations
                fits[1] = sph = again
                crit = self.criteria(fits, cyl, strain, mask)
                best = min(fits, key=lambda r: crit[r.model])
        if best is not cyl and self.runs_off(best):
            best = cyl  # an ellipse longer than the array is the line the cylinder model fits
        iterations = sum(r.iterations for r in fits)
        evaluations = sum(r.evaluations for r in fits)
        resolved = (best is not cyl or point_scout) and best.params is not None
        if best is cyl and scouted and not f._out_of_time():  # the line, scouted: solve it
            best = f.line.solve(strain, cyl, mask)
            iterations += best.iterations - cyl.iterations
            evaluations += best.evaluations - cyl.evaluations
        if resolved:  # scouted: now solve it fully
            best = f._fit_model(strain, get_model(best.model), np.asarray(best.params), mask,
                                   start_chi2=best.chi2)
            iterations += best.iterations
            if self.runs_off(best):
                best, resolved = cyl, False
        best.criterion = {k: float(v) for k, v in crit.items() if math.isfinite(v)}
        best.iterations = iterations
        best.evaluations = evaluations + (best.evaluations if resolved else 0)
        return best

    def plain(self, scouts: list[FitResult], cyl: FitResult, strain: np.ndarray,
              mask: np.ndarray | None) -> FitResult | None:
        """Among several contacts on a curved array: the cylinder, solved fully from where its
        scout ``cyl`` stopped, when that scout converged with chi^2 consistent with the noise
        (:func:`tactiled.fit.search.consistent`) and the information criterion ranks it first
        of the ``scouts`` (the cylinder's and the sphere's); else None, and the general
        ellipse is scouted as :meth:`choose` scouts it for one contact.  Where the cylinder
        explains the window to the noise, the general ellipse's one more parameter can only
        fit the noise or a neighbour's strain (the mirror of a flat array's line that
        explains its band, :meth:`tactiled.fit.linefit.LineFit.explains`): on the paper's
        finger the general was chosen so for 28 % of the crossing cylinders of ``tactiled
        bench --suite contacts``'s grasps, each the costliest fit of its frame (its
        orientation's profile tests).  Not where the sphere ranks first: an ellipsoid whose
        sphere is within the noise is still told from it by the criterion."""
        f = self.fitter
        crit = self.criteria(scouts, cyl, strain, mask)
        if (min(scouts, key=lambda r: crit[r.model]) is not cyl or not cyl.contact
                or not cyl.converged or cyl.chi2 is None or cyl.params is None
                or not search.consistent(f, cyl) or self.runs_off(cyl)):
            return None
        out = self.solved(strain, mask, cyl)
        if not out.contact or out.params is None:
            return None
        out.criterion = {k: float(v) for k, v in crit.items() if math.isfinite(v)}
        out.iterations += sum(r.iterations for r in scouts)
        out.evaluations += sum(r.evaluations for r in scouts)
        out.message = f"{PLAIN_MESSAGE}; {out.message}"
        return out

    def simpler(self, strain: np.ndarray, mask: np.ndarray | None, general: FitResult) -> FitResult:
        """:meth:`plain` for a general ellipse ``general`` solved on this strain and mask: the
        cylinder along its long axis (its radius the smaller) and the sphere (its radius the
        ellipse's first) scouted from the ellipse's point, the cylinder solved fully where it
        explains the window to the noise and ranks first; else a result that is no contact.
        (A contact's model chosen on the whole frame, its window holding its neighbours'
        strain, is tried so again on the frame less theirs: :func:`tactiled.fit.multi.fit_contacts`.)"""
        f = self.fitter
        none = FitResult(contact=False, message="no simpler model explains the window")
        if general.model != "general" or general.params is None or general.chi2 is None:
            return none
        ln_ra, beta, psi, ln_f, x0, y0 = general.params
        b2 = beta * beta
        small, axis = (ln_ra, psi) if b2 <= 1.0 else (ln_ra - math.log(b2), psi + 0.5 * math.pi)
        cyl = f._fit_model(strain, get_model("cylinder"), np.array([small, axis, ln_f, x0, y0]),
                           mask, scouting=True)
        if f._out_of_time():
            return none
        sph = f._fit_model(strain, get_model("sphere"), np.array([ln_ra, ln_f, x0, y0]), mask,
                           scouting=True)
        if f._out_of_time():
            return none
        plain = self.plain([cyl, sph], cyl, strain, mask)
        return none if plain is None else plain

    def sphere_alone(self, strain: np.ndarray, mask: np.ndarray | None) -> FitResult | None:
        """The sphere, when its scout converges with chi^2 consistent with the noise
        (:func:`tactiled.fit.search.consistent`) and no end beyond the array
        (:meth:`runs_off`), solved fully from there; else None, the budget as it was, and
        the full choice follows.  The mirror of :meth:`tactiled.fit.linefit.LineFit.explains`:
        where the sphere explains a round blob, a line (four parameters too) has no ridge to
        follow and the general ellipse's two more could only fit the noise, so neither is
        scouted (two searches of the sphere instead of auto's five or six)."""
        f = self.fitter
        saved = dataclasses.replace(f._budget) if f._budget is not None else None
        sphere = get_model("sphere")
        scout = f._fit_model(strain, sphere, None, mask, scouting=True)
        self.round_scout = scout
        if (scout.contact and scout.converged and scout.chi2 is not None and scout.params is not None
                and search.consistent(f, scout) and not self.runs_off(scout) and not f._out_of_time()):
            best = f._fit_model(strain, sphere, np.asarray(scout.params), mask, start_chi2=scout.chi2)
            if best.contact and best.params is not None and not self.runs_off(best):
                best.iterations += scout.iterations
                best.evaluations += scout.evaluations
                best.message = f"{ROUND_MESSAGE}; {best.message}"
                return best
        if saved is not None:
            f._budget = saved  # the full choice spends what it would have had
        return None

    def round_choice(self, strain: np.ndarray, mask: np.ndarray | None) -> FitResult | None:
        """A round blob among several that the sphere alone does not explain (its scout,
        :meth:`sphere_alone`'s, above the noise: a neighbour's strain in its window, or a
        ball pressed off round): the sphere or the general ellipse, by BIC with known noise
        on the line's band as the full choice ranks them (:meth:`on_band`), the winner solved
        fully.  No line is scouted: a round blob has no
        ridge for it to follow (and a flat array's line explains no ball).  None, the budget
        as it was, when the sphere's scout found no contact or either runs off the array:
        then the full choice follows."""
        f = self.fitter
        sph = getattr(self, "round_scout", None)
        if sph is None or not sph.contact or sph.params is None or sph.chi2 is None \
                or self.runs_off(sph) or f._out_of_time():
            return None
        saved = dataclasses.replace(f._budget) if f._budget is not None else None
        s_ln_r, s_ln_f, sx, sy = sph.params
        gen = f._fit_model(strain, get_model("general"),
                           np.array([s_ln_r, 0.95, 0.5 * math.pi, s_ln_f, sx, sy]), mask,
                           scouting=True, start_chi2=sph.chi2)
        fits = [sph] + ([gen] if gen.contact and gen.params is not None and gen.chi2 is not None
                        and gen.window == sph.window else [])
        crit = {r.model: self.on_band(r, strain, mask) for r in fits}
        best = min(fits, key=lambda r: crit[r.model])
        if best is gen and not f._out_of_time():
            # the general's two extra parameters against the sphere at its best (as choose)
            ln_ra, _, _, g_ln_f, gx, gy = gen.params
            again = f._fit_model(strain, get_model("sphere"), np.array([ln_ra, g_ln_f, gx, gy]),
                                 mask, scouting=True)
            if again.contact and again.chi2 is not None and again.chi2 < sph.chi2 \
                    and again.window == sph.window:
                fits[0] = sph = again
                crit["sphere"] = self.on_band(again, strain, mask)
                best = min(fits, key=lambda r: crit[r.model])
        if self.runs_off(best) or f._out_of_time():
            if saved is not None:
                f._budget = saved
            return None
        out = f._fit_model(strain, get_model(best.model), np.asarray(best.params), mask,
                           start_chi2=best.chi2)
        if not out.contact or out.params is None or self.runs_off(out):
            if saved is not None:
                f._budget = saved
            return None
        out.criterion = {k: float(v) for k, v in crit.items() if math.isfinite(v)}
        out.iterations += sum(r.iterations for r in fits)
        out.evaluations += sum(r.evaluations for r in fits)
        return out

    def on_band(self, r: FitResult, strain: np.ndarray, mask: np.ndarray | None) -> float:
        """A point fit's BIC with known noise on the line's band, as :meth:`criteria` ranks it
        beside the line (the same tactels, so the same choice), or on its own window where
        there is no band."""
        chi2, n = chi2_on_band(self.fitter, strain, mask, r.model, r.params)
        if chi2 is None:
            chi2, n = r.chi2, r.n_points
        return chi2 + len(r.params) * math.log(max(n, 2))

    def solved(self, strain: np.ndarray, mask: np.ndarray | None, scout: FitResult) -> FitResult:
        """A point model's scout solved fully from where it stopped (or, the budget spent,
        reported there, not converged)."""
        if not scout.contact or scout.params is None or scout.model is None:
            return scout
        return self.fitter._fit_model(strain, get_model(scout.model), np.asarray(scout.params), mask,
                                      start_chi2=scout.chi2)

    def criteria(self, fits: list[FitResult], cyl: FitResult, strain: np.ndarray,
                  mask: np.ndarray | None) -> dict[str, float]:
        """Each fit's BIC with known noise, ``chi^2 + k ln n`` (Schwarz), by model.  On a flat
        array the point models' chi^2 is taken on the line's band, so that models are compared
        on the same tactels."""
        f = self.fitter
        flat = f.sensor.geometry.flat
        crit = {}
        for r in fits:
            k = len(r.params) if r.params is not None else get_model(r.model).size
            chi2, n = r.chi2, r.n_points
            if flat and r is not cyl and cyl.window != r.window:  # compared on the line's band
                chi2, n = chi2_on_band(f, strain, mask, r.model, r.params)
            crit[r.model] = (chi2 if chi2 is not None else math.inf) + k * math.log(max(n, 2))
        return crit

    def cut_short(self, cyl: FitResult, fits: list[FitResult],
                  solved: FitResult | None = None) -> FitResult:
        """Auto's answer when its budget ran out while it scouted the other models: the
        cylinder, fully solved (``solved``: the scouted cylinder's solve, among several),
        with every search's iterations and evaluations; the scouts, unfinished, cannot be
        ranked.  ``fit`` says the choice stopped short."""
        out = cyl if solved is None else solved
        done = fits if solved is None else [*fits, solved]
        out.iterations = sum(r.iterations for r in done)
        out.evaluations = sum(r.evaluations for r in done)
        return out

    def runs_off(self, res: FitResult) -> bool:
        """On a flat array: ``res`` (a general or sphere fit) is an ellipse whose both ends lie
        off the array (beyond a pitch of its edge), which within the array is a line contact:
        the line model says the same with fewer parameters and without a force or ends that
        nothing measured."""
        f = self.fitter
        if not f.sensor.geometry.flat or res.params is None or res.model not in compiled.KINDS:
            return False
        a, _, theta, _ = compiled.ellipse_at(compiled.KINDS[res.model], np.asarray(res.params),
                                             f.model._rf, f.model._k)
        if a < 0.0:
            return True
        g = f.sensor.geometry
        x0, y0 = res.params[-2], res.params[-1]
        ends = ((x0 + s * a * math.cos(theta), y0 + s * a * math.sin(theta)) for s in (-1.0, 1.0))
        return all(not (-g.dx <= x <= g.span_x + g.dx and -g.dy <= y <= g.span_y + g.dy)
                   for x, y in ends)


# -- a ball among several contacts ----------------------------------------------------------

def round_blob(band: np.ndarray) -> bool:
    """On a flat array: the line's ``band`` (a boolean frame: the tactels that see the strain
    through the peak, :func:`tactiled.fit.linewindow.band`) is no ridge, at most
    ``RIDGE_ELONGATION`` times as long as wide (second moments of at least three tactels).
    A line's band runs from border to border, three to six tactels wide; a ball's is a disc
    (its half-peak tactels, one to four on a 16x16 pad, are too few to have a shape)."""
    m, n = np.nonzero(band)
    if m.size < 3:
        return False
    small, big, _ = spread(m.astype(float), n.astype(float))
    return bool(big <= small * RIDGE_ELONGATION ** 2)

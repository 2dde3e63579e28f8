"""``tactiled bench --suite shear``: tangential force, torsion, friction and slip on simulated
3-axis arrays (docs/concepts/shear.md).

On ``xela_uskin_4x4``, ``xela_uskin_4x6``, ``flat16`` and the paper's finger made 3-axis:
independent frames (RMS error over the Cramer-Rao bound, coverage of fx, fy, torsion, mu),
pull-until-slip scenes (onset delay), and stick-only scenes (no slip events should be declared).
"""
# 3-axis versions by tactiled.physics.threeaxis.three_axis: magnets at the cover's depth, 2
# readings of noise per axis.
# * independent frames (tactiled/sim/shear.py random_frames: sphere radius 5-20 mm, force 0.5-2 N,
#   Q/(mu P) 0-0.95, mu 0.3-1, torsion +/-0.3 N mm): RMS error over the RMS Cramer-Rao bound and
#   the 2-sigma coverage of fx, fy and the torsion; how often mu is resolved and its coverage;
# * pull-until-slip scenes at 1 kHz: the onset's delay (frames from the true onset to the
#   declared one; estimates and detector run as the daemon's, a fit every FIT_EVERY frames and
#   the step on every frame, from 50 frames before the onset, cold, to 30 after), the share
#   declared within ONSET_FRAMES frames; with the friction turning kinetic at the onset (0.8 of
#   the static: the force drops), with a constant friction (the motion alone shows it), and
#   with a constant friction on varied pulls (ramps of 0.15-0.6 s, the normal force constant or
#   falling by 30 %);
#   and, on the constant-friction pulls, what a test that knew the onset would see
#   ONSET_FRAMES frames after it (the slide and the levelling-off together on the track from
#   the true onset: the information in the readings, which no search over starts can exceed),
#   the slide's statistic alone on that track (the motion: all that tells a slip from a contact
#   held at the friction's limit, whose force levels off too), and from the same tests on the
#   noiseless truth the factor on the signal over the noise that 95 % over COMBINE_Z needs;
# * pulls that stay put at the friction's limit (the simulator's ``limit``: no drop, no motion;
#   the ramp of 0.3 s and varied ones): the same delays, and the margin to slip's sigma
#   ONSET_FRAMES after the onset against the MARGIN_SIGMA the detector's margin rule needs;
# * stick-only scenes (STICKS in turn, every frame of their tangential loading);
# * ``python -m tactiled_bench.shear --sensor NAME --seed N`` prints the slip figures alone
#   (:func:`limits`);
# * along all those scenes, the shear filter's fx, fy and torsion against the truth (error over
#   the filter's sigma); the slide test's null distribution on Gaussian estimates (null_tail),
#   and the whole detector's onsets on contacts held near slip, Gaussian estimates of a fit's
#   covariance (null_events).

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
from scipy.special import ndtr

from tactiled.fit.shear import ShearFitter, ShearStep
from tactiled.fit.shear_filter import ShearFilter, SlideTest
from tactiled.fit.slip import COMBINE_Z, DETECT_WALK, MARGIN_SIGMA, SETTLE, SlipDetector
from tactiled.physics.threeaxis import three_axis
from tactiled.sensors import load_description
from tactiled.sensors.description import SensorDescription
from tactiled.sim.shear import random_frames, sequence

ONSET_FRAMES = 5
#: A full fit on every this many frames, the linearised step (:class:`ShearStep`) on the rest,
#: as the daemon runs it (a fit takes some 10-200 ms; the step microseconds).
FIT_EVERY = 10
#: The detector starts this many frames before a pull's true onset and stops this many after.
LEAD, AFTER = 50, 30


#: The suite's arrays: a description's name or path, or a 1-axis one's name + ``_3axis``.
ARRAYS = ("xela_uskin_4x4", "xela_uskin_4x6", "flat16_3axis", "fearing1988_3axis", "paxini_px6ax")


def resolve(spec: str) -> SensorDescription:
    """The description ``spec`` names; ``NAME_3axis`` is 1-axis ``NAME`` made 3-axis."""
    if spec.endswith("_3axis"):
        return three_axis(load_description(spec[: -len("_3axis")]))
    return load_description(spec)


def _track(fitter: ShearFitter, frames: np.ndarray, first: int, last: int | None = None,
           every: int = FIT_EVERY, truth: dict[str, np.ndarray] | None = None,
           errors: list[tuple[float, float, float]] | None = None,
           known: list[tuple[float, float]] | None = None, clean: list[tuple[float, float]] | None = None,
           margins: list[float] | None = None, biases: list[tuple[float, float]] | None = None
           ) -> list[tuple[str, int]]:
    """Estimate ``frames[first:last]`` in order through a slip detector, as the daemon does: a
    fit (warm-started) on every ``every``-th frame, the step from the last fit on each frame;
    the detector's events.  With ``truth``, ``errors`` gains each frame's errors of the
    filtered ``fx``, ``fy`` and torsion over their sigma (the reported filter's, as the
    daemon's tables, once it has settled), ``known`` the statistics of the best tests that
    know the true onset (:func:`_known_onset`: the slide and the levelling-off together, the
    slide alone) at :data:`ONSET_FRAMES` after it, and ``clean`` the same on the noiseless
    truth (each frame's true parameters with its estimate's covariance): their means, the
    signal the noise scatters about; ``margins`` the 1-sigma of the detector's margin to slip
    (:class:`tactiled.fit.slip.Margin`) :data:`ONSET_FRAMES` after the true onset; ``biases``
    gains the scene's mean error of the unclipped ``lam`` over its sigma on the frames under
    stick whose true ``lam`` is :data:`NEAR_SLIP` or more, and that mean's standard error
    (:func:`_scene_bias`; 10 such frames at least)."""
    det, prev, step, events, near = SlipDetector(), None, None, [], []
    flt = det.tracking
    onset = int(truth["true_onset"]) if truth is not None and "true_onset" in truth else -1
    oracle = (ShearFilter(DETECT_WALK), SlideTest()) if known is not None and onset >= 0 else None
    ideal = (ShearFilter(DETECT_WALK), SlideTest()) if clean is not None and onset >= 0 else None
    for i in range(first, len(frames) if last is None else min(last, len(frames))):
        if step is None or (i - first) % every == 0:
            fit = fitter.fit(frames[i], start=prev)
            prev, step = fit.params, fitter.step(fit)
        est = step(frames[i])
        if oracle is not None and i <= onset + ONSET_FRAMES:
            z = _known_onset(*oracle, est, i - onset)
            if z is not None and known is not None:
                known.append(z)
        if ideal is not None and truth is not None and clean is not None and i <= onset + ONSET_FRAMES:
            z = _known_onset(*ideal, _truth_estimate(truth, i, est), i - onset)
            if z is not None:
                clean.append(z)
        _, ev = det.feed(i, est)
        if biases is not None and truth is not None and NEAR_SLIP <= truth["true_lam"][i] < 1.0 \
                and not truth["true_slip"][i] and est.cov[7, 7] > 0:
            near.append((est.lam_free - truth["true_lam"][i]) / math.sqrt(est.cov[7, 7]))
        if margins is not None and i == onset + ONSET_FRAMES:
            margins.append(det.margin[1])
        if ev is not None:
            events.append((ev.kind, ev.frame))
        if truth is not None and errors is not None and flt.frames > SETTLE:
            errors.append(tuple((flt.value(k)[0] - truth[key][i]) / flt.value(k)[1]
                                for k, key in ((4, "true_fx"), (5, "true_fy"), (6, "true_torque"))))
    if biases is not None and len(near) >= 10:
        z = np.array(near)
        biases.append((float(z.mean()), float(z.std() / math.sqrt(z.size))))
    return events


#: The frames whose bias of ``lam`` the bench measures: under stick, the true ``lam`` at least this.
NEAR_SLIP = 0.8


def _scene_bias(biases: list[tuple[float, float]]) -> tuple[float, float, float, int]:
    """Over the scenes: the mean of their mean error of ``lam`` near slip (in its sigma), the
    spread of those means, the RMS of their standard errors (the spread their noise alone
    makes) and the count of scenes."""
    if not biases:
        return math.nan, math.nan, math.nan, 0
    m, se = np.array(biases).T
    return float(m.mean()), float(m.std()), float(np.sqrt(np.mean(se ** 2))), len(m)


def _known_onset(flt: ShearFilter, test: SlideTest, est, k: int) -> tuple[float, float] | None:
    """Feed ``est`` to a stick filter and its slide test; ``k`` frames after the true onset
    (:data:`ONSET_FRAMES`), the statistic of the slide and the levelling-off together on the
    track that starts at the true onset, accelerating from rest: what a test that knew the
    onset, and so searched no starts, would see there (the information in the readings); and
    the slide's statistic alone on that track: what tells a slip from a contact held at the
    friction's limit, whose force levels off too."""
    flt.update(est.params, est.cov, est.lam_free)
    fx, fy, q, _ = flt.tangential()
    u = (fx / q, fy / q) if q > 0 else (1.0, 0.0)
    test.update(flt, *u)
    if k != ONSET_FRAMES:
        return None
    j = test.track(k + 1, "accelerating")
    return float(test.tracks[j]), float(test.slides[j])


class _Truth:
    """A frame's true parameters (the shear fit's order) with an estimate's covariance."""

    def __init__(self, params: np.ndarray, cov: np.ndarray, lam: float) -> None:
        self.params, self.cov, self.lam_free = params, cov, lam


def _truth_estimate(truth: dict[str, np.ndarray], i: int, est) -> _Truth:
    """Frame ``i``'s truth as an estimate without noise, bounded by ``est``'s covariance."""
    p = np.array([math.log(truth["true_r1"][i]), math.log(truth["true_force"][i])]
                 + [truth[k][i] for k in ("true_x", "true_y", "true_fx", "true_fy", "true_torque", "true_lam")])
    return _Truth(p, est.cov, float(p[7]))


#: The one-sided 95 % point of a unit normal: a statistic whose mean is this far over the
#: threshold exceeds it on 95 % of draws.
Z95 = 1.6449


def snr_needed(clean: list[float], threshold: float = COMBINE_Z, share: float = 0.95) -> float:
    """The factor by which the signal over the noise (the slide's acceleration and the force's
    ramp over the bounds of the estimates) must grow for ``share`` of the pulls' known-onset
    statistics to exceed ``threshold``: each pull's statistic taken as its noiseless value
    ``m`` (which scales with that factor) plus a unit normal, the least ``f`` with ``mean
    Phi(f m - threshold) >= share``.  Below 1: the readings hold that much margin."""
    m = np.array(clean, dtype=float)
    if not m.size or not np.all(np.isfinite(m)) or m.max() <= 0:
        return math.nan
    lo, hi = 0.0, 1.0
    while np.mean(ndtr(hi * m - threshold)) < share:
        hi *= 2.0
        if hi > 1e3:
            return math.inf
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.mean(ndtr(mid * m - threshold)) < share else (lo, mid)
    return hi


def null_tail(desc: SensorDescription, frames: int, seed: int) -> dict[str, float]:
    """The slide test under the stick hypothesis: a held contact's estimates drawn from the
    fit's covariance (its tangential force ramping, then held), through the filter and the
    test; the share of frames whose statistic exceeds 3, 4 and :data:`COMBINE_Z` sigma (the
    combined rule's threshold; the slide alone needs :data:`tactiled.fit.slip.ONSET_Z`)."""
    rng = np.random.default_rng(seed)
    fitter = ShearFitter(desc)
    scene, _ = sequence(desc, "push", rng)
    est = fitter.fit(scene[-1])
    keep = np.nonzero(np.isfinite(np.diag(est.cov)))[0]
    chol = np.linalg.cholesky(est.cov[np.ix_(keep, keep)])
    zs: list[float] = []
    while len(zs) < frames:
        flt, test = ShearFilter(DETECT_WALK), SlideTest()
        for i in range(400):
            p = est.params.copy()
            p[4:6] *= min(1.0, (i + 1) / 200)
            p[keep] += chol @ rng.normal(size=keep.size)
            flt.update(p, est.cov)
            fx, fy, _, _ = flt.tangential()
            z = test.update(flt, *((fx, fy) / np.hypot(fx, fy)))
            if flt.frames > SETTLE:
                zs.append(z)
    a = np.array(zs[:frames])
    return {"frames": float(a.size), "over3": float(np.mean(a > 3.0)), "over4": float(np.mean(a > 4.0)),
            "over_onset": float(np.mean(a > COMBINE_Z))}


def null_events(desc: SensorDescription, scenes: int, seed: int, hold: float = 0.95,
                hold_frames: int = 300) -> dict[str, float]:
    """Slip onsets declared on held contacts near slip: a push to ``hold`` of ``mu P`` fitted
    once; its true parameters, the tangential force and ``lam`` ramping to them (over 150-600
    frames) and held, drawn ``scenes`` times with Gaussian noise of the fit's covariance through
    the slip detector (the whole detector: every rule, on the stick hypothesis's null).  The
    draws centre on the truth, not on the fit: a fit whose ``lam`` sat at 1 would make every
    draw a contact at the limit."""
    rng = np.random.default_rng(seed)
    fitter = ShearFitter(desc)
    scene, truth = sequence(desc, "push", rng, hold=hold)
    est = fitter.fit(scene[-1])
    fit_lam = float(est.params[7])
    est.params = _truth_estimate(truth, len(scene) - 1, est).params
    keep = np.nonzero(np.isfinite(np.diag(est.cov)))[0]
    chol = np.linalg.cholesky(est.cov[np.ix_(keep, keep)])
    onsets, frames = 0, 0
    for _ in range(scenes):
        det = SlipDetector()
        ramp = int(rng.integers(150, 601))
        for i in range(ramp + hold_frames):
            p = est.params.copy()
            s = min(1.0, (i + 1) / ramp)
            p[4:6] *= s
            p[7] *= s
            p[keep] += chol @ rng.normal(size=keep.size)
            lam_free = float(p[7])
            p[7] = min(1.0, max(0.0, lam_free))
            _, ev = det.update(i, p, est.cov, lam_free)
            onsets += ev is not None and ev.kind == "onset"
            frames += 1
    return {"scenes": float(scenes), "frames": float(frames), "onsets": float(onsets),
            "lam": fit_lam, "lam_sigma": float(np.sqrt(est.cov[7, 7]))}


def centre_along_q(desc: SensorDescription, scenes: int, seed: int) -> dict[str, tuple[float, float, int]]:
    """The centre's error along the true tangential force, in its sigma, on pushes to 0.8 ``mu
    P`` (stick throughout: the centre does not move), every frame from 30 before the load, the
    step from a fit every :data:`FIT_EVERY` frames: per kind of frame (``fit``, ``step``) and
    band of the true ``lam`` (0-0.3, 0.3-0.6, 0.6-1), the mean, the spread and the frames.  A
    shift of the centre by the cover's shear under the load, were the model to miss it, shows
    as a mean away from 0 growing with ``lam``."""
    rng = np.random.default_rng(seed)
    fitter = ShearFitter(desc)
    rows: dict[bool, list[tuple[float, float]]] = {True: [], False: []}
    for _ in range(scenes):
        frames, truth = sequence(desc, "push", rng)
        loaded = int(np.argmax(np.hypot(truth["true_fx"], truth["true_fy"]) > 0))
        first, prev, step = max(0, loaded - 30), None, None
        for i in range(first, len(frames)):
            fitted = step is None or (i - first) % FIT_EVERY == 0
            if fitted:
                fit = fitter.fit(frames[i], start=prev)
                prev, step = fit.params, fitter.step(fit)
            est = step(frames[i])
            q = math.hypot(truth["true_fx"][i], truth["true_fy"][i])
            if q <= 0:
                continue
            u = np.array((truth["true_fx"][i], truth["true_fy"][i])) / q
            e = np.array((est.params[2] - truth["true_x"][i], est.params[3] - truth["true_y"][i]))
            s = math.sqrt(float(u @ est.cov[2:4, 2:4] @ u))
            rows[fitted].append((float(u @ e) / s, float(truth["true_lam"][i])))
    out = {}
    for fitted, v in rows.items():
        a = np.array(v).reshape(-1, 2)
        for lo, hi in ((0.0, 0.3), (0.3, 0.6), (0.6, 1.0)):
            z = a[(a[:, 1] >= lo) & (a[:, 1] < hi), 0]
            out[f"{'fit' if fitted else 'step'} {lo:g}-{hi:g}"] = (
                float(z.mean()) if z.size else math.nan, float(z.std()) if z.size else math.nan, int(z.size))
    return out


def accuracy(desc: SensorDescription, n: int, seed: int) -> dict[str, float]:
    """RMS/CRB and 2-sigma coverage of fx, fy, torque; mu's resolved share and coverage."""
    frames, truth = random_frames(desc, n, np.random.default_rng(seed))
    fitter = ShearFitter(desc)
    err, sig, mu_z = [], [], []
    for i in range(n):
        est = fitter.fit(frames[i])
        p, s = est.params, est.sigma
        err.append((p[4] - truth["true_fx"][i], p[5] - truth["true_fy"][i], p[6] - truth["true_torque"][i]))
        sig.append((s[4], s[5], s[6]))
        mu, s_mu, _ = est.mu()
        if mu is not None:
            mu_z.append((mu - truth["true_mu"][i]) / s_mu)
    e, s = np.array(err), np.array(sig)
    out = {}
    for k, name in enumerate(("fx", "fy", "torque")):
        out[f"{name}_ratio"] = float(np.sqrt(np.mean(e[:, k] ** 2)) / np.sqrt(np.mean(s[:, k] ** 2)))
        out[f"{name}_cover"] = float(np.mean(np.abs(e[:, k]) <= 2 * s[:, k]))
        out[f"{name}_crb"] = float(np.sqrt(np.mean(s[:, k] ** 2)))
    out["mu_resolved"] = len(mu_z) / n
    out["mu_cover"] = float(np.mean(np.abs(mu_z) <= 2)) if mu_z else math.nan
    out["mu_beyond4"] = float(np.mean(np.abs(mu_z) > 4)) if mu_z else math.nan
    return out


#: The stick-only scenes, in turn: a push to 0.8 mu P, a twist, a push held near slip (0.95
#: mu P), a push while the normal force falls by 30 % (Q following it at 0.8 mu P).
STICKS = (("push", {}), ("twist", {}), ("push", {"hold": 0.95}), ("push", {"force_change": -0.3}),
          ("push", {"hold": 0.9}))


def slip(desc: SensorDescription, pulls: int, sticks: int, seed: int, kinetic: float = 0.8,
         varied: bool = False, errors: list[tuple[float, float, float]] | None = None,
         kind: str = "pull") -> dict[str, float]:
    """Onset delays on pull scenes (friction turning kinetic at ``kinetic`` times the static;
    ``varied``: each pull's ramp drawn in 0.15-0.6 s and its normal force constant or falling
    by 30 % over it), slip events on stick-only scenes (:data:`STICKS` in turn); ``errors``
    gains the filtered forces' errors over their sigma along every scene.  ``kind`` ``limit``:
    the pulls stay put at the friction's limit (no drop, no motion; ``kinetic`` unused).  A
    pull's delay is the first onset's from :data:`ONSET_FRAMES` before the true one (negative:
    declared before it, as the margin's bound allows); ``early`` counts onsets before that."""
    rng = np.random.default_rng(seed)
    fitter = ShearFitter(desc)
    delays, early, known, clean, margins, biases = [], 0, [], [], [], []
    for _ in range(pulls):
        extra = {"ramp_s": rng.uniform(0.15, 0.6), "force_change": rng.choice((0.0, -0.3))} if varied else {}
        frames, truth = sequence(desc, kind, rng, kinetic=kinetic, **extra)
        onset = int(truth["true_onset"])
        events = _track(fitter, frames, onset - LEAD, onset + AFTER, truth=truth, errors=errors, known=known,
                        clean=clean, margins=margins, biases=biases)
        onsets = [f for ev, f in events if ev == "onset"]
        declared = next((f for f in onsets if f >= onset - ONSET_FRAMES), None)
        early += sum(1 for f in onsets if f < onset - ONSET_FRAMES)
        delays.append(math.inf if declared is None else declared - onset)
    false = 0
    for k in range(sticks):
        scene, extra = STICKS[k % len(STICKS)]
        frames, truth = sequence(desc, scene, rng, **extra)
        loaded = int(np.argmax(np.abs(truth["true_fx"]) + np.abs(truth["true_fy"]) + np.abs(truth["true_torque"]) > 0))
        false += sum(1 for ev, _ in _track(fitter, frames, max(0, loaded - 30), truth=truth, errors=errors,
                                           biases=biases)
                     if ev == "onset")
    d = np.array(delays)
    ok = d[np.isfinite(d)]
    m = np.array(margins, dtype=float)
    return {"pulls": pulls, "within": float(np.mean(np.abs(d) <= ONSET_FRAMES)) if pulls else math.nan,
            "margin_resolved": float(np.mean(m <= MARGIN_SIGMA)) if m.size else math.nan,
            "margin_snr_needed": float(np.percentile(m, 95) / MARGIN_SIGMA) if m.size else math.nan,
            "median_delay": float(np.median(ok)) if ok.size else math.nan,
            "max_delay": float(ok.max()) if ok.size else math.nan, "missed": int(np.sum(~np.isfinite(d))),
            "early": early, "sticks": sticks, "false": false,
            "p95_delay": _p95(d) if pulls else math.nan,
            "biases": biases, **_known_figures(known, clean)}


def _p95(d: np.ndarray) -> float:
    """The 95th percentile of delays, ``inf`` where it falls among the missed pulls (``inf``)."""
    ok = np.isfinite(d)
    if ok.all():
        return float(np.percentile(d, 95))
    v = float(np.percentile(np.where(ok, d, 1e9), 95))
    return v if v <= d[ok].max(initial=-math.inf) else math.inf


def _known_figures(known: list[tuple[float, float]], clean: list[tuple[float, float]]) -> dict[str, float]:
    """The known-onset statistics' median and share over :data:`COMBINE_Z` (the slide and the
    levelling-off together: ``known_``; the slide alone: ``motion_``), the noiseless ones'
    median (``clean_``, ``motion_clean_``) and the factor on the signal over the noise that
    95 % over :data:`COMBINE_Z` needs (``snr_needed``, ``motion_snr_needed``)."""
    out: dict[str, float] = {}
    k, c = np.array(known, dtype=float).reshape(-1, 2), np.array(clean, dtype=float).reshape(-1, 2)
    for j, name in enumerate(("known", "motion")):
        out[f"{name}_median"] = float(np.median(k[:, j])) if k.size else math.nan
        out[f"{name}_over"] = float(np.mean(k[:, j] > COMBINE_Z)) if k.size else math.nan
    for j, name in enumerate(("clean", "motion_clean")):
        out[f"{name}_median"] = float(np.median(c[:, j])) if c.size else math.nan
    out["snr_needed"] = snr_needed(list(c[:, 0])) if c.size else math.nan
    out["motion_snr_needed"] = snr_needed(list(c[:, 1])) if c.size else math.nan
    return out


def run(quick: bool, progress: bool | None, sensors: list[str] | None = None, seed: int = 1,
        say: Callable[[str], None] | None = None) -> str:
    """The suite's Markdown tables (``sensors`` replaces the arrays: 3-axis descriptions)."""
    descs = [resolve(s) for s in (sensors or ARRAYS)]
    for d in descs:
        if d.axes != 3:
            from tactiled.errors import ConfigError

            raise ConfigError(f"sensor {d.name!r} is a 1-axis array: the shear suite needs axes = 3")
    n, pulls, flat, sticks, null = (40, 3, 3, 4, 2000) if quick else (150, 20, 20, 8, 20000)
    rows_a, rows_s, rows_f, rows_l = [], [], [], []
    for k, d in enumerate(descs):
        t0 = time.perf_counter()
        a = accuracy(d, n, seed + 10 * k)
        errors: list[tuple[float, float, float]] = []
        s = slip(d, pulls, sticks, seed + 10 * k + 1, errors=errors)
        c = slip(d, flat, 0, seed + 10 * k + 2, kinetic=1.0, errors=errors)
        v = slip(d, flat, 0, seed + 10 * k + 3, kinetic=1.0, varied=True, errors=errors)
        lim = slip(d, flat, 0, seed + 10 * k + 6, kind="limit", errors=errors)
        limv = slip(d, flat, 0, seed + 10 * k + 7, kind="limit", varied=True, errors=errors)
        tail = null_tail(d, null, seed + 10 * k + 4)
        held = null_events(d, 4 if quick else 20, seed + 10 * k + 5)
        if progress is not False:
            import sys

            print(f"shear: {d.name} in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        rows_a.append(f"| {d.name} | {d.rows}x{d.cols} | "
                      + " | ".join(f"{a[f'{q}_ratio']:.2f} / {a[f'{q}_cover']:.0%}" for q in ("fx", "fy", "torque"))
                      + f" | {a['fx_crb'] * 1000:.1f} mN, {a['torque_crb']:.3f} N mm"
                      + f" | {a['mu_resolved']:.0%} | "
                      + (f"{a['mu_cover']:.0%} / {a['mu_beyond4']:.0%}" if math.isfinite(a["mu_cover"]) else "-")
                      + " |")
        rows_s.append(f"| {d.name} | " + " | ".join(
            f"{r['within']:.0%} ({r['pulls']}), {r['median_delay']:g} / {r['p95_delay']:g} / {r['max_delay']:g}, {r['missed']}"
            for r in (s, c, v)) + " | " + " / ".join(
            f"{r['known_over']:.0%} ({r['known_median']:.1f})" for r in (c, v))
            + " | " + " / ".join(f"{r['motion_over']:.0%} ({r['motion_median']:.1f})" for r in (c, v))
            + " | " + " / ".join(f"{r['snr_needed']:.2f}, {r['motion_snr_needed']:.2f}" for r in (c, v))
            + f" | {s['early'] + c['early'] + v['early']} | {s['false']} ({s['sticks']}) |")
        rows_l.append(f"| {d.name} | " + " | ".join(
            f"{r['within']:.0%} ({r['pulls']}), {r['median_delay']:g} / {r['p95_delay']:g} / {r['max_delay']:g}, "
            f"{r['missed']}, {r['early']}" for r in (lim, limv)) + " | " + " / ".join(
            f"{r['margin_resolved']:.0%}" for r in (lim, limv)) + " | " + " / ".join(
            f"{r['margin_snr_needed']:.2f}" for r in (lim, limv)) + " |")
        e = np.array(errors).reshape(-1, 3)
        rows_f.append(f"| {d.name} | " + " | ".join(
            f"{np.sqrt(np.mean(e[:, j] ** 2)):.2f} / {np.mean(np.abs(e[:, j]) <= 2):.0%}" for j in range(3))
            + f" | {len(e)} | {tail['over3']:.1e} / {tail['over4']:.1e} / {tail['over_onset']:.1e} ({tail['frames']:.0f})"
            + f" | {held['onsets']:.0f} ({held['scenes']:.0f}, {held['frames']:.0f} frames) |")
    head_a = ["| array | taxels | fx RMS/CRB / 2-sigma cover | fy | torque | RMS CRB (fx, torque) "
              "| mu resolved | mu 2-sigma cover / beyond 4 sigma |", "|---|---|---|---|---|---|---|---|"]
    head_s = [f"| array | friction turning kinetic: within {ONSET_FRAMES} frames (pulls), delay median / p95 / max, missed "
              "| constant friction: the same | constant friction, varied pulls: the same "
              f"| the onset known: over {COMBINE_Z:g} sigma at {ONSET_FRAMES} frames (median sigma), constant / varied "
              f"| the onset known, the motion alone: the same "
              f"| the factor on the signal over the noise that {COMBINE_Z:g} sigma on 95 % needs: both, the motion alone; "
              "constant / varied "
              "| early | slip events on stick-only scenes (scenes) |", "|---|---|---|---|---|---|---|---|---|"]
    head_f = ["| array | filtered fx error/sigma RMS / 2-sigma cover | fy | torque | frames "
              f"| slide test under stick: share of frames over 3 / 4 / {COMBINE_Z:g} sigma (frames) "
              "| slip onsets on contacts held at 0.95 mu P (scenes) |",
              "|---|---|---|---|---|---|---|"]
    head_l = [f"| array | at the limit, the ramp of 0.3 s: within {ONSET_FRAMES} frames (pulls), delay median / p95 / max, "
              "missed, early | at the limit, varied pulls: the same "
              f"| the margin resolved ({MARGIN_SIGMA:g}) {ONSET_FRAMES} frames after the onset, 0.3 s / varied "
              "| the factor on the signal over the noise that resolves it on 95 % (its sigma's p95 over "
              f"{MARGIN_SIGMA:g}), 0.3 s / varied |", "|---|---|---|---|---|"]
    return "\n".join([f"Independent frames ({n} per array):", "", *head_a, *rows_a, "",
                      f"Slip: pull-until-slip and stick-only scenes at 1 kHz (a fit every {FIT_EVERY} frames, "
                      "the step on every frame, as the daemon runs); delays in frames (ms at 1 kHz):", "",
                      *head_s, *rows_s, "",
                      "Pulls that stay put at the friction's limit (no force drop, no motion: the margin "
                      "to slip alone shows the onset):", "", *head_l, *rows_l, "",
                      "The shear filter along those scenes, and the slide test's null distribution:", "",
                      *head_f, *rows_f])


def limits(sensors: list[str], seed: int, pulls: int, sticks: int) -> str:
    """The slip figures alone, per array: pulls that stay put at the friction's limit (the ramp
    of 0.3 s and varied ramps), pulls that slide with a constant friction, the stick-only
    scenes (:data:`STICKS` in turn) and contacts held at 0.95 ``mu P`` drawn from a fit's
    covariance (:func:`null_events`, 20 scenes).  ``python -m tactiled_bench.shear``."""
    rows = ["| array | at the limit, 0.3 s: within / delay p50, p95 / missed, early | at the limit, varied: the same "
            f"| margin resolved ({MARGIN_SIGMA:g}) at +{ONSET_FRAMES}, 0.3 s / varied; sigma p95 over it "
            "| sliding, constant friction: within / delay p50, p95 / missed, early "
            "| onsets on stick-only scenes (scenes) | onsets on held contacts (scenes) "
            f"| lam's error near slip (true lam >= {NEAR_SLIP:g}, under stick): mean of the scenes' means, their "
            "spread / their noise (scenes), sigma |",
            "|---|---|---|---|---|---|---|---|"]
    for k, spec in enumerate(sensors):
        d = resolve(spec)
        base = seed + 10 * k
        lim = slip(d, pulls, 0, base + 6, kind="limit")
        limv = slip(d, pulls, 0, base + 7, kind="limit", varied=True)
        c = slip(d, pulls, sticks, base + 2, kinetic=1.0)
        held = null_events(d, 20, base + 5)

        def cell(r: dict[str, float]) -> str:
            return (f"{r['within']:.0%} ({r['pulls']}) / {r['median_delay']:g}, {r['p95_delay']:g} / "
                    f"{r['missed']}, {r['early']}")

        rows.append(f"| {d.name} | {cell(lim)} | {cell(limv)} | {lim['margin_resolved']:.0%} / "
                    f"{limv['margin_resolved']:.0%}; {lim['margin_snr_needed']:.2f} / {limv['margin_snr_needed']:.2f} "
                    f"| {cell(c)} | {c['false']} ({c['sticks']}) | {held['onsets']:.0f} ({held['scenes']:.0f}) "
                    "| {:+.2f}, {:.2f} / {:.2f} ({}) |".format(*_scene_bias(lim["biases"] + limv["biases"] + c["biases"])))
    return "\n".join(rows)


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(prog="python -m tactiled_bench.shear", description=limits.__doc__)
    ap.add_argument("--sensor", action="append", required=True)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--pulls", type=int, default=10)
    ap.add_argument("--sticks", type=int, default=5)
    a = ap.parse_args()
    print(limits(a.sensor, a.seed, a.pulls, a.sticks))

"""The temporal tracker on its own (tactiled/pipeline/contact_filter.py), fed the way the daemon feeds
it: real fits and real linearisations from the worker's code, frames from the physics with
Gaussian noise, played synchronously (no processes, so the numbers are exact to the frame).
Bounds are in units of the single-frame Cramer-Rao bound at the truth, computed by the fitter
independently of the tracker."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled.sensors.model import NoiseModel, SensorModel
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.linearize import linearize
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
from tactiled.pipeline.contact_filter import MAX_FORCE_N, RATE_KEYS, Tracker, untracked, within_reason

SIGMA = 0.0005
RATE = 1000.0  # frames/s


@pytest.fixture(scope="module")
def kit():
    sensor = SensorModel(noise=NoiseModel(sigma=SIGMA))
    return Fitter(sensor, FitOptions(withhold_relative_sigma=0.5)), StrainModel(sensor)


def play(kit, truth, frames: int, seed: int, tracker: Tracker | None = None,
         nan_at: tuple[int, ...] = ()) -> tuple[list, Tracker, int]:
    """Frames of ``truth(t)`` through a tracker as the daemon runs it: a fit (and its
    linearisation) when the tracker asks for one, a relinearisation when it wants one.
    Returns ``[(t, contact, estimate, status)]``, the tracker and the number of fits."""
    fitter, model = kit
    rng = np.random.default_rng(seed)
    tr = tracker or Tracker(withhold_relative_sigma=0.5)
    out, base, fits = [], None, 0
    for k in range(frames):
        t = k / RATE
        c = truth(t)
        s = model.predict(c) + rng.normal(0.0, SIGMA, (8, 8))
        if k in nan_at:
            tr.skip()
            out.append((t, c, tr.estimate(base), "skipped"))
            continue
        status = tr.step(s.ravel(), t) if tr.active else "refit"
        if status == "refit":
            res = fitter.fit(s, "cylinder", warm=tr.predicted(t))
            fits += 1
            lin = None if res.params is None else linearize(fitter, s, res.model, np.array(res.params))
            if lin is None:  # nothing to track from (a frame at the noise): as the daemon does
                tr.clear()
                out.append((t, c, res.to_json_dict(), "untracked"))
                continue
            tr.adopt(lin)
            status = tr.step(s.ravel(), t, fitted=True)
            base = res.to_json_dict()
        want = tr.wants_linearization()
        if want is not None:
            lin = linearize(fitter, s, want[0], want[1])
            if lin is not None:
                tr.adopt(lin)
        out.append((t, c, tr.estimate(base), status))
    return out, tr, fits


def crb(kit, c: Contact) -> dict:
    fitter, model = kit
    s = model.predict(c)
    p = fitter.fit(s, "cylinder").params
    return fitter.cramer_rao(s, "cylinder", np.array(p))


HELD = Contact(r1=10.0, psi_deg=60.0, force=1.2, x0=8.0, y0=9.0)


def test_a_held_contact_sharpens_like_one_over_sqrt_frames(kit) -> None:
    bound = crb(kit, HELD)
    errs = {25: [], 100: [], 400: []}
    sds = {25: [], 100: [], 400: []}
    for seed in range(12):
        out, tr, fits = play(kit, lambda t: HELD, 401, seed)
        assert fits == 1 and tr.resets == 0  # one fit, then every frame measured
        for n in errs:
            _, _, e, _ = out[n - 1]
            assert e["frames_used"] == n
            errs[n].append(e["r1_mm"] - HELD.r1)
            sds[n].append(e["std"]["r1_mm"])
    for n in errs:
        sd = float(np.median(sds[n]))
        # the reported sigma follows the bound over sqrt(frames) (the curvature averages
        # every frame), within 25 %
        assert sd == pytest.approx(bound["r1_mm"] / math.sqrt(n), rel=0.25), n
        rms = math.sqrt(np.mean(np.square(errs[n])))
        assert rms < 1.6 * sd, (n, rms, sd)  # 12 samples: chi-square's 99.9 % is 1.6^2
    # the bars: after 100 ms under a third of the single-frame bound, after 400 ms
    # well on the way to the tenth it asks at 1 s
    assert math.sqrt(np.mean(np.square(errs[100]))) < bound["r1_mm"] / 3
    assert math.sqrt(np.mean(np.square(errs[400]))) < bound["r1_mm"] / 6


def test_a_light_contact_is_measured_not_refitted_for_its_noisy_radius(kit) -> None:
    """0.2 N on a 10 mm cylinder: one frame's sigma of ln R is 1.35, so a frame measured
    through the linearisation often steps ln R by more than 1.  That is noise, not a jump
    beyond the linear range: the tracker weighs it, where refitting every such frame (as it
    once did: 140-167 fits in these 400 frames) restarted the radius's average each time and
    left it 7-9 sigma off."""
    light = Contact(r1=10.0, psi_deg=60.0, force=0.2, x0=8.0, y0=9.0)
    assert crb(kit, light)["r1_mm"] / light.r1 > 1.0  # ln R's single-frame sigma
    z = []
    for seed in range(6):
        out, _, fits = play(kit, lambda t: light, 400, seed)
        e = out[-1][2]
        assert fits <= 20, (seed, fits)
        z.append((e["r1_mm"] - light.r1) / e["std"]["r1_mm"])
        assert e["force_n"] == pytest.approx(light.force, rel=0.03)
    # 6 fixed seeds: the worst within 3.5 sigma, typically within 2 (a radius this poorly
    # determined averages in log, so a small bias upward remains)
    assert max(abs(v) for v in z) < 3.5 and float(np.median(np.abs(z))) < 2.0, z


@pytest.mark.parametrize("motion", ["roll 5 mm/s", "turn 45 deg/s"])
def test_a_moving_contact_is_followed_without_lag(kit, motion) -> None:
    if motion.startswith("roll"):
        rate, key, attr, rate_key = 5.0, "x_mm", "x0", "vx_mm_s"

        def truth(t: float) -> Contact:
            return Contact(r1=10, psi_deg=60, force=1.2, x0=7 + rate * t, y0=9.0)
    else:
        rate, key, attr, rate_key = 45.0, "angle_deg", "psi_deg", "angle_rate_deg_s"

        def truth(t: float) -> Contact:
            return Contact(r1=10, psi_deg=60 + rate * t, force=1.2, x0=8, y0=9)
    bound = crb(kit, HELD)
    lags, rates = [], []
    for seed in range(4):
        out, _, _ = play(kit, truth, 600, seed)
        for _, c, e, _ in out[100:]:
            lags.append(e[key] - getattr(c, attr))
            rates.append(e[rate_key])
    # the bars: median signed error within 0.2 single-frame sigmas, rate within 10 %
    assert abs(float(np.median(lags))) < 0.2 * bound[key]
    assert float(np.median(rates)) == pytest.approx(rate, rel=0.1)


@pytest.mark.parametrize("change", ["force step", "jump"])
def test_a_step_shows_at_once_and_restarts_the_accumulation(kit, change) -> None:
    def truth(t: float) -> Contact:
        after = t >= 0.3
        if change == "force step":
            return Contact(r1=10, psi_deg=60, force=1.2 * (1.2 if after else 1.0), x0=8, y0=9)
        return Contact(r1=10, psi_deg=60, force=1.2, x0=8 + (0.5 if after else 0.0), y0=9)

    out, tr, _ = play(kit, truth, 340, seed=3)
    step = 300
    key, attr, size = (("force_n", "force", 0.24) if change == "force step"
                       else ("x_mm", "x0", 0.5))
    assert out[step - 1][3] == "tracked" and out[step - 1][2]["frames_used"] == step
    # the step frame itself is fitted and restarts the filter: frames_used back to 1
    assert out[step][3] == "reset" and out[step][2]["frames_used"] == 1
    for k in (step, step + 1):  # visible within 2 frames: past 90 % of the step
        e, c = out[k][2], out[k][1]
        assert abs(e[key] - getattr(c, attr)) < 0.1 * size, (k, e[key])
    # a force step does not change the object: the radius keeps its accumulated precision
    if change == "force step":
        assert out[step + 5][2]["std"]["r1_mm"] < 0.3 * crb(kit, truth(0.5))["r1_mm"]
    assert tr.resets == 1


def test_unusable_frames_are_skipped_and_counted_never_averaged_in(kit) -> None:
    out, tr, _ = play(kit, lambda t: HELD, 60, seed=5, nan_at=(30, 31))
    assert tr.skipped == 2
    assert out[30][2]["frames_used"] == out[29][2]["frames_used"] == 30
    assert out[30][2]["r1_mm"] == out[29][2]["r1_mm"]
    assert out[32][2]["frames_used"] == 31


def test_time_running_backwards_restarts_the_filter(kit) -> None:
    fitter, model = kit
    out, tr, _ = play(kit, lambda t: HELD, 50, seed=6)
    s = model.predict(HELD) + np.random.default_rng(1).normal(0, SIGMA, (8, 8))
    assert tr.step(s.ravel(), 0.001) == "reset"  # the device restarted its clock
    assert tr.n == 1 and tr.resets == 1
    e = tr.estimate(out[-1][2])
    assert e["frames_used"] == 1 and all(e[k] is None for k in RATE_KEYS)
    assert "too few frames" in e["reasons"]["vx_mm_s"]


def test_an_estimate_it_did_not_make_carries_its_keys_empty() -> None:
    fit = {"contact": False, "std": {"x_mm": None}, "reasons": {}}
    out = untracked(fit, 0, "no contact")
    assert out["frames_used"] == 0 and all(out[k] is None for k in RATE_KEYS)
    assert all(out["reasons"][k] == "no contact" for k in RATE_KEYS)
    assert fit == {"contact": False, "std": {"x_mm": None}, "reasons": {}}  # not modified


def test_a_start_beyond_what_a_finger_carries_is_clipped() -> None:
    """A worker's fit or linearisation starts from the tracker's state only within reason: a
    filter on a light edge can run its radius off to ln R of -50 and beyond, and an evaluation
    there, or at a contact larger than the array, outlasts the worker's deadline (on the
    moving scene the workers were killed as hung, one after the other)."""
    from tactiled.fit.models import get_model
    from tactiled.pipeline.jobs import WARM_GRID, warm_start as _warm_start

    geometry = SensorModel().geometry
    cyl = get_model("cylinder")
    good = cyl.from_values(8.0, math.inf, 60.0, 1.2, 9.0, 13.5)
    assert np.array_equal(within_reason(good, geometry), good)
    runaway = [cyl.from_values(8.0, math.inf, 60.0, 2 * MAX_FORCE_N, 9.0, 13.5),
               cyl.from_values(8.0, math.inf, 60.0, 1.2, -20.0, 13.5),
               cyl.from_values(8.0, math.inf, 60.0, 1.2, 9.0, 60.0),
               np.array([-50.0, 1.0, math.log(1.2), 9.0, 13.5])]
    clipped = [within_reason(p, geometry) for p in runaway]
    assert math.exp(clipped[0][2]) == pytest.approx(MAX_FORCE_N)
    assert clipped[1][3] == pytest.approx(-5.0)
    assert clipped[2][4] == pytest.approx((geometry.cols - 1) * geometry.dy + 5.0)
    assert math.exp(clipped[3][0]) == pytest.approx(0.005)
    # what goes to a worker: clipped, and on the grid (the CPU's last bits stay home)
    model, p = _warm_start(("cylinder", tuple(runaway[3] + 1e-13)), geometry)
    assert model == "cylinder" and math.exp(p[0]) == pytest.approx(0.005, rel=1e-6)
    assert all(abs(v / WARM_GRID - round(v / WARM_GRID)) < 1e-3 for v in p)
    assert _warm_start(None, geometry) is None


def test_a_contact_at_the_noise_is_measured_its_values_held_within_reason(kit) -> None:
    """0.07 N on a 10 mm cylinder: one frame says next to nothing of the radius (its
    single-frame sigma is 8 times the radius), so ln R steps by several units on frames
    measured through the linearisation.  That is noise: the frames are measured, not each
    refitted (this tracker once refitted 435 of these 600 frames: a fit of a frame at the
    noise is the slowest there is, and says as little).  Unbounded, such a value
    random-walks (on the moving scene's release residuals, to exp() overflow and centres a
    kilometre off the array): each measurement is held within what a finger carries.

    The radius's accuracy is not asserted here: averaged in log, a radius this poorly
    determined keeps an upward bias (see the 0.2 N test); these seeds end 2.7-5.7 reported
    sigmas high, and the old code, in the one seed it got through, 4.8.  A known weakness
    (measured when frames at the noise stopped being refitted; the history of
    docs/performance/benchmarks.md in git), not this test's subject."""
    from tactiled.pipeline.contact_filter import LN_R_BOUNDS

    faint = Contact(r1=10.0, psi_deg=60.0, force=0.07, x0=8.0, y0=9.0)
    assert crb(kit, faint)["r1_mm"] / faint.r1 > 5.0
    for seed in range(6):
        out, tr, fits = play(kit, lambda t: faint, 600, seed)
        assert fits <= 30, (seed, fits)
        assert LN_R_BOUNDS[0] <= tr.x[0] <= LN_R_BOUNDS[1]
        e = out[-1][2]
        if e["force_n"] is None:  # tied to the radius it does not resolve
            assert "radius the frames do not resolve" in e["reasons"]["force_n"], e
        else:
            assert abs(e["force_n"] - faint.force) < 4 * e["std"]["force_n"], e
        assert abs(e["x_mm"] - faint.x0) < 4 * e["std"]["x_mm"], e


def test_a_centre_no_frame_locates_is_withheld_not_run_off() -> None:
    """A measurement outside what a finger carries is held at its edge, and a position
    whose sigma exceeds OFF_ARRAY_MM is withheld ("not observable"), not published as a
    number kilometres off the array."""
    from tactiled.sensors.model import Geometry
    from tactiled.pipeline.contact_filter import OFF_ARRAY_MM, reasonable_bounds, within_reason

    g = Geometry()
    box = {i: (lo, hi) for i, lo, hi in reasonable_bounds(("ln_r", "psi", "ln_f", "x0", "y0"), g)}
    assert set(box) == {0, 2, 3, 4}  # the angle is free
    assert box[3] == (-OFF_ARRAY_MM, (g.rows - 1) * g.dx + OFF_ARRAY_MM)
    q = within_reason(np.array([80.0, 9.0, -90.0, 1e6, -1e6]), g)
    assert q == [box[0][1], 9.0, box[2][0], box[3][1], box[4][0]]
    tr = Tracker()
    assert tr._withheld("x_mm", 3.0, OFF_ARRAY_MM * 1.01).startswith("position not observable")
    assert tr._withheld("y_mm", 3.0, OFF_ARRAY_MM * 0.99) is None


def test_a_press_ramp_the_filter_lags_is_covered_by_its_sigma(kit) -> None:
    """A press whose force rises linearly from near zero (its log decelerates: no constant
    velocity): the filter trails it, and the reported force sigma holds that lag (the running
    mean of its innovations).  Measured: 74 % of the errors within 2 sigma, 62 % without the
    lag term; the rest is the linear measurement's second-order error between
    relinearisations (docs/concepts/tracking.md)."""
    def truth(t: float) -> Contact:
        return Contact(r1=10.0, psi_deg=60.0, force=0.15 + 6.0 * t, x0=8.0, y0=9.0)

    z, z_bare = [], []
    for seed in range(3):
        out, tr, _ = play(kit, truth, 300, seed)
        for _, c, e, status in out[20:]:
            if e.get("force_n") is not None and e["std"]["force_n"]:
                z.append((e["force_n"] - c.force) / e["std"]["force_n"])
    # the same frames with the lag term off
    from tactiled.pipeline import contact_filter as tracker_module

    bare = tracker_module.LAG_Z
    tracker_module.LAG_Z = math.inf  # no drift detector's mean is beyond it
    try:
        for seed in range(3):
            out, _, _ = play(kit, truth, 300, seed)
            for _, c, e, _ in out[20:]:
                if e.get("force_n") is not None and e["std"]["force_n"]:
                    z_bare.append((e["force_n"] - c.force) / e["std"]["force_n"])
    finally:
        tracker_module.LAG_Z = bare
    inside = float(np.mean(np.abs(z) <= 2.0))
    inside_bare = float(np.mean(np.abs(z_bare) <= 2.0))
    assert inside > inside_bare + 0.02, (inside, inside_bare)
    assert inside >= 0.7, inside

"""The flat field: each tactel's gain and position learned from a finger's own fits
(tactiled.fit.flatfield), checked against the simulated finger's truth."""

import copy
import math

import numpy as np
import pytest

from tactiled_bench import identify as bench
from tactiled.sensors.model import NoiseModel
from tactiled.sensors.finger import FingerSpec
from tactiled.fit.flatfield import FlatField
from tactiled.physics.strain import StrainModel

CENTRE = (slice(2, 6), slice(2, 6))


def _fitting(spec: FingerSpec, seed: int):
    """A learning fitter of the finger ``spec``, and ``fit(n)``: ``n`` more of its test
    cylinders (the draws of ``seed``, in order) through it."""
    fitter, linearise = bench.nominal_fitter(spec)
    truth = StrainModel(spec.sensor(noise=NoiseModel(bench.FRAME_SIGMA)))
    rng = np.random.default_rng(seed)

    def fit(n: int) -> None:
        for _ in range(n):
            clean = truth.predict(bench.test_cylinder(rng))
            fitter.fit(linearise(spec.to_counts(clean + rng.normal(0.0, bench.FRAME_SIGMA, clean.shape))), "cylinder")
    return fitter, fit


def _fit_frames(spec: FingerSpec, n: int, seed: int):
    """A learning fitter on ``n`` test cylinders of the finger ``spec``."""
    fitter, fit = _fitting(spec, seed)
    fit(n)
    return fitter


@pytest.fixture(scope="module")
def gains_and_positions():
    """5 % gains and 0.1 mm displacements the model does not know (``FingerSpec`` seed 6),
    its learning fitter on seed 41's test cylinders: ``(spec, a copy of the fitter after 300
    fits, the fitter after 400)``, the 400 the same 300 and 100 more (two tests share them)."""
    spec = FingerSpec(gain_error=0.05, position_error=0.1, seed=6)
    fitter, fit = _fitting(spec, seed=41)
    fit(300)
    at_300 = copy.deepcopy(fitter)
    fit(100)
    return spec, at_300, fitter


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(a * a)))


def test_the_flat_field_learns_a_fingers_gains_and_positions(gains_and_positions):
    """5 % gains and 0.1 mm displacements the model does not know: after 400 fits the
    tactels under the contacts are known to a fraction of their spread."""
    spec, _, fitter = gains_and_positions
    flat = fitter.flat
    assert flat.active
    gains = spec.gains()
    gains = gains / gains.mean()  # the array's mean is what no contact can tell
    ex, ey = spec.positions().arrays(8, 8)
    ex, ey = ex - ex.mean(), ey - ey.mean()
    before = _rms(gains[CENTRE] - 1.0)
    after = _rms(gains[CENTRE] - flat.gain[CENTRE])
    assert before > 0.03 and after < before / 4, (before, after)
    before = _rms(np.hypot(ex, ey)[CENTRE])
    after = _rms(np.hypot(ex - flat.dx, ey - flat.dy)[CENTRE])
    assert before > 0.1 and after < before / 2.5, (before, after)
    # the errors left are what the posterior says they are (a few too large at most)
    sd = np.sqrt(np.diag(flat.covariance)).reshape(3, 8, 8)
    z = np.concatenate([((flat.gain - gains) / sd[0])[CENTRE].ravel(),
                        ((flat.dx - ex) / sd[1])[CENTRE].ravel(), ((flat.dy - ey) / sd[2])[CENTRE].ravel()])
    assert np.mean(np.abs(z) < 2.0) > 0.8, z


def test_a_finger_that_matches_its_model_is_never_corrected():
    fitter = _fit_frames(FingerSpec(), 300, seed=42)
    assert not fitter.flat.active and fitter.flat.fits == 300
    assert np.all(fitter.flat.gain == 1.0) and not fitter.flat.dx.any() and not fitter.flat.dy.any()


def test_the_estimate_and_its_covariance_on_a_linear_problem():
    """Independent of the fitter: windows with random Jacobians (4x4, 6 parameters each),
    residuals ``M (E u + noise)`` for a known departure ``u`` of chosen spreads: the estimate
    lands within its own sigmas of ``u`` (about 95 % inside 2 sigma), and the spreads are
    found."""
    rng = np.random.default_rng(3)
    rows = cols = 8
    n = rows * cols
    u = np.concatenate((rng.normal(0.0, 0.05, n), rng.normal(0.0, 0.1, 2 * n)))
    flat = FlatField(rows, cols)
    for _ in range(3000):
        r0, c0 = rng.integers(0, 5, 2)
        t = np.array([(r0 + i) * cols + c0 + j for i in range(4) for j in range(4)])
        m = rng.uniform(5.0, 200.0, 16)
        jx, jy = rng.normal(0.0, 100.0, (2, 16))
        jac = rng.normal(size=(16, 6))
        resid_op = np.eye(16) - jac @ np.linalg.solve(jac.T @ jac, jac.T)
        e = -m * u[t] + jx * u[t + n] + jy * u[t + 2 * n] + rng.normal(size=16)
        # the fit ran with the current correction: its residuals are what is left of e
        used = -m * flat._u[t] + jx * flat._u[t + n] + jy * flat._u[t + 2 * n]
        flat.add(t, resid_op, m, jx, jy, resid_op @ (e - used))
    flat.solve()
    assert flat.active
    est = flat._u
    sd = np.sqrt(np.diag(flat.covariance))
    z = (est - u) / sd
    assert 0.9 <= np.mean(np.abs(z) < 2.0) <= 0.99, np.mean(np.abs(z) < 2.0)
    assert abs(float(np.mean(z))) < 0.2
    assert math.sqrt(flat._var[0]) == pytest.approx(0.05, rel=0.25)
    assert math.sqrt(flat._var[1]) == pytest.approx(0.1, rel=0.25)


def test_a_linearisation_reads_raw_frames_as_the_corrected_fit_does(gains_and_positions):
    """The tracker measures later frames as they come (uncorrected) with a fit's
    linearisation: with the flat field on, that linearisation is in the frames' own units, so
    it measures a moved contact where a fit on the same frame lands."""
    from tactiled.fit.linearize import linearize
    from tactiled.physics.contact import Contact

    spec, fitter, _ = gains_and_positions  # after 300 fits (this test's own copy)
    assert fitter.flat.active
    fitter.flat._next_solve = 10**9  # hold the corrections still from here
    truth = StrainModel(spec.sensor())
    linearise = bench.nominal_fitter(spec)[1]
    frame = linearise(spec.to_counts(truth.predict(Contact(8.0, math.inf, 70.0, 1.2, 11.0, 12.0))))
    res = fitter.fit(frame, "cylinder")
    lin = linearize(fitter, frame, "cylinder", np.array(res.params))
    moved = linearise(spec.to_counts(truth.predict(Contact(8.0, math.inf, 72.0, 1.25, 11.1, 12.05))))
    refit = fitter.fit(moved, "cylinder", warm=("cylinder", res.params))
    z = lin.p + lin.gain @ (moved.ravel()[lin.index] - lin.strain)
    sd = np.sqrt(np.diag(lin.cov))
    assert np.all(np.abs(z - np.array(refit.params)) < 0.25 * sd), (z - np.array(refit.params)) / sd
    # the corrections' own uncertainty is systematic: the same in every frame
    assert np.all(np.diag(lin.systematic) > 0.0)
    # its prediction on the whole array is in the frames' units too (the tactel gains on it,
    # the tactels where the flat field puts them): the window's own strains to 0.2 noise sigma,
    # which read the learned displacements to first order where the prediction is exact
    np.testing.assert_allclose(lin.predicted.ravel()[lin.index], lin.strain, rtol=0,
                               atol=0.2 * bench.FRAME_SIGMA)


def test_residuals_that_follow_the_contacts_are_not_blamed_on_the_tactels():
    """The simulator's demo scene on the model's own finger (hysteresis, light frames, contacts
    the model does not describe): the fits' residuals exceed the noise, but corrections for each
    tactel would explain only about half of that excess, so the flat field never switches on
    (when it did, its corrections cost the force's coverage 95 -> 78 %)."""
    from tactiled.sensors.model import SensorModel
    from tactiled.fit.fitter import FitOptions, Fitter
    from tactiled.sim import FingerSimulator

    sim = FingerSimulator(scene="demo", seed=1, rate_hz=1000, noise=0.0005, loop=True)
    fitter = Fitter(SensorModel(noise=NoiseModel(0.0005)), FitOptions(learn_floor=True))
    inside, ever_on = [], False
    for i in range(21000):
        tick = sim.step()
        if i % 7 or tick.contact is None or tick.contact.force < 0.05:
            continue
        res = fitter.fit(tick.strain - tick.drift, "auto")
        ever_on |= fitter.flat.active
        if res.values.get("force_n") and res.std.get("force_n"):
            inside.append(abs(res.values["force_n"] - tick.contact.force) < 2.0 * res.std["force_n"])
    assert fitter.flat.fits > 2000 and fitter.flat.explained < 0.8
    assert not ever_on, fitter.flat.note
    assert np.mean(inside) > 0.93


def test_what_a_flat_field_holds_is_bounded_and_loses_no_fit(monkeypatch):
    """Windows with masked tactels are sets of their own: past MAX_WINDOWS of them a fit's
    sums go straight into the array's, and the normal equations are the same as with every
    window kept."""
    import tactiled.fit.flatfield as ff

    rng = np.random.default_rng(5)
    fits = []
    for _ in range(300):
        r0, c0 = rng.integers(0, 5, 2)
        keep = rng.uniform(size=16) > 0.1  # a masked tactel or two: many distinct sets
        t = np.array([(r0 + i) * 8 + c0 + j for i in range(4) for j in range(4)])[keep]
        k = t.size
        jac = rng.normal(size=(k, 6))
        resid_op = np.eye(k) - jac @ np.linalg.solve(jac.T @ jac, jac.T)
        fits.append((t, resid_op, *rng.uniform(5.0, 50.0, (1, k)), *rng.normal(0.0, 30.0, (2, k)),
                     resid_op @ rng.normal(size=k)))
    bound = ff.MAX_WINDOWS
    assert len({f[0].tobytes() for f in fits}) > bound + 50  # the bound is reached
    sums = []
    for limit in (bound, 10**6):
        monkeypatch.setattr(ff, "MAX_WINDOWS", limit)
        flat = FlatField(8, 8)
        flat._next_solve = 10**9
        for f in fits:
            flat.add(*f)
        assert len(flat._windows) <= limit
        flat._fold()
        sums.append((flat.ata.copy(), flat.atb.copy()))
    np.testing.assert_allclose(sums[0][0], sums[1][0], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(sums[0][1], sums[1][1], rtol=1e-12, atol=1e-9)


def test_a_fit_answers_before_the_solve_it_makes_due():
    """A solve of the flat field's normal equations costs a few fits' time (1-3 ms); the fit
    that makes one due answers without running it, and it runs afterwards: a daemon worker
    calls ``catch_up`` after sending the answer, any other caller's next fit runs it first."""
    spec = FingerSpec(gain_error=0.05, position_error=0.1, seed=6)
    fitter, linearise = bench.nominal_fitter(spec)
    truth = StrainModel(spec.sensor(noise=NoiseModel(bench.FRAME_SIGMA)))
    rng = np.random.default_rng(43)
    flat = fitter.flat
    solves = []  # the fit count at each solve
    real_solve = flat.solve

    def counted_solve() -> None:
        solves.append(flat.fits)
        real_solve()

    flat.solve = counted_solve
    became_due = 0
    for _ in range(60):
        clean = truth.predict(bench.test_cylinder(rng))
        n_before = len(solves)
        fitter.fit(linearise(spec.to_counts(clean + rng.normal(0.0, bench.FRAME_SIGMA, clean.shape))),
                   "cylinder")
        if flat.solve_due:
            became_due += 1
            # no solve ran in the fit that made it due (one may have run first: the last due)
            assert all(n < flat.fits for n in solves[n_before:])
            assert fitter.catch_up() and not flat.solve_due
            assert solves[-1] == flat.fits  # run now, on every fit so far
        assert not fitter.catch_up()  # nothing is left due
    assert became_due >= 3, became_due  # solves at 20, 25, 31, 38, 47, 58 fits
    assert solves == [20, 25, 31, 38, 47, 58], solves

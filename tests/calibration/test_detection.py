"""Contact detection: noise-calibrated threshold, false-alarm rate, hysteresis, NaN handling."""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
import pytest

from tactiled.calibration import ContactDetector, detection_threshold, filter_matrices
from tactiled.sensors.model import DEFAULT_SENSOR, NoiseModel, SensorModel

SIGMA = 0.0005


def test_threshold_is_the_union_bound_over_template_centres():
    t = detection_threshold(SIGMA, 1e-4)
    assert t == pytest.approx(SIGMA * NormalDist().inv_cdf(1 - 1e-4 / 225))  # 15 x 15 centres
    assert t / SIGMA == pytest.approx(4.915, abs=1e-3)
    one_per_tactel = detection_threshold(SIGMA, 1e-4, subdivide=1)
    assert one_per_tactel == pytest.approx(SIGMA * NormalDist().inv_cdf(1 - 1e-4 / 64))
    assert detection_threshold(2 * SIGMA) == pytest.approx(2 * t)
    with pytest.raises(ValueError, match="sigma"):
        detection_threshold(0.0)
    with pytest.raises(ValueError, match="false_rate"):
        detection_threshold(SIGMA, 0.0)
    with pytest.raises(ValueError, match="method"):
        detection_threshold(SIGMA, method="guess")


def test_default_sigma_comes_from_the_noise_model():
    assert ContactDetector().sigma == DEFAULT_SENSOR.noise.effective_sigma
    quantised = SensorModel(noise=NoiseModel(sigma=0.0004, quantum=0.001))
    d = ContactDetector(sensor=quantised)
    assert d.sigma == pytest.approx(math.sqrt(0.0004**2 + 0.001**2 / 12))
    # entries get half the false-contact budget: hysteresis holds a false entry ~2 frames
    from tactiled.calibration.detection import DEFAULT_FALSE_RATE, HYSTERESIS_DWELL

    assert d.enter_threshold == pytest.approx(detection_threshold(d.sigma, DEFAULT_FALSE_RATE / HYSTERESIS_DWELL))
    # without hysteresis (exit = enter) the whole budget goes to entries
    plain = ContactDetector(sensor=quantised, exit_fraction=1.0)
    assert plain.enter_threshold == pytest.approx(detection_threshold(d.sigma))


def test_each_filter_output_has_the_noise_sigma():
    # normalisation: every position of T is N(0, sigma^2) on noise, edges and corners included
    ax, ay = filter_matrices()
    assert ax.shape == (15, 8) and ay.shape == (15, 8)
    np.testing.assert_allclose((ax**2).sum(axis=1), 1.0)
    np.testing.assert_allclose((ay**2).sum(axis=1), 1.0)
    z = np.random.default_rng(0).normal(0.0, SIGMA, (20000, 8, 8))
    t = ax @ z @ ay.T
    np.testing.assert_allclose(t.std(axis=0) / SIGMA, 1.0, atol=0.03)


def test_false_contacts_on_noise_only_frames_stay_within_the_rate():
    # 200k Gaussian noise frames, vectorised.  Expect <= 20 false contacts at 1e-4 per frame;
    # the count is ~Poisson(<= 20): allow the one-sided 0.1 % quantile, 35 (P(X >= 36 | 20)
    # ~ 8e-4).  (The bound is conservative: ~12 are typical.)
    detector = ContactDetector(SIGMA)
    rng = np.random.default_rng(2024)
    false = sum(int((detector.statistic_batch(rng.normal(0.0, SIGMA, (50_000, 8, 8)))
                     > detector.enter_threshold).sum()) for _ in range(4))
    assert false <= 35
    # At a rate high enough to measure precisely, the bound holds and is not wildly loose.
    loose = ContactDetector(SIGMA, false_rate=0.01, exit_fraction=1.0)  # single frames
    stats = loose.statistic_batch(rng.normal(0.0, SIGMA, (50_000, 8, 8)))
    rate = float(np.mean(stats > loose.enter_threshold))
    assert 0.003 < rate <= 0.01 + 3 * math.sqrt(0.01 / 50_000)
    # With one template per tactel the bound is nearly tight.
    grid = ContactDetector(SIGMA, false_rate=0.01, subdivide=1, exit_fraction=1.0)
    rate = float(np.mean(grid.statistic_batch(rng.normal(0.0, SIGMA, (50_000, 8, 8)))
                         > grid.enter_threshold))
    assert 0.008 < rate <= 0.01 + 3 * math.sqrt(0.01 / 50_000)


def test_montecarlo_threshold_agrees_with_the_bound():
    bound = detection_threshold(SIGMA, 1e-2)
    mc = detection_threshold(SIGMA, 1e-2, method="montecarlo", n_frames=100_000, seed=3)
    assert 0.9 * bound < mc <= bound * 1.01


def _point_strain(amplitude: float, m0: int = 4, n0: int = 3) -> np.ndarray:
    """Noise-free strain of a point load over tactel [m0, n0]: the sampled impulse response."""
    from tactiled.physics.impulse import line_response

    g, imp = DEFAULT_SENSOR.geometry, DEFAULT_SENSOR.impulse
    hx = line_response((np.arange(8) - m0) * g.dx, imp.depth_x, imp.nu_x)
    hy = line_response((np.arange(8) - n0) * g.dy, imp.depth_y, imp.nu_y)
    h = np.outer(hx, hy)
    return amplitude * h / h[m0, n0]


def _point_strain_at(amplitude: float, x: float, y: float) -> np.ndarray:
    """Point load at (x, y) in tactel pitches, scaled so a load over a tactel peaks at
    ``amplitude``."""
    from tactiled.physics.impulse import line_response

    g, imp = DEFAULT_SENSOR.geometry, DEFAULT_SENSOR.impulse
    hx = line_response((np.arange(8) - x) * g.dx, imp.depth_x, imp.nu_x)
    hy = line_response((np.arange(8) - y) * g.dy, imp.depth_y, imp.nu_y)
    peak = line_response(0.0, imp.depth_x, imp.nu_x) * line_response(0.0, imp.depth_y, imp.nu_y)
    return amplitude * np.outer(hx, hy) / peak


def test_matched_filter_beats_the_peak_tactel_and_the_bank_catches_contacts_between_tactels():
    detector = ContactDetector(SIGMA)
    gain = detector.statistic(_point_strain(SIGMA)) / SIGMA  # peak strain of one sigma
    assert 1.15 < gain < 1.3  # SNR gain of the template over the single peak tactel
    # Between four tactels the strain is split; a template centred there recovers the optimum
    # (the frame's own norm), while tactel-centred templates lose about a quarter of it.
    between = _point_strain_at(SIGMA, 3.5, 3.5)
    optimum = np.linalg.norm(between)
    assert detector.statistic(between) == pytest.approx(optimum, rel=0.02)
    tactel_centred = ContactDetector(SIGMA, subdivide=1).statistic(between)
    assert tactel_centred < 0.8 * optimum


def test_hysteresis_enter_and_exit_thresholds():
    detector = ContactDetector(SIGMA)
    enter, leave = detector.enter_threshold, detector.exit_threshold
    assert leave == pytest.approx(0.6 * enter)
    unit = detector.statistic(_point_strain(1.0))  # statistic per unit peak strain

    def frame(level: float) -> np.ndarray:
        return _point_strain(level / unit)

    decisions = [detector.update(frame(v)) for v in
                 (0.9 * enter, 0.99 * enter, 1.01 * enter, 0.8 * enter, 0.65 * enter,
                  0.61 * enter, 0.59 * enter, 0.9 * enter, 1.2 * enter)]
    # waits for enter; then stays through the band between exit and enter; leaves below exit;
    # needs enter again to come back
    assert decisions == [False, False, True, True, True, True, False, False, True]
    # a contact hovering around the enter threshold does not flicker
    detector.reset()
    hover = [detector.update(frame(enter * (1 - 0.05 * (-1) ** k))) for k in range(20)]
    assert hover == [False] + [True] * 19


def test_non_finite_entries_are_treated_as_zero_and_counted():
    detector = ContactDetector(SIGMA)
    z = np.zeros((8, 8))
    for bad in (np.nan, np.inf, -np.inf):
        z[0, 0] = bad
        assert detector.update(z) is False
    assert detector.nonfinite_frames == 3
    assert math.isfinite(detector.last_statistic)
    strong = _point_strain(10 * SIGMA)
    strong[7, 7] = np.nan
    assert detector.update(strong) is True
    assert detector.nonfinite_frames == 4
    batch = np.stack([strong, np.zeros((8, 8))])
    stats = detector.statistic_batch(batch)
    assert np.all(np.isfinite(stats)) and stats[0] > detector.enter_threshold


def test_bad_arguments():
    with pytest.raises(ValueError, match="exit_threshold"):
        ContactDetector(SIGMA, enter_threshold=0.001, exit_threshold=0.002)
    with pytest.raises(ValueError, match="exit_fraction"):
        ContactDetector(SIGMA, exit_fraction=1.5)
    with pytest.raises(ValueError, match="subdivide"):
        filter_matrices(subdivide=0)
    with pytest.raises(ValueError, match="reach"):
        filter_matrices(reach=0.1)

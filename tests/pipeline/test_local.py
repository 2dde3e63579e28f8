"""Linearisations in the daemon's own process (tactiled/pipeline/local.py): a frame that left the
tracker's linear range is measured through a linearisation nearer to it instead of waiting for
a fit, when one near the prediction explains it; a jump still gets a fit.  Real fits, real
linearisations, frames from the physics with Gaussian noise, played synchronously.  Bounds are
in units of the single-frame Cramer-Rao bound at the truth, from the fitter."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled.config import NoiseModel, SensorModel
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.models import get_model
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
from tactiled.pipeline.local import MAX_FORCE_N, LocalModel, within_reason

from pipeline_helpers import play_tracked

SIGMA = 0.0005
RATE = 1000.0  # frames/s
OPTIONS = (("window", 4), ("withhold_relative_sigma", 0.5))


@pytest.fixture(scope="module")
def kit():
    sensor = SensorModel(noise=NoiseModel(sigma=SIGMA))
    fitter = Fitter(sensor, FitOptions(**dict(OPTIONS)))
    return fitter, StrainModel(sensor), LocalModel(sensor, OPTIONS)


def roll(speed_mm_s: float):
    def truth(t: float) -> Contact:
        return Contact(r1=8.0, psi_deg=60.0, force=1.2, x0=8.0 + speed_mm_s * t, y0=13.5)
    return truth


def play(kit, truth, frames: int, seed: int, iterate: bool) -> tuple[list, int, int]:
    """The daemon's tracked path with no relinearisation from a worker arriving in time (the
    worst case on a loaded machine); a frame the tracker cannot measure is iterated here when
    ``iterate``, and gets a fit otherwise (or when that fails).  Returns ``[(t, truth, x_mm,
    status)]``, the fits made and the frames measured by iterating."""
    fitter, model, local = kit
    out, _tr, fits, iterated = play_tracked(fitter, model, truth, frames, seed, SIGMA, RATE,
                                            relinearize=False, local=local if iterate else None)
    return [(t, c, est["x_mm"], status) for t, c, est, status in out], fits, iterated


def x_bound(kit, c: Contact) -> float:
    fitter, model, _ = kit
    p = get_model("cylinder").from_values(c.r1, c.r2, c.psi_deg, c.force, c.x0, c.y0)
    return fitter.cramer_rao(model.predict(c), "cylinder", p)["x_mm"]


@pytest.mark.parametrize("seed", [3, 4])
def test_a_fast_roll_is_measured_without_waiting_for_fits(kit, seed: int) -> None:
    """Rolling at 100 mm/s the contact leaves a linearisation's range every ten frames or so
    (its estimate through a far linearisation then looks like a jump); with no relinearisation
    arriving from a worker, those frames are measured through a linearisation at the
    prediction instead of a fit each, and the estimate stays within the single-frame bound."""
    truth = roll(100.0)
    _base_out, base_fits, _ = play(kit, truth, 150, seed=seed, iterate=False)
    out, fits, iterated = play(kit, truth, 150, seed=seed, iterate=True)
    assert base_fits >= 8  # without iterating the roll needs fits all along
    assert fits <= base_fits // 4, (fits, base_fits)
    assert iterated >= base_fits // 2, (iterated, base_fits)
    bound = x_bound(kit, truth(0.075))
    # after the filter has settled on the motion: errors against the truth
    err = np.array([x - c.x0 for t, c, x, _ in out if t >= 0.03])
    rms = math.sqrt(float(np.mean(err ** 2)))
    assert rms <= 1.2 * bound, (rms, bound)


def test_a_jump_is_not_iterated_but_fitted(kit) -> None:
    """A force step of 40 % is a change, not motion: no linearisation near the prediction
    may absorb it, the frame goes to a fit (and the filter restarts there)."""
    fitter, model, local = kit

    def truth(t: float) -> Contact:
        return Contact(r1=8.0, psi_deg=60.0, force=1.2 if t < 0.05 else 1.68, x0=9.0, y0=13.5)

    out, fits, iterated = play(kit, truth, 80, seed=5, iterate=True)
    step = [status for t, _c, _x, status in out if abs(t - 0.05) < 1e-9][0]
    assert step in ("reset", "tracked")  # the step's frame got a fit of its own
    assert fits == 2 and iterated == 0


def test_a_point_no_finger_carries_is_refused(kit) -> None:
    """The loop never evaluates a contact a finger cannot carry (a filter run away: its
    evaluation costs tens of ms), and says so in the counter."""
    _fitter, model, local = kit
    c = Contact(r1=8.0, psi_deg=60.0, force=1.2, x0=9.0, y0=13.5)
    s = model.predict(c)
    cyl = get_model("cylinder")
    good = cyl.from_values(8.0, math.inf, 60.0, 1.2, 9.0, 13.5)
    assert local.linearize(s, ("cylinder", good)) is not None
    refused = local.refused
    bad = [cyl.from_values(8.0, math.inf, 60.0, 2 * MAX_FORCE_N, 9.0, 13.5),
           cyl.from_values(8.0, math.inf, 60.0, 1.2, -20.0, 13.5),
           cyl.from_values(8.0, math.inf, 60.0, 1.2, 9.0, 60.0),
           cyl.from_values(math.exp(-50.0), math.inf, 60.0, 1.2, 9.0, 13.5)]  # a radius run off
    for p in bad:
        assert local.linearize(s, ("cylinder", p)) is None
    assert local.refused == refused + len(bad)
    # the same limits bound a worker's warm start: clipped to the nearest reasonable contact
    geometry = SensorModel().geometry
    clipped = [within_reason(p, geometry) for p in bad]
    assert math.exp(clipped[0][2]) == pytest.approx(MAX_FORCE_N)
    assert clipped[1][3] == pytest.approx(-5.0) and clipped[3][0] > math.log(0.001)
    assert np.array_equal(within_reason(good, geometry), good)

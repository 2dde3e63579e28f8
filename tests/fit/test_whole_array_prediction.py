"""A linearisation's prediction on the whole array (``Linearization.predicted``, what the zeroer
follows drift around): the forward model at the linearisation point on every tactel, equal on
the window to the strains the linearisation itself was computed from (the compiled window
evaluation, an independent code path), and in the frames' own units."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactiled.sensors.model import SensorModel
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.linearize import linearize
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel

SIGMA = 0.0005


@pytest.mark.parametrize("contact, model", [
    (Contact(10.0, math.inf, 60.0, 1.0, 12.0, 13.0), "cylinder"),
    (Contact(8.0, 8.0, 90.0, 0.8, 10.0, 15.0), "sphere"),
    (Contact(5.0, 20.0, 30.0, 1.2, 14.0, 11.0), "general"),
])
def test_the_prediction_is_the_model_on_every_tactel(contact: Contact, model: str) -> None:
    truth = StrainModel(SensorModel()).predict(contact)
    fitter = Fitter(SensorModel(), FitOptions())
    fit = fitter.fit(truth, model)
    lin = linearize(fitter, truth, model, np.array(fit.params))
    assert lin is not None and lin.predicted is not None
    assert lin.predicted.shape == truth.shape
    # noise-free frame, converged fit: the prediction is the frame, far from the window too
    assert np.abs(lin.predicted - truth).max() < 1e-3 * SIGMA
    # on the window, the same numbers as the linearisation's own strains
    np.testing.assert_allclose(lin.predicted.ravel()[lin.index], lin.strain, rtol=1e-9,
                               atol=1e-12)

import pytest

from tactiled.sensors.model import NoiseModel, SensorModel
from tactiled.fit.fitter import Fitter


@pytest.fixture(scope="session")
def fitter() -> Fitter:
    return Fitter()


@pytest.fixture(scope="session")
def noisy_fitter() -> Fitter:
    """Fitter whose noise model matches the issue's noisy frames: quantised to 0.001 plus
    Gaussian 0.0003, i.e. sigma_eff = sqrt(0.0003^2 + 0.001^2/12)."""
    return Fitter(SensorModel(noise=NoiseModel(sigma=0.0003, quantum=0.001)))

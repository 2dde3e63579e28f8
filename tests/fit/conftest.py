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


@pytest.fixture(scope="session")
def on_description():
    """``on_description(name)``: ``(sensor, strain model, fitter with the description's
    window)`` of a built-in description, the simulator and the fitter of a test scored
    against its truth."""
    return _on_description


def _on_description(name: str):
    from tactiled.fit.fitter import FitOptions
    from tactiled.physics.strain import StrainModel
    from tactiled.sensors import load_description
    desc = load_description(name)
    sensor = desc.sensor_model()
    return sensor, StrainModel(sensor), Fitter(sensor, FitOptions(window=desc.window))

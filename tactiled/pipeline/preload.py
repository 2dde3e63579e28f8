"""Imported once by the forkserver, so every fit worker forked from it starts warm.

Workers are forked with numpy, scipy and the fitter imported and the default sensor's start
table built (``start_table`` is cached per SensorModel), so a replacement worker for a default
sensor is ready in milliseconds instead of the second a cold start takes.
Nothing here may raise: the forkserver would die with it.  (It ignores only ImportError.)
"""

from __future__ import annotations

try:
    from tactiled.sensors.model import DEFAULT_SENSOR
    from tactiled.fit.fitter import Fitter

    Fitter(DEFAULT_SENSOR)  # builds and caches the start table
except Exception:  # noqa: BLE001 - a cold start is slower, never wrong
    pass

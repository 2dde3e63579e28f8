"""Imported once by the forkserver, so every fit worker forked from it starts warm.

A worker started from nothing spends about a second importing numpy, scipy and the fitter and
building the fitter's start table, far too long for a restart after a crash.  The forkserver
imports this module once; workers are forked from it with the modules imported and the
default sensor's start table built (``start_table`` is cached per SensorModel), so a
replacement worker for a default sensor is ready in milliseconds.

Nothing here may raise: the forkserver would die with it.  (It ignores only ImportError.)
"""

from __future__ import annotations

try:
    from tactiled.sensors.model import DEFAULT_SENSOR
    from tactiled.fit.fitter import Fitter

    Fitter(DEFAULT_SENSOR)  # builds and caches the start table
except Exception:  # noqa: BLE001 - a cold start is slower, never wrong
    pass

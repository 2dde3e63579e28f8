"""The daemon's core: N sensor loops, one pool of fit workers, one hub (no web server here).

``tactiled run`` builds a :class:`Daemon` from :func:`tactiled.settings.load_settings`, starts
it, and serves ``daemon.hub`` and the control methods over HTTP; ``tactiled replay`` runs one in
lossless mode over a recording.  Graceful stop: stop reading, let fits in flight finish (up to
``fit.stop_timeout`` s, then SIGKILL), close the sources, flush the recordings, close the hub.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

from tactiled.errors import CalibrationError, ConfigError, DriverError, TactiledError
from tactiled.io.files import check_output
from tactiled.pipeline.hub import Hub
from tactiled.pipeline.pool import WorkerPool
from tactiled.pipeline.sensor import SensorPipeline
from tactiled.pipeline.sensor_stats import SensorStats
from tactiled.settings import (
    FIT_FIELDS,
    RUNTIME_SENSOR_KEYS,
    SENSOR_FIELDS,
    Settings,
    check_sensor_value,
)
from tactiled.sources import FrameSource, open_source

log = logging.getLogger(__name__)

#: ``[fit]`` keys the daemon can change while running.
RUNTIME_FIT_KEYS = ("timeout", "ping_interval", "ping_timeout")


class UnknownSensorError(TactiledError, KeyError):
    """No sensor of that name (the service maps it to 404)."""

    def __str__(self) -> str:  # KeyError would quote the whole message
        return str(self.args[0]) if self.args else "unknown sensor"


class Daemon:
    """Owns the sensors of ``settings``, their worker pool and the hub they publish to.

    ``lossless``: every sensor waits for each fit before reading on (replay, regression
    tests); live sensors use latest-frame-wins.  ``sources`` may supply ready-made frame
    sources by sensor name (tests), instead of opening the configured URLs.  ``keep_learned``
    (default: when not lossless) keeps what the fits learn of each finger in the state
    directory (``[state] dir``; ``tactiled/pipeline/learned.py``) and starts from it: a
    replay's output must not depend on what a live daemon learned.  Construction does
    no device I/O but loads calibration files: problems raise ``ConfigError`` naming the key.
    """

    def __init__(self, settings: Settings | None = None, *, hub: Hub | None = None,
                 lossless: bool = False,
                 sources: Mapping[str, FrameSource] | None = None,
                 keep_learned: bool | None = None) -> None:
        self.settings = settings or Settings()
        names = [s.name for s in self.settings.sensors]
        self.hub = hub if hub is not None else Hub(names)
        self.pool = WorkerPool(self.settings.worker_count(), self.settings.fit)
        self.lossless = lossless
        self.sensors: dict[str, SensorPipeline] = {}
        sources = sources or {}
        keep = (not lossless) if keep_learned is None else keep_learned
        state_dir = self.settings.state.directory() if keep else None
        for i, s in enumerate(self.settings.sensors):
            source = sources.get(s.name)
            if source is None:
                try:
                    source = open_source(s.url)  # builds the driver; no I/O yet
                except (ValueError, DriverError) as err:
                    raise ConfigError(f"sensor[{i}].url: {err}") from err
            record = self.settings.record_path(s.name)
            if record is not None:  # refused now, not at the first frame (and then only logged)
                try:
                    check_output(record, ConfigError)
                except ConfigError as err:
                    raise ConfigError(f"record.path: {err}") from None
            try:
                pipe = SensorPipeline(s, pool=self.pool, hub=self.hub,
                                      record_path=record,
                                      lossless=lossless, source=source,
                                      state_dir=state_dir)
            except CalibrationError as err:
                raise ConfigError(f"sensor[{i}].calibration: {err}") from err
            self.sensors[s.name] = pipe
            self.pool.attach(pipe)
        self.started_at: float | None = None
        self._state = "new"

    # -- lifecycle ------------------------------------------------------------------------------

    async def start(self, wait_ready: bool = True) -> None:
        """Start the fit workers (waiting until they are warm, with ``wait_ready``) and then
        the sensor loops."""
        if self._state != "new":
            raise RuntimeError(f"daemon cannot start: it is {self._state}")
        self._state = "running"
        self.started_at = time.monotonic()
        try:
            await self.pool.start(wait_ready=wait_ready)
        except BaseException:
            await self.pool.stop(0.0)
            self._state = "stopped"
            raise
        for pipe in self.sensors.values():
            pipe.start()
        log.info("daemon started: %d sensor(s), %d fit worker(s)", len(self.sensors),
                 self.pool.size)

    async def stop(self, timeout: float | None = None) -> None:
        """Graceful stop (idempotent): see the module docstring.  ``timeout`` in seconds
        (default ``fit.stop_timeout``) bounds the wait for fits in flight."""
        if self._state in ("stopping", "stopped"):
            return
        if self._state == "new":
            self._state = "stopped"
            for pipe in self.sensors.values():
                await pipe.close()
            self.hub.close()
            return
        self._state = "stopping"
        for pipe in self.sensors.values():
            await pipe.stop_reading()
        await self.pool.stop(timeout)
        for pipe in self.sensors.values():
            await pipe.close()
        self.hub.close()
        self._state = "stopped"
        log.info("daemon stopped")

    async def __aenter__(self) -> Daemon:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    @property
    def state(self) -> str:
        """"new", "running", "stopping" or "stopped"."""
        return self._state

    async def wait_finished(self, timeout: float | None = None) -> bool:
        """Wait until every source has ended (replays) and every fit is done; False on
        ``timeout`` (s)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not all(p.finished and p.settled for p in self.sensors.values()):
            if deadline is not None and time.monotonic() > deadline:
                return False
            await asyncio.sleep(0.01)
        return True

    # -- control --------------------------------------------------------------------------------

    def _sensor(self, name: str) -> SensorPipeline:
        try:
            return self.sensors[name]
        except KeyError:
            raise UnknownSensorError(f"unknown sensor {name!r}; known: "
                                     f"{', '.join(self.sensors)}") from None

    def tare(self, sensor: str) -> None:
        """Re-zero ``sensor`` on its next frame (nothing may touch it then)."""
        self._sensor(sensor).tare()

    def sensor_stats(self, sensor: str) -> SensorStats:
        """The counters of ``sensor`` as a typed record (``UnknownSensorError``)."""
        return self._sensor(sensor).stats()

    def stats(self, sensor: str | None = None) -> dict[str, Any]:
        """Counters of one sensor, or of all (``{"sensors": {...}, "workers": ..., "hub":
        ...}``); JSON-ready."""
        if sensor is not None:
            return self._sensor(sensor).stats().to_json_dict()
        return {
            "state": self._state,
            "uptime_s": None if self.started_at is None else time.monotonic() - self.started_at,
            "lossless": self.lossless,
            "sensors": {name: p.stats().to_json_dict() for name, p in self.sensors.items()},
            "workers": self.pool.stats(),
            "hub": self.hub.stats(),
        }

    def get_config(self) -> dict[str, Any]:
        """The settings that :meth:`update_config` can change, as plain data."""
        fit = self.pool.settings
        return {
            "sensors": {name: p.runtime_config() for name, p in self.sensors.items()},
            "fit": {k: getattr(fit, k) for k in RUNTIME_FIT_KEYS},
        }

    def update_config(self, patch: Mapping[str, Any]) -> dict[str, Any]:
        """Change thresholds / model choice at run time, all or nothing; returns the new
        :meth:`get_config`.

        ``patch`` looks like ``{"sensors": {"finger0": {"model": "sphere"}}, "fit":
        {"timeout": 0.5}}``.  A bad key or value raises ``ConfigError`` naming it
        (``sensors.finger0.model: must be one of ...``) and changes nothing.
        """
        if not isinstance(patch, Mapping):
            raise ConfigError(f"config: expected an object, got {type(patch).__name__}")
        sensor_changes: dict[str, dict[str, Any]] = {}
        fit_changes: dict[str, Any] = {}
        for top, body in patch.items():
            if top not in ("sensors", "fit"):
                raise ConfigError(f"{top}: not changeable at run time (only sensors, fit)")
            if not isinstance(body, Mapping):
                raise ConfigError(f"{top}: expected an object, got {type(body).__name__}")
            if top == "fit":
                for key, value in body.items():
                    if key not in RUNTIME_FIT_KEYS:
                        raise ConfigError(f"fit.{key}: " + (
                            "cannot be changed at run time (restart the daemon)"
                            if key in FIT_FIELDS else "unknown key"))
                    fit_changes[key] = FIT_FIELDS[key](value, f"fit.{key}")
                continue
            for name, changes in body.items():
                if name not in self.sensors:
                    raise ConfigError(f"sensors.{name}: unknown sensor (known: "
                                      f"{', '.join(self.sensors)})")
                if not isinstance(changes, Mapping):
                    raise ConfigError(f"sensors.{name}: expected an object")
                checked = {}
                for key, value in changes.items():
                    where = f"sensors.{name}.{key}"
                    if key not in RUNTIME_SENSOR_KEYS:
                        raise ConfigError(f"{where}: " + (
                            "cannot be changed at run time (restart the daemon)"
                            if key in SENSOR_FIELDS else "unknown key"))
                    checked[key] = check_sensor_value(key, value, where)
                sensor_changes[name] = checked
        # Every value passed its check, but applying one can still fail (a detector threshold
        # out of reach): then what was applied is rolled back, so a patch is all or nothing.
        applied: list[tuple[SensorPipeline, dict[str, Any]]] = []
        for name, checked in sensor_changes.items():
            if not checked:
                continue
            pipe = self.sensors[name]
            applied.append((pipe, {key: getattr(pipe.settings, key) for key in checked}))
            try:
                pipe.configure(checked)
            except (ValueError, ArithmeticError) as err:
                for done, old in reversed(applied):
                    done.configure(old)
                raise ConfigError(f"sensors.{name}: cannot be applied: {err}") from None
        if fit_changes:
            self.pool.settings = replace(self.pool.settings, **fit_changes)
        return self.get_config()

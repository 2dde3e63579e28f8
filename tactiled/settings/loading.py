"""Loading the configuration: defaults < TOML file < ``TACTILED_*`` environment < overrides,
merged with where each value came from, then typed and checked section by section.
"""

from __future__ import annotations

import os
import re
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from tactiled.errors import ConfigError
from tactiled.settings.checks import SECTIONS, SENSOR_FIELDS, _Text
from tactiled.settings.sections import (
    ENV_CONFIG,
    ENV_PREFIX,
    FitSettings,
    RecordSettings,
    Ros2Settings,
    SensorSettings,
    ServerSettings,
    Settings,
    StateSettings,
    ZenohSettings,
)

#: Keys whose relative paths are taken relative to the config file.
_PATH_KEYS = {("sensor", "calibration"), ("record", "path"), ("zenoh", "config"), ("state", "dir")}


_KEY_RE = re.compile(r"^(?:(server|fit|record|zenoh|ros2|state)\.([a-z_]+)|sensor\[(\d+)\]\.([a-z_]+))$")


@dataclass
class _Raw:
    """The merged, not yet typed configuration, with where each value came from."""

    sections: dict[str, dict[str, Any]] = field(
        default_factory=lambda: {"server": {}, "fit": {}, "record": {}, "zenoh": {},
                                 "ros2": {}, "state": {}})
    sensors: list[dict[str, Any]] = field(default_factory=list)
    origin: dict[str, str] = field(default_factory=dict)  # dotted key -> where it was set

    def set(self, dotted: str, value: Any, origin: str) -> None:
        m = _KEY_RE.match(dotted)
        if not m:
            raise ConfigError(f"{dotted}: not a configuration key (write section.key or "
                              f"sensor[i].key){_suffix(origin)}")
        if m.group(1):
            section, key = m.group(1), m.group(2)
            if key not in SECTIONS[section]:
                raise ConfigError(f"{dotted}: unknown key (known in [{section}]: "
                                  f"{', '.join(SECTIONS[section])}){_suffix(origin)}")
            self.sections[section][key] = value
        else:
            index, key = int(m.group(3)), m.group(4)
            if key not in SENSOR_FIELDS:
                raise ConfigError(f"{dotted}: unknown key (known in [[sensor]]: "
                                  f"{', '.join(SENSOR_FIELDS)}){_suffix(origin)}")
            if not self.sensors and index > 0:
                self.sensors.append({})  # the implicit default sensor is sensor[0]
            if index > len(self.sensors):
                raise ConfigError(f"{dotted}: sensor index {index} skips ahead; the next sensor "
                                  f"to add is sensor[{len(self.sensors)}]{_suffix(origin)}")
            if index == len(self.sensors):
                self.sensors.append({})
            self.sensors[index][key] = value
        self.origin[dotted] = origin


def _suffix(origin: str) -> str:
    return f" (from {origin})" if origin else ""


def _device_description(url: str) -> str | None:
    """The built-in description of the array a source URL's device has (``robotiq://`` ->
    ``robotiq_tsf85``), or None (not a vendor device, or the URL's size is another)."""
    from tactiled.sensors.devices import url_description
    from tactiled.sources import parse_source_url

    return url_description(parse_source_url(url))


def _is_path(value: Any) -> bool:
    """A description value naming a file (else a built-in's name)."""
    return isinstance(value, str) and (value.endswith(".toml") or "/" in value)


def _resolve(value: Any, base: Path) -> Any:
    if isinstance(value, str) and value.strip() and not os.path.isabs(value):
        return str(base / value)
    return value


def _read_file(path: Path, raw: _Raw) -> None:
    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such configuration file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, not a configuration file") from None
    except OSError as err:
        raise ConfigError(f"{path}: cannot read configuration file ({err.strerror or err})") from err
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from err
    base = path.parent
    origin = str(path)
    for top, body in doc.items():
        if top == "sensor":
            if not isinstance(body, list) or not all(isinstance(t, dict) for t in body):
                raise ConfigError(f"sensor: must be an array of tables ([[sensor]]){_suffix(origin)}")
            for i, table in enumerate(body):
                for key, value in table.items():
                    if ("sensor", key) in _PATH_KEYS or (key == "description" and _is_path(value)):
                        value = _resolve(value, base)
                    raw.set(f"sensor[{i}].{key}", value, origin)
        elif top in SECTIONS:
            if not isinstance(body, dict):
                raise ConfigError(f"{top}: must be a table ([{top}]){_suffix(origin)}")
            for key, value in body.items():
                if (top, key) in _PATH_KEYS:
                    value = _resolve(value, base)
                raw.set(f"{top}.{key}", value, origin)
        else:
            raise ConfigError(f"{top}: unknown section (known: server, sensor, fit, "
                              f"record, zenoh, ros2, state){_suffix(origin)}")


_ENV_SENSOR_RE = re.compile(r"^SENSOR_(\d+)_([A-Z_]+)$")


def _read_env(env: Mapping[str, str], raw: _Raw) -> None:
    # Sorted, so TACTILED_SENSOR_1_* (adding sensor 1) is applied before TACTILED_SENSOR_2_*.
    def order(name: str) -> tuple[int, str]:
        m = _ENV_SENSOR_RE.match(name[len(ENV_PREFIX):])
        return (int(m.group(1)) if m else -1, name)

    for name in sorted((n for n in env if n.startswith(ENV_PREFIX)), key=order):
        rest = name[len(ENV_PREFIX):]
        value = _Text(env[name])
        m = _ENV_SENSOR_RE.match(rest)
        if m:
            raw.set(f"sensor[{int(m.group(1))}].{m.group(2).lower()}", value, name)
            continue
        section, _, key = rest.partition("_")
        if section.lower() in SECTIONS:
            raw.set(f"{section.lower()}.{key.lower()}", value, name)
        elif section == "SENSOR":
            raise ConfigError(f"{name}: write TACTILED_SENSOR_<index>_<KEY>, e.g. "
                              "TACTILED_SENSOR_0_URL")
        # Any other TACTILED_* variable (TACTILED_CONFIG, ...) is not a settings key.


def _build(raw: _Raw) -> Settings:
    def typed(checks: dict[str, Callable[[Any, str], Any]], values: dict[str, Any], cls: type,
              prefix: str) -> Any:
        out = {}
        for key, value in values.items():
            dotted = f"{prefix}.{key}"
            try:
                out[key] = checks[key](value, dotted)
            except ConfigError as err:
                raise ConfigError(f"{err}{_suffix(raw.origin.get(dotted, ''))}") from None
        return cls(**out)

    server = typed(SECTIONS["server"], raw.sections["server"], ServerSettings, "server")
    fit = typed(SECTIONS["fit"], raw.sections["fit"], FitSettings, "fit")
    record = typed(SECTIONS["record"], raw.sections["record"], RecordSettings, "record")
    zenoh = typed(SECTIONS["zenoh"], raw.sections["zenoh"], ZenohSettings, "zenoh")
    ros2 = typed(SECTIONS["ros2"], raw.sections["ros2"], Ros2Settings, "ros2")
    state = typed(SECTIONS["state"], raw.sections["state"], StateSettings, "state")
    sensor_tables = raw.sensors or [{}]
    sensors = []
    for i, table in enumerate(sensor_tables):
        values = {"name": f"finger{i}", **table}
        sensor = typed(SENSOR_FIELDS, values, SensorSettings, f"sensor[{i}]")
        if "description" not in table:  # a vendor device's own array, when its driver knows it
            device = _device_description(sensor.url)
            if device is not None:
                sensor = replace(sensor, description=device)
        # the description's noise and window, unless the sensor says otherwise
        if "noise_sigma" not in table or "window" not in table:
            from tactiled.sensors import load_description

            desc = load_description(sensor.description)
            if "noise_sigma" not in table:
                sensor = replace(sensor, noise_sigma=desc.noise_sigma)
            if "window" not in table:
                sensor = replace(sensor, window=desc.window)
        sensors.append(sensor)
    seen: dict[str, int] = {}
    for i, s in enumerate(sensors):
        if s.name in seen:
            raise ConfigError(f"sensor[{i}].name: {s.name!r} is already the name of "
                              f"sensor[{seen[s.name]}]")
        seen[s.name] = i
    for i, s in enumerate(sensors):
        if s.calibration is not None and not Path(s.calibration).is_file():
            what = ("is a directory, not a file:" if Path(s.calibration).is_dir()
                    else "no such file")
            raise ConfigError(f"sensor[{i}].calibration: {what} {s.calibration!r}"
                              f"{_suffix(raw.origin.get(f'sensor[{i}].calibration', ''))}")
    if record.path is not None and len(sensors) > 1 and "{sensor}" not in record.path:
        raise ConfigError(f"record.path: must contain '{{sensor}}' with {len(sensors)} sensors "
                          f"(one recording file per sensor), got {record.path!r}")
    if zenoh.config is not None and not Path(zenoh.config).is_file():
        raise ConfigError(f"zenoh.config: no such file {zenoh.config!r}"
                          f"{_suffix(raw.origin.get('zenoh.config', ''))}")
    if zenoh.mode == "client" and not zenoh.connect and not zenoh.scouting:
        raise ConfigError("zenoh.connect: a client needs a router to connect to: give its "
                          "endpoint (e.g. [\"tcp/192.168.1.10:7447\"]) or set "
                          "zenoh.multicast_scouting = true to find one")
    if ros2.enabled and "zenoh" in ros2.middlewares(zenoh.enabled) and not zenoh.enabled:
        raise ConfigError(f"ros2.middleware: {ros2.middleware!r} publishes on the daemon's Zenoh "
                          "session: set zenoh.enabled = true as well, or middleware = \"dds\"")
    return Settings(server=server, sensors=tuple(sensors), fit=fit, record=record, zenoh=zenoh,
                    ros2=ros2, state=state)


def load_settings(path: str | os.PathLike[str] | None = None,
                  env: Mapping[str, str] | None = None,
                  overrides: Mapping[str, Any] | None = None,
                  origins: Mapping[str, str] | None = None) -> Settings:
    """Defaults < TOML file ``path`` < ``env`` (``TACTILED_*``) < ``overrides`` (dotted keys).

    ``origins``: what an error names as an override's origin (``{"server.port": "--port"}``).

    ``path`` None: ``env["TACTILED_CONFIG"]`` if set, else no file.  ``env`` None: no
    environment (pass ``os.environ`` explicitly; tests pass dicts).  Raises
    :class:`~tactiled.errors.ConfigError` naming the key of the first problem.
    """
    env = {} if env is None else env
    raw = _Raw()
    if path is None and env.get(ENV_CONFIG):
        path = env[ENV_CONFIG]
    if path is not None:
        _read_file(Path(path), raw)
    _read_env(env, raw)
    for dotted, value in (overrides or {}).items():
        raw.set(dotted, _Text(value) if isinstance(value, str) else value,
                (origins or {}).get(dotted, "overrides"))
    settings = _build(raw)
    return replace(settings, source=None if path is None else str(path))


def settings_to_dict(settings: Settings) -> dict[str, Any]:
    """The settings as plain data, with the token masked (for logs and the health endpoint)."""
    def table(obj: Any) -> dict[str, Any]:
        return {f.name: getattr(obj, f.name) for f in fields(obj)}

    server = table(settings.server)
    if server["token"] is not None:
        server["token"] = "***"
    return {
        "server": server,
        "sensor": [table(s) for s in settings.sensors],
        "fit": table(settings.fit),
        "record": table(settings.record),
        "zenoh": table(settings.zenoh),
        "ros2": table(settings.ros2),
        "state": table(settings.state),
        "source": settings.source,
    }

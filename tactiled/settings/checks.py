"""Field checks: ``(value, key) -> checked value``, or a :class:`~tactiled.errors.ConfigError`
naming the key.  Shared by the loader and the daemon's runtime ``update_config``, so both speak
the same language.  A source URL is checked by its driver's registry entry (scheme and query
keys) without importing the driver; its values are checked when the daemon builds the source.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Any

from tactiled.errors import ConfigError
from tactiled.settings.sections import (
    MODELS,
    RECORD_FORMATS,
    START_METHODS,
    ZENOH_IP_PROTOCOLS,
    ZENOH_MODES,
    ZENOH_PROTOCOLS,
)

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


def _fail(key: str, message: str) -> ConfigError:
    return ConfigError(f"{key}: {message}")


class _Text(str):
    """A value given as text (environment, overrides): parsed as the key's type.  Plain
    ``str`` values come from the TOML file, which has types of its own: ``port = "80"`` there
    is an error, not 80."""


def _as_int(value: Any, key: str) -> int:
    if isinstance(value, _Text):
        try:
            return int(value.strip(), 10)
        except ValueError:
            raise _fail(key, f"expected an integer, got {value!r}") from None
    if isinstance(value, bool) or not isinstance(value, int):
        raise _fail(key, f"expected an integer, got {value!r}")
    return value


def _as_float(value: Any, key: str) -> float:
    if isinstance(value, _Text):
        try:
            value = float(value.strip())
        except ValueError:
            raise _fail(key, f"expected a number, got {value!r}") from None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _fail(key, f"expected a number, got {value!r}")
    try:
        value = float(value)
    except OverflowError:  # an int past a double's range (a JSON body may hold one)
        raise _fail(key, "expected a finite number, got an integer too large for a double") \
            from None
    if not math.isfinite(value):
        raise _fail(key, f"expected a finite number, got {value!r}")
    return value


def _as_bool(value: Any, key: str) -> bool:
    if isinstance(value, _Text):
        lowered = value.strip().lower()
        if lowered in ("1", "true", "yes", "on"):
            return True
        if lowered in ("0", "false", "no", "off"):
            return False
        raise _fail(key, f"expected a boolean (true/false, 1/0, yes/no, on/off), got {value!r}")
    if not isinstance(value, bool):
        raise _fail(key, f"expected a boolean, got {value!r}")
    return value


def _as_str(value: Any, key: str) -> str:
    if not isinstance(value, str):
        raise _fail(key, f"expected a string, got {value!r}")
    return str(value)


def _optional(check: Callable[[Any, str], Any]) -> Callable[[Any, str], Any]:
    def checked(value: Any, key: str) -> Any:
        if value is None or (isinstance(value, _Text) and value.strip() == ""):
            return None
        return check(value, key)

    return checked


def _in_range(check: Callable[[Any, str], Any], lo: float, hi: float,
              what: str) -> Callable[[Any, str], Any]:
    def checked(value: Any, key: str) -> Any:
        v = check(value, key)
        if not lo <= v <= hi:
            raise _fail(key, f"must be {what} in {lo:g}..{hi:g}, got {v!r}")
        return v

    return checked


def _choice(choices: tuple[str, ...]) -> Callable[[Any, str], str]:
    def checked(value: Any, key: str) -> str:
        v = _as_str(value, key).strip()
        if v not in choices:
            raise _fail(key, f"must be one of {', '.join(choices)}, got {v!r}")
        return v

    return checked


def _name(value: Any, key: str) -> str:
    v = _as_str(value, key)
    if not _NAME_RE.match(v):
        raise _fail(key, f"must be 1-64 letters, digits, '_', '.', '-' (starting with a letter "
                         f"or digit), got {v!r}")
    return v


def _host(value: Any, key: str) -> str:
    v = _as_str(value, key).strip()
    if not v:
        raise _fail(key, "must not be empty")
    return v


_ORIGIN_RE = re.compile(r"^https?://[^/\s?#]+$", re.IGNORECASE)


def _origins(value: Any, key: str) -> tuple[str, ...]:
    """A list of browser origins (``scheme://host[:port]``); as text, comma-separated."""
    if isinstance(value, _Text):
        value = [part.strip() for part in value.split(",") if part.strip()]
    if not isinstance(value, (list, tuple)):
        raise _fail(key, f"expected a list of origins, got {value!r}")
    out = []
    for item in value:
        origin = _as_str(item, key).strip().rstrip("/")
        if not _ORIGIN_RE.match(origin):
            raise _fail(key, f"{item!r} is not an origin: write scheme://host[:port], e.g. "
                             "\"http://console.local:8080\" (no path)")
        out.append(origin)
    return tuple(out)


_ENDPOINT_RE = re.compile(r"^([A-Za-z0-9-]+)/([^?#]*)(\?[^#]*)?(#.*)?$")
_HOST_PORT_RE = re.compile(r"^(\[[0-9A-Fa-f:.%a-zA-Z]+\]|[A-Za-z0-9_.-]+):(\d{1,5})$")


def _endpoint(value: Any, key: str) -> str:
    """A Zenoh endpoint, ``<protocol>/<address>[?<metadata>][#<config>]``: a known protocol,
    and for the IP ones an address ``host:port`` (an IPv6 host in brackets)."""
    text = _as_str(value, key).strip()
    m = _ENDPOINT_RE.match(text)
    if not m or not m.group(2):
        raise _fail(key, f"{text!r} is not an endpoint: write <protocol>/<address>, e.g. "
                         "\"tcp/192.168.1.10:7447\"")
    proto, address = m.group(1), m.group(2)
    if proto not in ZENOH_PROTOCOLS:
        raise _fail(key, f"unknown protocol {proto!r} in {text!r} (known: "
                         f"{', '.join(ZENOH_PROTOCOLS)})")
    if proto in ZENOH_IP_PROTOCOLS:
        hp = _HOST_PORT_RE.match(address)
        if not hp:
            raise _fail(key, f"{text!r}: the address must be host:port, e.g. "
                             f"\"{proto}/127.0.0.1:7447\" (an IPv6 host in brackets: "
                             f"\"{proto}/[::1]:7447\")")
        if int(hp.group(2)) > 65535:
            raise _fail(key, f"{text!r}: port {hp.group(2)} is not a port (0..65535)")
    return text


def _ros_name(pattern: str, rule: str) -> Callable[[Any, str], str]:
    """A ROS name matching ``pattern`` whole (``rule`` says what that is, in the error)."""
    compiled = re.compile(rf"^(?:{pattern})$")

    def check(value: Any, key: str) -> str:
        text = _as_str(value, key)
        if not compiled.match(text) or "__" in text:
            raise _fail(key, f"must be {rule}, without '__', got {text!r}")
        return text

    return check


def _endpoints(value: Any, key: str) -> tuple[str, ...]:
    """A list of Zenoh endpoints; as text, comma-separated.  Errors name the item
    (``zenoh.connect[1]: ...``)."""
    if isinstance(value, _Text):
        value = [part.strip() for part in value.split(",") if part.strip()]
    if not isinstance(value, (list, tuple)):
        raise _fail(key, f"expected a list of endpoints like [\"tcp/192.168.1.10:7447\"], "
                         f"got {value!r}")
    return tuple(_endpoint(item, f"{key}[{i}]") for i, item in enumerate(value))


def _key_prefix(value: Any, key: str) -> str:
    """A Zenoh key with no wildcard: non-empty chunks separated by '/'."""
    v = _as_str(value, key).strip()
    if not v or any(not chunk for chunk in v.split("/")):
        raise _fail(key, f"must be a Zenoh key of non-empty chunks separated by '/' (no leading, "
                         f"trailing or doubled '/'), e.g. \"tactiled/hand1\", got {v!r}")
    bad = sorted({c for c in v if c in "*$?#" or c.isspace()})
    if bad:
        raise _fail(key, f"must be a plain key: {' '.join(map(repr, bad))} not allowed (no "
                         f"wildcards, selectors or spaces), got {v!r}")
    if v.startswith("@"):
        raise _fail(key, f"keys starting with '@' are Zenoh's own, got {v!r}")
    return v


def _window(value: Any, key: str) -> int:
    v = _as_int(value, key)
    if not 2 <= v <= 255:
        raise _fail(key, f"must be at least 2 tactels (and at most 255), got {v}")
    return v


def _false_rate(value: Any, key: str) -> float:
    v = _as_float(value, key)
    # Below ~1e-14 per frame the detector's threshold (a normal quantile of 1 - p / centres)
    # is beyond double precision; above 0.5 a "contact" would be a coin toss.
    if not 1e-12 <= v <= 0.5:
        raise _fail(key, f"must be a probability in 1e-12..0.5 (false contacts per "
                         f"noise-only frame), got {v!r}")
    return v


def _url(value: Any, key: str) -> str:
    """A source URL whose scheme has a driver and whose query keys that driver accepts, checked
    by the driver registry without importing the driver (the values are checked when the
    daemon builds the source)."""
    from tactiled.errors import DriverError
    from tactiled.sources import check_source_url, known_schemes, parse_source_url

    text = _as_str(value, key).strip()
    try:
        parsed = parse_source_url(text)
    except ValueError as err:
        raise _fail(key, str(err)) from None
    schemes = known_schemes()
    if parsed.scheme not in schemes:
        raise _fail(key, f"unknown scheme {parsed.scheme!r} (known: {', '.join(schemes)})")
    try:
        check_source_url(text)
    except (DriverError, ValueError) as err:
        raise _fail(key, str(err)) from None
    return text


_SERVER_FIELDS: dict[str, Callable[[Any, str], Any]] = {
    "host": _host,
    "port": _in_range(_as_int, 0, 65535, "a TCP port"),
    "token": _optional(_as_str),
    "max_subscribers": _in_range(_as_int, 1, 100_000, "a connection count"),
    "allow_origins": _origins,
    "read_timeout": _in_range(_as_float, 0.1, 3600.0, "a time in s"),
}
def _description(value: Any, key: str) -> str:
    """A sensor description: a built-in's name or a .toml file, read and checked now."""
    from tactiled.sensors import load_description

    text = _as_str(value, key).strip()
    try:
        load_description(text)
    except ConfigError as err:
        raise _fail(key, str(err)) from None
    return text


SENSOR_FIELDS: dict[str, Callable[[Any, str], Any]] = {
    "name": _name,
    "description": _description,
    "url": _url,
    "wire_id": _optional(_in_range(_as_int, 0, 65535, "a wire sensor id")),
    "calibration": _optional(_as_str),
    "model": _choice(MODELS),
    "window": _window,
    # Below ~1e-8 the fit's weights overflow (1e-300 divided by zero in the fitter); above 0.1
    # the noise would exceed any strain the rubber can carry.
    "noise_sigma": _in_range(_as_float, 1e-8, 0.1, "strain (1 sigma)"),
    "false_rate": _false_rate,
    "detector_average": _in_range(_as_int, 1, 64, "a frame count"),
    "reuse_unchanged": _as_bool,
    "track": _as_bool,
    "hysteresis": _as_bool,
    "unchanged_z": _in_range(_as_float, 0.0, 1e6, "a z-score"),
    "rate_hz": _optional(_in_range(_as_float, 0.01, 1e6, "a frame rate in Hz")),
}
#: Bounds of the pool's times (s): below the supervisor's 50 ms tick a deadline means nothing
#: (5e-324 passed a plain positivity check and had every fit's worker killed as hung).
MIN_FIT_TIME_S, MAX_FIT_TIME_S = 0.05, 3600.0
_FIT_TIME = _in_range(_as_float, MIN_FIT_TIME_S, MAX_FIT_TIME_S, "a positive time in s")
FIT_FIELDS: dict[str, Callable[[Any, str], Any]] = {
    "workers": _in_range(_as_int, 0, 256, "a worker count (0: automatic)"),
    "start_method": _choice(START_METHODS),
    "timeout": _FIT_TIME,
    "ping_interval": _FIT_TIME,
    "ping_timeout": _FIT_TIME,
    "startup_timeout": _FIT_TIME,
    "stop_timeout": _FIT_TIME,
    "max_fits_per_worker": _in_range(_as_int, 0, 10**12, "a fit count (0: never)"),
}
_RECORD_FIELDS: dict[str, Callable[[Any, str], Any]] = {
    "path": _optional(_as_str),
    "format": _choice(RECORD_FORMATS),
}
_ZENOH_FIELDS: dict[str, Callable[[Any, str], Any]] = {
    "enabled": _as_bool,
    "mode": _choice(ZENOH_MODES),
    "connect": _endpoints,
    "listen": _endpoints,
    "multicast_scouting": _optional(_as_bool),
    "prefix": _key_prefix,
    # Above the fastest sensor's frame rate the limit means nothing; 0 publishes no frame.
    "frame_rate_hz": _in_range(_as_float, 0.0, 10_000.0, "a rate in Hz"),
    "config": _optional(_as_str),
    "reliable": _as_bool,
}
_ROS_SEGMENT = r"[A-Za-z_][A-Za-z0-9_]*"
_ROS2_FIELDS: dict[str, Callable[[Any, str], Any]] = {
    "enabled": _as_bool,
    # 0..232: the domain ids ROS 2 documents (DDS port arithmetic ends there; rmw_zenoh keeps
    # the same ROS_DOMAIN_ID meaning).
    "domain_id": _in_range(_as_int, 0, 232, "a ROS domain id"),
    "namespace": _ros_name(rf"/|(/{_ROS_SEGMENT})+",
                           "'/' or /name[/name...] (letters, digits, '_'; no leading digit)"),
    "node_name": _ros_name(_ROS_SEGMENT, "letters, digits and '_', not starting with a digit"),
    "frame_id": _as_str,
    "middleware": _choice(("auto", "dds", "zenoh", "both")),
    "distro": _choice(("humble", "jazzy", "kilted", "rolling")),
}
_STATE_FIELDS: dict[str, Callable[[Any, str], Any]] = {
    "dir": _optional(_as_str),
}
SECTIONS: dict[str, dict[str, Callable[[Any, str], Any]]] = {
    "server": _SERVER_FIELDS,
    "fit": FIT_FIELDS,
    "record": _RECORD_FIELDS,
    "zenoh": _ZENOH_FIELDS,
    "ros2": _ROS2_FIELDS,
    "state": _STATE_FIELDS,
}

#: Sensor keys the daemon can change while running (Daemon.update_config).
RUNTIME_SENSOR_KEYS = ("model", "window", "noise_sigma", "false_rate", "reuse_unchanged",
                       "unchanged_z", "track", "hysteresis")


def check_sensor_value(key: str, value: Any, where: str) -> Any:
    """Check one sensor key's value; ``where`` names it in errors (``sensor[0].model``)."""
    check = SENSOR_FIELDS.get(key)
    if check is None:
        raise _fail(where, f"unknown key (known: {', '.join(SENSOR_FIELDS)})")
    return check(value, where)

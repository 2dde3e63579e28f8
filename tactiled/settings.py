"""Daemon configuration: a TOML file, ``TACTILED_*`` environment variables, explicit overrides.

Precedence, lowest first: built-in defaults < the file < the environment < ``overrides`` (the
command line).  Everything is validated once, here, and every problem is a
:class:`~tactiled.errors.ConfigError` whose message starts with the offending key, e.g.
``sensor[1].url: unknown scheme 'foo' (known: replay, serial, sim)``.

Keys (the documented example is ``deploy/tactiled.toml``)::

    [server]   host = "127.0.0.1", port = 8765, token = (none), max_subscribers = 64,
               allow_origins = [] (browser origins besides the server's own),
               read_timeout = 10 (s to send a request's headers, and its body)
    [[sensor]] name, url, wire_id, calibration, model, window, noise_sigma, false_rate,
               detector_average, reuse_unchanged, unchanged_z, track, hysteresis,
               rate_hz
    [fit]      workers, start_method, timeout, ping_interval, ping_timeout, startup_timeout,
               stop_timeout, max_fits_per_worker
    [record]   path, format = "tact" ("mcap", "both")
    [zenoh]    enabled = false, mode = "peer", connect = [], listen = [],
               multicast_scouting = (on in peer mode), prefix = "tactiled/<hostname>",
               frame_rate_hz = 0, config = (none)
    [ros2]     enabled = false, domain_id = 0, namespace = "/tactiled", node_name = "tactiled",
               frame_id = "{sensor}", middleware = "auto" ("dds", "zenoh", "both"),
               distro = "jazzy" ("humble", "kilted", "rolling")
    [state]    dir = ($STATE_DIRECTORY, else ~/.local/state/tactiled)

With no file and no sensor keys anywhere there is one sensor, ``finger0`` on
``sim://?scene=demo&seed=1``.

Environment: ``TACTILED_CONFIG`` names the file when ``path`` is None;
``TACTILED_<SECTION>_<KEY>`` sets ``<section>.<key>`` (``TACTILED_SERVER_PORT``,
``TACTILED_FIT_TIMEOUT``, ``TACTILED_RECORD_PATH``, ``TACTILED_ZENOH_CONNECT``);
``TACTILED_SENSOR_<i>_<KEY>`` sets ``sensor[i].<key>`` (``TACTILED_SENSOR_0_URL``; ``i`` may be
one past the last sensor to add one).  An unknown name under those prefixes is an error (a
typo must not be ignored);
other ``TACTILED_*`` names belong to other parts of tactiled and are left alone.  Overrides are
a flat dict of the same dotted keys: ``{"server.port": 9000, "sensor[0].url": "..."}``.
String values from the environment or overrides are parsed as the key's type (``""`` means
"none" for optional keys; lists are comma-separated).  Relative ``calibration``,
``record.path`` and ``zenoh.config`` values in the file are relative to the file's directory;
elsewhere to the working directory.
"""

from __future__ import annotations

import math
import os
import re
import socket
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from tactiled.errors import ConfigError

DEFAULT_HOST = "127.0.0.1"
#: The REST/WebSocket port.  8765 is unassigned by IANA and easy to remember.
DEFAULT_PORT = 8765
DEFAULT_URL = "sim://?scene=demo&seed=1"
MODELS = ("auto", "cylinder", "sphere", "general")
START_METHODS = ("forkserver", "spawn")
ZENOH_MODES = ("peer", "client")
RECORD_FORMATS = ("tact", "mcap", "both")
#: Link protocols a Zenoh endpoint may name (what zenoh's transports know), and of those the
#: ones whose address is ``host:port``.
ZENOH_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream", "unixpipe", "serial",
                   "vsock")
ZENOH_IP_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")
ENV_PREFIX = "TACTILED_"
ENV_CONFIG = "TACTILED_CONFIG"

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


@dataclass(frozen=True)
class ServerSettings:
    """Where the REST/WebSocket service listens (used by ``tactiled run``)."""

    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT  # 0: any free port
    token: str | None = None  # bearer token for the API; None: no authentication
    max_subscribers: int = 64  # WebSocket stream connections at once; one more gets 1013
    #: Browser origins ("scheme://host[:port]") allowed besides the server's own.
    allow_origins: tuple[str, ...] = ()
    #: s a client has to send a request's headers (from connecting, or from the previous
    #: answer), and then its body; a slower one is answered 408 and disconnected.
    read_timeout: float = 10.0


@dataclass(frozen=True)
class SensorSettings:
    """One fingertip: where its frames come from and how they are turned into estimates."""

    name: str = "finger0"  # how the API names the sensor
    #: what the array is (docs/howto/sensors.md): a built-in description's name or a .toml file
    description: str = "fearing1988"
    url: str = DEFAULT_URL  # frame source URL (serial://, sim://, replay://)
    wire_id: int | None = None  # sensor_id in the frames; None: the calibration's, else any
    calibration: str | None = None  # lookup-table file; None: the nominal linear table
    model: str = "auto"  # contact model: auto (BIC choice), cylinder, sphere, general
    window: int = 4  # side of the square fit window, tactels
    noise_sigma: float = 0.0005  # strain noise of a zeroed tactel, 1 sigma (dimensionless)
    false_rate: float = 1e-4  # false contacts per noise-only frame (contact threshold)
    detector_average: int = 2  # frames the contact detector averages (latency for sensitivity)
    reuse_unchanged: bool = True  # gate: reuse the last fit for a frame unchanged within noise
    unchanged_z: float = 3.0  # gate: "unchanged" means chi^2 <= n + z sqrt(2n), see gate.py
    #: Follow the contact through time (tactiled/pipeline/contact_filter.py): every contact frame
    #: measured through the last fit, a held contact sharpened, rates estimated.  False: each
    #: estimate is one frame's fit, reused while frames are unchanged (the gate).
    track: bool = True
    #: Learn the rubber's hysteresis from tracked contacts and take it out of every frame once
    #: the estimate is significant (tactiled/calibration/hysteresis.py).  False: frames as read.
    hysteresis: bool = True
    #: Nominal frame rate (Hz); health reports the sensor DEGRADED while it delivers less
    #: (below 0.9 of it over a second) for more than 2 s.  None: no nominal rate, not judged.
    rate_hz: float | None = None


@dataclass(frozen=True)
class FitSettings:
    """The fit worker processes (times in seconds)."""

    workers: int = 0  # worker processes; 0: min(number of sensors, CPUs)
    start_method: str = "forkserver"  # multiprocessing start method (never fork)
    timeout: float = 1.0  # a fit with no answer within this is a hung worker: restarted
    ping_interval: float = 0.5  # an idle worker is pinged this often
    ping_timeout: float = 1.0  # ... and restarted if it does not answer within this
    startup_timeout: float = 30.0  # a new worker must be ready (fitters warmed) within this
    stop_timeout: float = 2.0  # graceful stop: in-flight fits get this long, then SIGKILL
    #: Replace a worker after this many fits (a successor is started first, so no fit is lost
    #: and the stream has no gap); 0: never.  A safety net against memory creep, off by default.
    max_fits_per_worker: int = 0


@dataclass(frozen=True)
class RecordSettings:
    """Recording of raw frames (tactiled/recording.py format), appended across restarts."""

    path: str | None = None  # file path; must contain "{sensor}" with several sensors
    #: "tact" (the raw wire frames), "mcap" (the ROS 2 messages, to ``path`` with the suffix
    #: ``.mcap``; docs/howto/ros2.md) or "both".
    format: str = "tact"


def default_zenoh_prefix() -> str:
    """``tactiled/<hostname>``, the host name reduced to what a key expression chunk may hold
    (letters, digits, '_', '.', '-'; anything else becomes '_')."""
    host = re.sub(r"[^A-Za-z0-9_.-]", "_", socket.gethostname().strip()) or "localhost"
    return f"tactiled/{host}"


@dataclass(frozen=True)
class ZenohSettings:
    """Publishing on Zenoh (``service/tactiled_service/bus.py``, ``docs/howto/zenoh.md``): off by
    default; needs the ``zenoh`` extra (``pip install 'tactiled[zenoh]'``)."""

    enabled: bool = False
    mode: str = "peer"  # "peer" (meshes with other peers) or "client" (through a router)
    #: Endpoints to connect to, ``<protocol>/<address>`` (``tcp/192.168.1.10:7447``).
    connect: tuple[str, ...] = ()
    #: Endpoints to listen on; empty: Zenoh's default (a peer: ``tcp/[::]:0``, every
    #: interface and a free port; a client: none).
    listen: tuple[str, ...] = ()
    #: UDP multicast scouting for peers and routers; None: on in peer mode, off in client mode.
    multicast_scouting: bool | None = None
    prefix: str = field(default_factory=default_zenoh_prefix)  # every key starts with it
    frame_rate_hz: float = 0.0  # zeroed frames per second per sensor, at most; 0: none
    config: str | None = None  # a Zenoh configuration file (JSON5), applied first

    @property
    def scouting(self) -> bool:
        """Whether multicast scouting is on (the default resolved for the mode)."""
        if self.multicast_scouting is None:
            return self.mode == "peer"
        return self.multicast_scouting


@dataclass(frozen=True)
class Ros2Settings:
    """ROS 2 topics over DDS (Cyclone DDS, as ROS 2's DDS middlewares lay them out) and/or
    on the daemon's Zenoh session (as rmw_zenoh lays them out): ``service/tactiled_service/
    ros2/``, ``docs/howto/ros2.md``.  Off by default; needs the ``ros2`` extra (``pip install
    'tactiled[ros2]'``), and ``zenoh.enabled`` for the Zenoh middleware."""

    enabled: bool = False
    domain_id: int = 0  # the ROS_DOMAIN_ID of the graph to join
    namespace: str = "/tactiled"  # the node's namespace: topics are <namespace>/<sensor>/<kind>
    node_name: str = "tactiled"
    frame_id: str = "{sensor}"  # header.frame_id of the messages; "{sensor}": the sensor's name
    #: "dds", "zenoh" or "both"; "auto": "zenoh" when zenoh.enabled, else "dds"
    middleware: str = "auto"
    #: the ROS 2 distribution whose rmw_zenoh layout to speak (Humble's has no type hashes)
    distro: str = "jazzy"

    def middlewares(self, zenoh_enabled: bool) -> tuple[str, ...]:
        """The middlewares to publish on: ``("dds",)``, ``("zenoh",)`` or both."""
        chosen = self.middleware
        if chosen == "auto":
            chosen = "zenoh" if zenoh_enabled else "dds"
        return ("dds", "zenoh") if chosen == "both" else (chosen,)


@dataclass(frozen=True)
class StateSettings:
    """What the daemon keeps across restarts (the flat field each sensor learns from its fits:
    ``tactiled/pipeline/learned.py``)."""

    #: The state directory; None: ``$STATE_DIRECTORY`` (systemd's ``StateDirectory=``), else
    #: ``$XDG_STATE_HOME/tactiled`` or ``~/.local/state/tactiled``.
    dir: str | None = None

    def directory(self) -> Path:
        from tactiled.pipeline.learned import default_state_dir

        return Path(self.dir) if self.dir is not None else default_state_dir()


@dataclass(frozen=True)
class Settings:
    """The daemon's whole configuration."""

    server: ServerSettings = field(default_factory=ServerSettings)
    sensors: tuple[SensorSettings, ...] = (SensorSettings(),)
    fit: FitSettings = field(default_factory=FitSettings)
    record: RecordSettings = field(default_factory=RecordSettings)
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)
    ros2: Ros2Settings = field(default_factory=Ros2Settings)
    state: StateSettings = field(default_factory=StateSettings)
    source: str | None = None  # the config file read, if any

    def sensor(self, name: str) -> SensorSettings:
        """The settings of sensor ``name`` (``KeyError`` if there is none)."""
        for s in self.sensors:
            if s.name == name:
                return s
        raise KeyError(name)

    def worker_count(self) -> int:
        """Worker processes to start: ``fit.workers``, or min(sensors, CPUs) when 0."""
        if self.fit.workers > 0:
            return self.fit.workers
        return max(1, min(len(self.sensors), os.cpu_count() or 1))

    def record_path(self, sensor: str) -> Path | None:
        """The recording file of ``sensor`` ("{sensor}" filled in), or None."""
        if self.record.path is None or self.record.format == "mcap":
            return None
        return Path(self.record.path.replace("{sensor}", sensor))

    def mcap_record_path(self, sensor: str) -> Path | None:
        """The MCAP recording of ``sensor`` (``record.path`` with the suffix ``.mcap``), or
        None when ``record.format`` is "tact"."""
        if self.record.path is None or self.record.format == "tact":
            return None
        return Path(self.record.path.replace("{sensor}", sensor)).with_suffix(".mcap")


# --------------------------------------------------------------------------------------------
# Field checks: (value, key) -> checked value, or ConfigError naming the key.
# Shared with the daemon's runtime update_config so both speak the same language.


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
    """A source URL whose scheme has a driver and whose parameters that driver accepts."""
    from tactiled.errors import DriverError
    from tactiled.sources import known_schemes, open_source, parse_source_url

    text = _as_str(value, key).strip()
    try:
        parsed = parse_source_url(text)
    except ValueError as err:
        raise _fail(key, str(err)) from None
    schemes = known_schemes()
    if parsed.scheme not in schemes:
        raise _fail(key, f"unknown scheme {parsed.scheme!r} (known: {', '.join(schemes)})")
    try:
        # Builds the driver object without any I/O: it checks the URL's parameters.
        open_source(text)
    except DriverError as err:
        raise _fail(key, str(err)) from None
    except ValueError as err:
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
_SECTIONS: dict[str, dict[str, Callable[[Any, str], Any]]] = {
    "server": _SERVER_FIELDS,
    "fit": FIT_FIELDS,
    "record": _RECORD_FIELDS,
    "zenoh": _ZENOH_FIELDS,
    "ros2": _ROS2_FIELDS,
    "state": _STATE_FIELDS,
}
#: Keys whose relative paths are taken relative to the config file.
_PATH_KEYS = {("sensor", "calibration"), ("record", "path"), ("zenoh", "config"), ("state", "dir")}

#: Sensor keys the daemon can change while running (Daemon.update_config).
RUNTIME_SENSOR_KEYS = ("model", "window", "noise_sigma", "false_rate", "reuse_unchanged",
                       "unchanged_z", "track", "hysteresis")


def check_sensor_value(key: str, value: Any, where: str) -> Any:
    """Check one sensor key's value; ``where`` names it in errors (``sensor[0].model``)."""
    check = SENSOR_FIELDS.get(key)
    if check is None:
        raise _fail(where, f"unknown key (known: {', '.join(SENSOR_FIELDS)})")
    return check(value, where)


# --------------------------------------------------------------------------------------------
# Loading and merging


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
            if key not in _SECTIONS[section]:
                raise ConfigError(f"{dotted}: unknown key (known in [{section}]: "
                                  f"{', '.join(_SECTIONS[section])}){_suffix(origin)}")
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
    ``robotiq_tsf85``), or None (the driver does not say, or the URL's size is another)."""
    from tactiled.sources import open_source

    device = open_source(url).device_array()  # builds the driver without I/O
    return None if device is None else device.description


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
        elif top in _SECTIONS:
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
        if section.lower() in _SECTIONS:
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

    server = typed(_SERVER_FIELDS, raw.sections["server"], ServerSettings, "server")
    fit = typed(FIT_FIELDS, raw.sections["fit"], FitSettings, "fit")
    record = typed(_RECORD_FIELDS, raw.sections["record"], RecordSettings, "record")
    zenoh = typed(_ZENOH_FIELDS, raw.sections["zenoh"], ZenohSettings, "zenoh")
    ros2 = typed(_ROS2_FIELDS, raw.sections["ros2"], Ros2Settings, "ros2")
    state = typed(_STATE_FIELDS, raw.sections["state"], StateSettings, "state")
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

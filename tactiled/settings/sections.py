"""The daemon's configuration as typed, frozen sections (``[server]``, ``[[sensor]]``,
``[fit]``, ``[record]``, ``[zenoh]``, ``[ros2]``, ``[state]``) with their defaults; the keys
are documented in docs/reference/configuration.md.
"""

from __future__ import annotations

import os
import re
import socket
from dataclasses import dataclass, field
from pathlib import Path

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
#: What the daemon reads when ``[state] dir`` is not set: the service's state directory, then
#: the user's (XDG).
ENV_SYSTEMD = "STATE_DIRECTORY"


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
    """Recording of raw frames (tactiled/io/recording.py format), appended across restarts."""

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
    #: Estimates and slip events put with congestion control BLOCK (no Zenoh node drops one
    #: for a full queue; a stalled subscriber pauses the others up to wait_before_close) instead
    #: of DROP (docs/howto/zenoh.md).
    reliable: bool = False

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
        return Path(self.dir) if self.dir is not None else default_state_dir()


def default_state_dir(env: dict[str, str] | None = None) -> Path:
    """``$STATE_DIRECTORY`` (systemd sets it from the unit's ``StateDirectory=``: the first of
    a colon-separated list), else ``$XDG_STATE_HOME/tactiled``, else
    ``~/.local/state/tactiled``."""
    env = dict(os.environ) if env is None else env
    if env.get(ENV_SYSTEMD):
        return Path(env[ENV_SYSTEMD].split(":")[0])
    base = env.get("XDG_STATE_HOME") or str(Path(env.get("HOME") or Path.home()) / ".local" / "state")
    return Path(base) / "tactiled"


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

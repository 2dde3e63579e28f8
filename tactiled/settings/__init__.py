"""Daemon configuration: a TOML file, ``TACTILED_*`` environment variables, explicit overrides.

Precedence, lowest first: built-in defaults < the file < the environment < ``overrides`` (the
command line).  Everything is validated once, here, and every problem is a
:class:`~tactiled.errors.ConfigError` whose message starts with the offending key, e.g.
``sensor[1].url: unknown scheme 'foo' (known: replay, serial, sim)``.
"""

# Keys (the documented example is ``deploy/tactiled.toml``)::
#
#     [server]   host = "127.0.0.1", port = 8765, token = (none), max_subscribers = 64,
#                allow_origins = [] (browser origins besides the server's own),
#                read_timeout = 10 (s to send a request's headers, and its body)
#     [[sensor]] name, url, wire_id, calibration, model, window, noise_sigma, false_rate,
#                detector_average, reuse_unchanged, unchanged_z, track, hysteresis,
#                rate_hz
#     [fit]      workers, start_method, timeout, ping_interval, ping_timeout, startup_timeout,
#                stop_timeout, max_fits_per_worker
#     [record]   path, format = "tact" ("mcap", "both")
#     [zenoh]    enabled = false, mode = "peer", connect = [], listen = [],
#                multicast_scouting = (on in peer mode), prefix = "tactiled/<hostname>",
#                frame_rate_hz = 0, config = (none), reliable = false
#     [ros2]     enabled = false, domain_id = 0, namespace = "/tactiled", node_name = "tactiled",
#                frame_id = "{sensor}", middleware = "auto" ("dds", "zenoh", "both"),
#                distro = "jazzy" ("humble", "kilted", "rolling")
#     [state]    dir = ($STATE_DIRECTORY, else ~/.local/state/tactiled)
#
# With no file and no sensor keys anywhere there is one sensor, ``finger0`` on
# ``sim://?scene=demo&seed=1``.
#
# Environment: ``TACTILED_CONFIG`` names the file when ``path`` is None;
# ``TACTILED_<SECTION>_<KEY>`` sets ``<section>.<key>`` (``TACTILED_SERVER_PORT``,
# ``TACTILED_FIT_TIMEOUT``, ``TACTILED_RECORD_PATH``, ``TACTILED_ZENOH_CONNECT``);
# ``TACTILED_SENSOR_<i>_<KEY>`` sets ``sensor[i].<key>`` (``TACTILED_SENSOR_0_URL``; ``i`` may be
# one past the last sensor to add one).  An unknown name under those prefixes is an error (a
# typo must not be ignored);
# other ``TACTILED_*`` names belong to other parts of tactiled and are left alone.  Overrides are
# a flat dict of the same dotted keys: ``{"server.port": 9000, "sensor[0].url": "..."}``.
# String values from the environment or overrides are parsed as the key's type (``""`` means
# "none" for optional keys; lists are comma-separated).  Relative ``calibration``,
# ``record.path`` and ``zenoh.config`` values in the file are relative to the file's directory;
# elsewhere to the working directory.

from tactiled.settings.checks import (
    FIT_FIELDS,
    MAX_FIT_TIME_S,
    MIN_FIT_TIME_S,
    RUNTIME_SENSOR_KEYS,
    SECTIONS,
    SENSOR_FIELDS,
    check_sensor_value,
)
from tactiled.settings.loading import load_settings, settings_to_dict
from tactiled.settings.sections import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    DEFAULT_URL,
    ENV_CONFIG,
    ENV_PREFIX,
    MODELS,
    RECORD_FORMATS,
    START_METHODS,
    ZENOH_IP_PROTOCOLS,
    ZENOH_MODES,
    ZENOH_PROTOCOLS,
    FitSettings,
    RecordSettings,
    Ros2Settings,
    SensorSettings,
    ServerSettings,
    Settings,
    StateSettings,
    ZenohSettings,
    default_state_dir,
    default_zenoh_prefix,
)

__all__ = [
    "DEFAULT_HOST", "DEFAULT_PORT", "DEFAULT_URL", "ENV_CONFIG", "ENV_PREFIX", "FIT_FIELDS",
    "MAX_FIT_TIME_S", "MIN_FIT_TIME_S", "MODELS", "RECORD_FORMATS", "RUNTIME_SENSOR_KEYS",
    "SECTIONS", "SENSOR_FIELDS", "START_METHODS", "ZENOH_IP_PROTOCOLS", "ZENOH_MODES",
    "ZENOH_PROTOCOLS", "FitSettings", "RecordSettings", "Ros2Settings", "SensorSettings",
    "ServerSettings", "Settings", "StateSettings", "ZenohSettings", "check_sensor_value",
    "default_state_dir", "default_zenoh_prefix", "load_settings", "settings_to_dict",
]

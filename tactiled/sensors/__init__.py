"""Sensor descriptions: what a taxel array is (grid, surface, cover, noise, wiring).

:func:`load_description` reads a TOML file or a built-in by name; the built-ins are package
data in ``builtin/``, each number with its source.  docs/howto/sensors.md is the user's guide.
"""

from tactiled.sensors.description import (
    DEFAULT_NAME,
    SensorDescription,
    builtin_names,
    builtin_text,
    default_description,
    load_description,
    parse_description,
)

__all__ = ["DEFAULT_NAME", "SensorDescription", "builtin_names", "builtin_text",
           "default_description", "load_description", "parse_description"]

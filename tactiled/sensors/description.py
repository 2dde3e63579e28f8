"""A sensor description: everything the physics needs to know about one taxel array."""

# A description is one TOML file (docs/howto/sensors.md)::
#
#     name = "flat16"
#     rows = 16                  # tactels along x
#     cols = 16                  # tactels along y
#     pitch_x_mm = 2.5
#     pitch_y_mm = 2.5
#     surface_radius_mm = inf    # the surface's radius around y; inf (or absent): a flat array
#     depth_x_mm = 2.0           # the cover's impulse response (docs/concepts/model.md)
#     nu_x = 0.5
#     depth_y_mm = 2.0
#     nu_y = 0.5
#     modulus_n_mm2 = 0.25       # the cover's modulus (force scale)
#     noise_sigma = 0.0005       # one zeroed tactel's strain noise, 1 sigma
#     wire_order = "row-major"   # or "column-major", "serpentine-rows", or a list of indices
#     dead = [[0, 3]]            # tactels to ignore (broken, covered)
#     axes = 1                   # 1: one reading per taxel (strain); 3: x, y, z per taxel
#     # with axes = 3 (docs/concepts/shear.md): what each taxel measures, the displacement of a
#     # point at taxel_depth_mm under the surface (a magnet over a Hall sensor), in readings
#     # per mm along x, y, z, and each axis's noise in readings, 1 sigma:
#     taxel_depth_mm = 3.0
#     axis_gain = [1000.0, 1000.0, 1000.0]
#     axis_noise = [2.0, 2.0, 2.0]
#
# Units are in the key names.  Built-in descriptions are package data
# (``tactiled/sensors/builtin/NAME.toml``); :func:`load_description` takes a path or a built-in's
# name.  A bad description is a :class:`~tactiled.errors.ConfigError` naming the key.
#
# Conventions (docs/concepts/model.md): tactel ``[m, n]`` sits at ``x = m * pitch_x_mm`` (``m < rows``),
# ``y = n * pitch_y_mm``; raw counts arrive in wire order, and :meth:`SensorDescription.to_grid`
# puts them on the ``(rows, cols)`` grid.

from __future__ import annotations

import hashlib
import json
import math
import tomllib
from dataclasses import asdict, dataclass, field, fields
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from tactiled.sensors.model import (
    COVER_RANGES,
    Geometry,
    ImpulseResponse,
    Material,
    NoiseModel,
    SensorModel,
)
from tactiled.errors import ConfigError

#: Wire orders a description may name (or an explicit list of indices).
WIRE_ORDERS = ("row-major", "column-major", "serpentine-rows")
#: Array sizes a description may declare (each side), and the largest tactel count the wire
#: format carries (tactiled/frames.py MAX_TACTELS).
MIN_SIDE, MAX_SIDE = 2, 64
MAX_TACTELS = 4096
#: Physical ranges of the grid and of the cover's constants (the cover's are the model's
#: :data:`~tactiled.sensors.model.COVER_RANGES`, under this file's key names).
RANGES: dict[str, tuple[float, float]] = {
    "pitch_x_mm": (0.1, 100.0),
    "pitch_y_mm": (0.1, 100.0),
    "depth_x_mm": COVER_RANGES["depth_x"],
    "depth_y_mm": COVER_RANGES["depth_y"],
    "nu_x": COVER_RANGES["nu_x"],
    "nu_y": COVER_RANGES["nu_y"],
    "modulus_n_mm2": COVER_RANGES["modulus"],
    "noise_sigma": (1e-8, 0.1),
    "cover_poisson": (0.0, 0.5),
    "taxel_depth_mm": (0.1, 30.0),
    "axis_gain": (1e-6, 1e9),
    "axis_noise": (1e-9, 1e9),
}
#: The keys of a 3-axis array, with their defaults when ``axes = 1`` (absent from its TOML and
#: its fingerprint, so a 1-axis description reads and hashes as it always has).
THREE_AXIS_KEYS = ("taxel_depth_mm", "axis_gain", "axis_noise")
DEFAULT_NAME = "fearing1988"


@dataclass(frozen=True)
class SensorDescription:
    """One taxel array (see the module docstring for every key, its unit and convention).

    ``surface_radius_mm`` is ``math.inf`` for a flat array.  ``wire_order`` is one of
    :data:`WIRE_ORDERS` or a tuple of ``rows * cols`` grid indices (``m * cols + n``), the
    tactel each wire position carries.  ``dead`` lists ``(m, n)`` tactels the fit ignores.
    ``nominal`` names the keys whose values are a vendor's nominal figure or a guess, not a
    measurement (``tactiled calibrate --identify`` measures the cover's); ``sources`` says
    where each number came from.
    """

    name: str
    rows: int
    cols: int
    pitch_x_mm: float
    pitch_y_mm: float
    surface_radius_mm: float = math.inf
    depth_x_mm: float = 4.3
    nu_x: float = 0.5
    depth_y_mm: float = 6.0
    nu_y: float = 0.7
    modulus_n_mm2: float = 0.25
    cover_poisson: float = 0.5
    noise_sigma: float = 0.0005
    #: side of the fit window, tactels (``tactiled sensors windows NAME`` shows what each keeps)
    window: int = 4
    wire_order: str | tuple[int, ...] = "row-major"
    dead: tuple[tuple[int, int], ...] = ()
    description: str = ""
    nominal: tuple[str, ...] = ()
    sources: tuple[str, ...] = field(default=(), compare=False)
    #: readings per taxel: 1 (strain) or 3 (displacement x, y, z at ``taxel_depth_mm``)
    axes: int = 1
    taxel_depth_mm: float = 0.0
    axis_gain: tuple[float, float, float] = (1.0, 1.0, 1.0)
    axis_noise: tuple[float, float, float] = (1.0, 1.0, 1.0)

    # -- derived ----------------------------------------------------------------------------
    @property
    def flat(self) -> bool:
        """True for a flat array (``1/R_f = 0``)."""
        return math.isinf(self.surface_radius_mm)

    def geometry(self) -> Geometry:
        return Geometry(rows=self.rows, cols=self.cols, dx=self.pitch_x_mm, dy=self.pitch_y_mm,
                        finger_radius=self.surface_radius_mm)

    def sensor_model(self, noise_sigma: float | None = None) -> SensorModel:
        """The :class:`~tactiled.sensors.model.SensorModel` the physics and the fitter take
        (``noise_sigma`` overrides the description's)."""
        return SensorModel(
            geometry=self.geometry(),
            impulse=ImpulseResponse(self.depth_x_mm, self.nu_x, self.depth_y_mm, self.nu_y),
            material=Material(self.modulus_n_mm2, self.cover_poisson),
            noise=NoiseModel(self.noise_sigma if noise_sigma is None else noise_sigma),
        )

    @cached_property
    def _permutation(self) -> np.ndarray | None:
        """Grid index of each wire position, or None for row-major."""
        n = self.rows * self.cols
        if self.wire_order == "row-major":
            return None
        grid = np.arange(n).reshape(self.rows, self.cols)
        if self.wire_order == "column-major":
            perm = grid.T.ravel()
        elif self.wire_order == "serpentine-rows":
            snake = grid.copy()
            snake[1::2] = snake[1::2, ::-1]
            perm = snake.ravel()
        else:
            perm = np.asarray(self.wire_order, dtype=np.intp)
        perm.setflags(write=False)
        return perm

    def to_grid(self, wire: np.ndarray) -> np.ndarray:
        """Counts in wire order (``rows * cols`` values, any shape) on the ``(rows, cols)`` grid."""
        flat = np.asarray(wire).reshape(-1)
        perm = self._permutation
        if perm is None:
            return flat.reshape(self.rows, self.cols)
        out = np.empty_like(flat)
        out[perm] = flat
        return out.reshape(self.rows, self.cols)

    def to_wire(self, grid: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`to_grid`: a ``(rows, cols)`` grid as a flat wire-order array."""
        flat = np.asarray(grid).reshape(-1)
        perm = self._permutation
        return flat.copy() if perm is None else flat[perm]

    def dead_mask(self) -> np.ndarray | None:
        """``(rows, cols)`` boolean mask, True on tactels to use; None when every one is."""
        if not self.dead:
            return None
        mask = np.ones((self.rows, self.cols), dtype=bool)
        for m, n in self.dead:
            mask[m, n] = False
        return mask

    def fingerprint(self) -> str:
        """A short hash of everything the physics reads (not the name, sources or text): two
        descriptions with one fingerprint describe the same array."""
        doc = {f.name: getattr(self, f.name) for f in fields(self)
               if f.name not in ("name", "description", "sources", "nominal")
               and (self.axes == 3 or f.name not in ("axes", *THREE_AXIS_KEYS))}
        doc["surface_radius_mm"] = None if self.flat else self.surface_radius_mm
        text = json.dumps(doc, sort_keys=True, default=list)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    # -- writing ----------------------------------------------------------------------------
    def to_toml(self) -> str:
        """The description as TOML, readable by :func:`parse_description`."""
        lines = [f"# {line}" if line else "#" for line in self.sources]
        for f in fields(self):
            if f.name == "sources":
                continue
            value = getattr(self, f.name)
            if f.name in ("description",) and not value:
                continue
            if f.name in ("dead", "nominal") and not value:
                continue
            if self.axes == 1 and f.name in ("axes", *THREE_AXIS_KEYS):
                continue
            lines.append(f"{f.name} = {_toml_value(value)}")
        return "\n".join(lines) + "\n"

    def summary(self) -> dict[str, Any]:
        """A JSON-ready dict of the description (``surface_radius_mm`` null when flat)."""
        d = asdict(self)
        d.pop("sources")
        d["surface_radius_mm"] = None if self.flat else self.surface_radius_mm
        d["flat"] = self.flat
        d["dead"] = [list(t) for t in self.dead]
        d["nominal"] = list(self.nominal)
        for key in THREE_AXIS_KEYS:
            if self.axes == 1:
                d.pop(key)
            elif key != "taxel_depth_mm":
                d[key] = list(d[key])
        if not isinstance(self.wire_order, str):
            d["wire_order"] = list(self.wire_order)
        return d


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isinf(value):
            return "inf"
        return repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML form for {value!r}")


# --------------------------------------------------------------------------------------------
# Reading

_KNOWN = {f.name for f in fields(SensorDescription)} - {"sources"}
_REQUIRED = ("name", "rows", "cols", "pitch_x_mm", "pitch_y_mm")


def _fail(where: str, key: str, message: str) -> ConfigError:
    return ConfigError(f"{where}: key {key!r}: {message}")


def _number(doc: dict[str, Any], key: str, where: str, default: float | None = None) -> float:
    value = doc.get(key, default)
    if value is None:
        raise _fail(where, key, "is missing")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _fail(where, key, f"must be a number, got {value!r}")
    value = float(value)
    if key == "surface_radius_mm":
        if math.isnan(value) or value <= 0:
            raise _fail(where, key, f"must be a radius > 0 in mm, or inf for a flat array, got {value!r}")
        return value
    if not math.isfinite(value):
        raise _fail(where, key, f"must be finite, got {value!r}")
    lo, hi = RANGES[key]
    if not lo <= value <= hi:
        raise _fail(where, key, f"is {value:g}, outside {lo:g}..{hi:g}")
    return value


def _side(doc: dict[str, Any], key: str, where: str) -> int:
    value = doc.get(key)
    if value is None:
        raise _fail(where, key, "is missing")
    if isinstance(value, bool) or not isinstance(value, int):
        raise _fail(where, key, f"must be a whole number of tactels, got {value!r}")
    if not MIN_SIDE <= value <= MAX_SIDE:
        raise _fail(where, key, f"is {value}, outside {MIN_SIDE}..{MAX_SIDE}")
    return value


def _wire_order(value: Any, n: int, where: str) -> str | tuple[int, ...]:
    if isinstance(value, str):
        if value not in WIRE_ORDERS:
            raise _fail(where, "wire_order", f"{value!r} is not one of {', '.join(WIRE_ORDERS)} "
                        "(or a list of grid indices)")
        return value
    if isinstance(value, list):
        if len(value) != n or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise _fail(where, "wire_order", f"a list must hold {n} whole numbers (rows * cols), "
                        f"got {len(value)} values")
        if sorted(value) != list(range(n)):
            raise _fail(where, "wire_order", f"a list must name each grid index 0..{n - 1} once")
        return tuple(value)
    raise _fail(where, "wire_order", f"must be a name or a list of indices, got {value!r}")


def _dead(value: Any, rows: int, cols: int, where: str) -> tuple[tuple[int, int], ...]:
    if not isinstance(value, list):
        raise _fail(where, "dead", f"must be a list of [row, col] pairs, got {value!r}")
    out = []
    for i, pair in enumerate(value):
        if (not isinstance(pair, list) or len(pair) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) for v in pair)):
            raise _fail(where, "dead", f"entry {i} must be a [row, col] pair, got {pair!r}")
        m, n = pair
        if not (0 <= m < rows and 0 <= n < cols):
            raise _fail(where, "dead", f"entry {i} {pair!r} lies outside the {rows}x{cols} array")
        out.append((m, n))
    if len(set(out)) > rows * cols - 9:
        raise _fail(where, "dead", "leaves fewer than 9 live tactels")
    return tuple(sorted(set(out)))


def parse_description(doc: dict[str, Any], where: str = "sensor description",
                      sources: tuple[str, ...] = ()) -> SensorDescription:
    """A validated description from a parsed TOML table; ``ConfigError`` naming the key."""
    if not isinstance(doc, dict):
        raise ConfigError(f"{where}: must be a TOML table")
    unknown = sorted(set(doc) - _KNOWN)
    if unknown:
        raise _fail(where, unknown[0], f"is not a description key (known: {', '.join(sorted(_KNOWN))})")
    for key in _REQUIRED:
        if key not in doc:
            raise _fail(where, key, "is missing")
    name = doc["name"]
    if not isinstance(name, str) or not name or len(name) > 64 or not all(
            c.isalnum() or c in "_.-" for c in name):
        raise _fail(where, "name", f"must be 1-64 letters, digits, '_', '.' or '-', got {name!r}")
    rows, cols = _side(doc, "rows", where), _side(doc, "cols", where)
    if rows * cols > MAX_TACTELS:
        raise _fail(where, "cols", f"{rows}x{cols} is more than {MAX_TACTELS} tactels")
    nums = {k: _number(doc, k, where, getattr(SensorDescription, k, None))
            for k in ("pitch_x_mm", "pitch_y_mm", "depth_x_mm", "nu_x", "depth_y_mm", "nu_y",
                      "modulus_n_mm2", "cover_poisson", "noise_sigma")}
    radius = _number(doc, "surface_radius_mm", where, math.inf)
    text = doc.get("description", "")
    if not isinstance(text, str):
        raise _fail(where, "description", "must be a string")
    nominal = doc.get("nominal", [])
    if not isinstance(nominal, list) or not all(isinstance(k, str) and k in _KNOWN for k in nominal):
        raise _fail(where, "nominal", "must be a list of description keys")
    window = doc.get("window", 4)
    if isinstance(window, bool) or not isinstance(window, int) or not 2 <= window <= 64:
        raise _fail(where, "window", f"must be a window side of 2..64 tactels, got {window!r}")
    return SensorDescription(
        **_three_axis(doc, where),
        name=name, rows=rows, cols=cols, surface_radius_mm=radius, window=window,
        wire_order=_wire_order(doc.get("wire_order", "row-major"), rows * cols, where),
        dead=_dead(doc.get("dead", []), rows, cols, where),
        description=text, nominal=tuple(nominal), sources=sources, **nums,
    )


def _three_axis(doc: dict[str, Any], where: str) -> dict[str, Any]:
    """The ``axes`` key and, for a 3-axis array, what its taxels measure (validated)."""
    axes = doc.get("axes", 1)
    if isinstance(axes, bool) or axes not in (1, 3):
        raise _fail(where, "axes", f"must be 1 or 3 (readings per taxel), got {axes!r}")
    if axes == 1:
        given = [k for k in THREE_AXIS_KEYS if k in doc]
        if given:
            raise _fail(where, given[0], "belongs to a 3-axis array (axes = 3)")
        return {}
    out: dict[str, Any] = {"axes": 3, "taxel_depth_mm": _number(doc, "taxel_depth_mm", where)}
    for key in ("axis_gain", "axis_noise"):
        value = doc.get(key)
        if (not isinstance(value, list) or len(value) != 3
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
            raise _fail(where, key, f"must be three numbers (x, y, z), got {value!r}")
        lo, hi = RANGES[key]
        if not all(math.isfinite(v) and lo <= v <= hi for v in value):
            raise _fail(where, key, f"each value must lie in {lo:g}..{hi:g}, got {value!r}")
        out[key] = tuple(float(v) for v in value)
    return out


def _comments(text: str) -> tuple[str, ...]:
    """The leading comment block of a TOML text (a built-in's sources)."""
    out = []
    for line in text.splitlines():
        if not line.startswith("#"):
            break
        out.append(line[1:].strip())
    return tuple(out)


def parse_description_text(text: str, where: str) -> SensorDescription:
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{where}: not valid TOML ({err})") from None
    return parse_description(doc, where, _comments(text))


def builtin_names() -> list[str]:
    """The names of the built-in descriptions, sorted."""
    root = resources.files("tactiled.sensors") / "builtin"
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".toml"))


def builtin_text(name: str) -> str:
    """The TOML text of built-in ``name`` (``ConfigError`` listing the names when unknown)."""
    if name not in builtin_names():
        raise ConfigError(f"no built-in sensor description {name!r} (built-in: {', '.join(builtin_names())}; "
                          "or give the path of a .toml file)")
    return (resources.files("tactiled.sensors") / "builtin" / f"{name}.toml").read_text(encoding="utf-8")


def load_description(spec: str | Path | None = None) -> SensorDescription:
    """The description at path ``spec``, or the built-in named ``spec`` (default
    :data:`DEFAULT_NAME`, the paper's finger).  A name without a path separator or ``.toml``
    suffix is a built-in's."""
    if spec is None:
        spec = DEFAULT_NAME
    text_spec = str(spec)
    looks_like_path = isinstance(spec, Path) or text_spec.endswith(".toml") or "/" in text_spec
    if not looks_like_path:
        return parse_description_text(builtin_text(text_spec), f"built-in sensor {text_spec!r}")
    from tactiled.io.files import read_text

    path = Path(text_spec)
    return parse_description_text(read_text(path, "sensor description (TOML)", ConfigError), str(path))


def default_description() -> SensorDescription:
    """The paper's finger (built-in :data:`DEFAULT_NAME`)."""
    return load_description(DEFAULT_NAME)

"""The tactile arrays the vendor drivers read, and how their counts read as strain.

A vendor driver (``lines://``, ``flexitac://``, ``robotiq://``, ``xela://``, ``paxini://``)
delivers raw counts in its array's own shape.  :func:`device_model` says which built-in
description each kind of device has; :class:`DeviceArray` adds the nominal linear table its
counts go through until a calibration file says otherwise.
"""

# What an array is (shape, pitch, surface, cover) is the sensor's description (``tactiled/sensors``,
# docs/howto/sensors.md).  The simulated devices (``tactiled simulate --as KIND``) render their
# frames from the same :class:`DeviceArray`, so a daemon on a simulated device reads its counts
# back as the simulator's strain.

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from tactiled.calibration.lut import LookupTable
from tactiled.sensors.model import SensorModel
from tactiled.sensors import load_description

if TYPE_CHECKING:
    from tactiled.sources import SourceURL

#: The kinds of device with a driver and a simulated device.
KINDS = ("lines", "flexitac", "robotiq", "xela", "paxini")

#: kind -> the built-in description of its array (a 4x6 XELA sensor: ``xela_uskin_4x6``).
DESCRIPTIONS: dict[str, str] = {
    "lines": "fearing1988",
    "flexitac": "flexitac_12x32",
    "robotiq": "robotiq_tsf85",
    "xela": "xela_uskin_4x4",
    "paxini": "paxini_px6ax",
}
_XELA_BY_SHAPE = {(4, 4): "xela_uskin_4x4", (4, 6): "xela_uskin_4x6"}

#: Counts per unit strain and counts at zero strain of the nominal table.  The 16-bit devices
#: use :meth:`LookupTable.linear`'s defaults (the simulator's own); FlexiTac sends 8 bits
#: (10-bit ADC >> 2), so 2000 counts per strain and a zero of 20 counts span strain -0.01 to
#: 0.117, the simulator's presses on its thin cover without clipping.
_COUNTS: dict[str, tuple[float, float]] = {
    "lines": (20000.0, 10000.0),
    "flexitac": (2000.0, 20.0),
    "robotiq": (20000.0, 10000.0),
    "xela": (20000.0, 10000.0),
    # PaXini: z in 0.1 N steps of 0..255, offset by 0x8000 (tactiled_drivers.paxini): 5000
    # counts per strain span a strain of 0.05, the simulator's presses on its cover
    "paxini": (5000.0, 32768.0),
}


@dataclass(frozen=True)
class DeviceArray:
    """One device's array: its :class:`SensorModel` and its nominal counts -> strain scaling."""

    kind: str
    model: SensorModel
    counts_per_strain: float
    zero_counts: float
    #: the built-in description of this array; None when the URL's rows/cols make it another
    #: array (which then needs a description of its own: docs/howto/sensors.md)
    description: str | None = None

    @property
    def shape(self) -> tuple[int, int]:
        g = self.model.geometry
        return (g.rows, g.cols)

    def nominal_table(self, sensor_id: int = 0) -> LookupTable:
        """The linear table ``strain = (counts - zero_counts) / counts_per_strain``."""
        rows, cols = self.shape
        return LookupTable.linear(rows, cols, self.counts_per_strain, self.zero_counts,
                                  sensor_id=sensor_id)


def description_name(kind: str, rows: int | None = None, cols: int | None = None) -> str:
    """The built-in description of a ``kind`` device (of ``rows`` x ``cols`` for XELA)."""
    if kind not in DESCRIPTIONS:
        raise ValueError(f"unknown device kind {kind!r}; known: {', '.join(KINDS)}")
    if kind == "xela" and rows and cols:
        return _XELA_BY_SHAPE.get((rows, cols), DESCRIPTIONS[kind])
    return DESCRIPTIONS[kind]


def device_model(kind: str, rows: int | None = None, cols: int | None = None) -> SensorModel:
    """The :class:`SensorModel` of a ``kind`` device: its built-in description's, with
    ``rows``/``cols`` (the arrays whose size the URL gives) replacing its shape."""
    model = load_description(description_name(kind, rows, cols)).sensor_model()
    g = model.geometry
    if (rows or g.rows, cols or g.cols) != (g.rows, g.cols):
        model = replace(model, geometry=replace(g, rows=rows or g.rows, cols=cols or g.cols))
    return model


def device_description(kind: str, rows: int | None = None, cols: int | None = None) -> str | None:
    """The built-in description of a ``kind`` device's array, or None when ``rows`` x
    ``cols`` make it another array (which then needs a description of its own)."""
    name = description_name(kind, rows, cols)
    g = load_description(name).geometry()
    return name if (rows or g.rows, cols or g.cols) == (g.rows, g.cols) else None


def url_description(url: SourceURL) -> str | None:
    """:func:`device_description` of the device a source URL names (its scheme is the kind,
    ``rows=``/``cols=`` its size), read from the URL alone, so the configuration finds it
    without building the driver; None for a scheme that is no vendor device (``sim``,
    ``replay``...) or a size that is not a whole number."""
    if url.scheme not in DESCRIPTIONS:
        return None
    size: list[int | None] = []
    for key in ("rows", "cols"):
        raw = url.params.get(key) if url.scheme != "robotiq" else None  # robotiq: fixed 7x4
        try:
            size.append(int(raw, 10) if raw else None)
        except ValueError:
            return None  # refused when the source is built
    return device_description(url.scheme, size[0], size[1])


def device_array(kind: str, rows: int | None = None, cols: int | None = None) -> DeviceArray:
    """The :class:`DeviceArray` of a ``kind`` device (see :func:`device_model`)."""
    cps, zero = _COUNTS[kind] if kind in _COUNTS else (0.0, 0.0)
    return DeviceArray(kind, device_model(kind, rows, cols), cps, zero,
                       device_description(kind, rows, cols))

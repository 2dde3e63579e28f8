"""The tactile arrays the vendor drivers read, as the physics and the calibration see them.

A vendor driver (``lines://``, ``flexitac://``, ``robotiq://``, ``xela://``) delivers raw counts
in its array's own shape; what those counts mean is the sensor's description.  Until a
description is given, :func:`device_array` is the one place that says, per kind of device, the
array's shape and tactel pitch (mm), the cover (the paper's rubber) and how the nominal linear
table reads counts as strain.  The simulated devices (``tactiled simulate --as KIND``) render
their frames from the same :class:`DeviceArray`, so a daemon on a simulated device reads its
counts back as the simulator's strain.

Pitches marked *nominal* are placeholders, not vendor figures: a real device needs its
description (or ``tactiled calibrate --identify``) before its contact geometry is trusted.
"""

from __future__ import annotations

from dataclasses import dataclass

from tactiled.calibration.lut import LookupTable
from tactiled.config import Geometry, SensorModel

#: The kinds of device with a driver and a simulated device.
KINDS = ("lines", "flexitac", "robotiq", "xela")

# kind -> (rows, cols, dx mm, dy mm).  Shapes: lines, the paper's 8x8 by default; FlexiTac 12x32
# (flexitac/firmware/template.ino: ROW_COUNT 12, COLUMN_COUNT 32); Robotiq TSF-85 7x4
# (tactile_sensors sdk_cpp/finger_data.h: FINGER_STATIC_TACTILE_ROW 7, _COL 4); XELA uSkin
# XR1944 4x4.  Pitches: lines, the paper's; XELA 4.7 mm; FlexiTac and Robotiq nominal.
_LAYOUT: dict[str, tuple[int, int, float, float]] = {
    "lines": (8, 8, 3.3, 3.9),
    "flexitac": (12, 32, 3.0, 3.0),
    "robotiq": (7, 4, 4.0, 4.0),
    "xela": (4, 4, 4.7, 4.7),
}

#: Counts per unit strain and counts at zero strain of the nominal table.  The 16-bit devices
#: use :meth:`LookupTable.linear`'s defaults (the simulator's own); FlexiTac sends 8 bits
#: (10-bit ADC >> 2), so 4000 counts per strain and a zero of 20 counts span strain -0.005 to
#: 0.059, the simulator's presses (peak ~0.045) without clipping.
_COUNTS: dict[str, tuple[float, float]] = {
    "lines": (20000.0, 10000.0),
    "flexitac": (4000.0, 20.0),
    "robotiq": (20000.0, 10000.0),
    "xela": (20000.0, 10000.0),
}


@dataclass(frozen=True)
class DeviceArray:
    """One device's array: its :class:`SensorModel` and its nominal counts -> strain scaling."""

    kind: str
    model: SensorModel
    counts_per_strain: float
    zero_counts: float

    @property
    def shape(self) -> tuple[int, int]:
        g = self.model.geometry
        return (g.rows, g.cols)

    def nominal_table(self, sensor_id: int = 0) -> LookupTable:
        """The linear table ``strain = (counts - zero_counts) / counts_per_strain``."""
        rows, cols = self.shape
        return LookupTable.linear(rows, cols, self.counts_per_strain, self.zero_counts,
                                  sensor_id=sensor_id)


def device_model(kind: str, rows: int | None = None, cols: int | None = None) -> SensorModel:
    """The :class:`SensorModel` of a ``kind`` device (``rows``/``cols`` override its shape,
    for the arrays whose size the URL gives); ``ValueError`` for an unknown kind."""
    if kind not in _LAYOUT:
        raise ValueError(f"unknown device kind {kind!r}; known: {', '.join(KINDS)}")
    r, c, dx, dy = _LAYOUT[kind]
    return SensorModel(geometry=Geometry(rows=rows or r, cols=cols or c, dx=dx, dy=dy))


def device_array(kind: str, rows: int | None = None, cols: int | None = None) -> DeviceArray:
    """The :class:`DeviceArray` of a ``kind`` device (see :func:`device_model`)."""
    cps, zero = _COUNTS[kind] if kind in _COUNTS else (0.0, 0.0)
    return DeviceArray(kind, device_model(kind, rows, cols), cps, zero)

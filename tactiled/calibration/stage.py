"""The calibration stage of the pipeline: raw frame -> linearised, zeroed strain + contact flag.

``Frame(raw) -> LookupTable.to_strain -> Zeroer.update (ContactDetector inside) -> frame.strain``,
one call per frame, no I/O.  Times come from the device clock (``device_time_us``), so the zeroing
time constants hold whatever the host's scheduling jitter.
"""

from __future__ import annotations

from tactiled.calibration.lut import LookupTable
from tactiled.calibration.zeroing import Zeroer
from tactiled.errors import CalibrationError
from tactiled.frames import Frame


class CalibrationStage:
    """Applies one sensor's table and zeroing to its frames.

    A frame from another sensor (``frame.sensor_id != table.sensor_id``) raises
    :class:`CalibrationError`: a table applied to the wrong sensor gives plausible-looking
    nonsense, so it must not pass silently.
    """

    def __init__(self, table: LookupTable, zeroer: Zeroer | None = None) -> None:
        self.table = table
        self.zeroer = Zeroer(table.shape) if zeroer is None else zeroer
        if self.zeroer.shape != table.shape:
            raise ValueError(f"zeroer shape {self.zeroer.shape} != table shape {table.shape}")

    def process(self, frame: Frame) -> bool:
        """Fill ``frame.strain`` (zeroed, float64) and return whether a contact is present."""
        if frame.sensor_id != self.table.sensor_id:
            raise CalibrationError(
                f"frame from sensor {frame.sensor_id}, but the calibration is for sensor "
                f"{self.table.sensor_id}"
            )
        strain = self.table.to_strain(frame.raw)
        frame.strain = self.zeroer.update(strain, frame.device_time_us * 1e-6)
        return self.zeroer.in_contact

    @property
    def in_contact(self) -> bool:
        return self.zeroer.in_contact

    def tare(self) -> None:
        """Re-zero on the next frame."""
        self.zeroer.tare()

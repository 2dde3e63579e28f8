"""Frames: one reading of the tactel array, and (below) the wire-format codec.

No I/O here: the decoder is fed bytes and returns frames, so it is trivially testable and
fuzzable.  The wire format is documented in ``docs/protocol.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Frame:
    """One reading of the array.

    ``raw`` holds the tactel counts as ``uint16`` of shape ``(rows, cols)``; ``strain`` is filled
    in by calibration (linearised, zeroed, positive under compression) and is ``None`` before.
    ``device_time_us`` is the sensor's own clock in microseconds; ``host_time`` is
    ``time.monotonic()`` seconds when the host finished receiving the frame.
    """

    seq: int
    device_time_us: int
    raw: np.ndarray
    sensor_id: int = 0
    host_time: float = 0.0
    strain: np.ndarray | None = field(default=None, repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.raw.shape[0]), int(self.raw.shape[1]))

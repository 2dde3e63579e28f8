"""A 3-axis array's counts as a device streams them: a tangential scene
(:func:`tactiled.sim.shear.sequence`) looped, each loop some frames at rest first.  Used by
``tactiled simulate --pty`` and ``sim://`` on a 3-axis description and by the simulated XELA
server (``tactiled simulate --as xela --scene pull``).
"""

# Counts are the description's readings (docs/concepts/shear.md) about a zero: x and y about
# the middle of 16 bits (signed readings, as XELA's magnets read), z about 10000, the zero of
# the simulator's counts -> strain table (tactiled.calibration.lut.LookupTable.linear, which
# XELA's nominal table shares), so the 1-axis path reads the z counts as it reads a
# simulated 1-axis array's.

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tactiled.frames import Frame
from tactiled.physics.threeaxis import ThreeAxisModel
from tactiled.sensors.description import SensorDescription
from tactiled.sim.shear import SEQUENCES, sequence

#: x and y counts at rest: the middle of 16 bits.
REST_XY = 0x8000
#: z counts at rest: LookupTable.linear's zero-load counts.
REST_Z = 10000.0
#: Frames at rest before each scene (the daemon learns the readings' zero from them).
REST_FRAMES = 300


@dataclass
class TaxelScenes:
    """Counts ``(rows, cols, 3)`` uint16 of ``kind`` (push, twist or pull) on ``desc`` at
    ``rate_hz``, looped with a new sphere each time (a pass: ``rest_frames`` at rest, then the
    scene); :meth:`resting`: a frame at rest; :meth:`next_frame`: the next as a
    :class:`~tactiled.frames.Frame` of ``sensor_id`` (seq from 0, the device clock at
    ``rate_hz``), as :class:`~tactiled.sim.FingerSimulator` gives them."""

    desc: SensorDescription
    kind: str
    seed: int = 0
    rate_hz: float = 1000.0
    rest_frames: int = REST_FRAMES
    sensor_id: int = 0
    rng: np.random.Generator = field(init=False, repr=False)
    _queue: list[np.ndarray] = field(init=False, default_factory=list, repr=False)

    def __post_init__(self) -> None:
        if self.desc.axes != 3:
            raise ValueError(f"sensor {self.desc.name!r} is 1-axis: a tangential scene needs a "
                             "3-axis description (axes = 3)")
        if self.kind not in SEQUENCES:
            raise ValueError(f"no tangential scene {self.kind!r} (scenes: {', '.join(SEQUENCES)})")
        self.rng = np.random.default_rng(self.seed)
        self.noise = ThreeAxisModel(self.desc).noise
        self.shape = (self.desc.rows, self.desc.cols, 3)
        self.zero = np.array([REST_XY, REST_XY, REST_Z])
        self.next_index = 0  # frames given so far
        self._refill()
        #: frames in one pass (rest and scene; the same for every pass)
        self.ticks_per_pass = len(self._queue)

    def _refill(self) -> None:
        rest = [self.rng.normal(size=self.shape) * self.noise for _ in range(self.rest_frames)]
        frames, _ = sequence(self.desc, self.kind, self.rng, rate_hz=self.rate_hz)
        self._queue = [*rest, *frames]
        self._queue.reverse()

    def _counts(self, readings: np.ndarray) -> np.ndarray:
        return np.clip(np.round(readings + self.zero), 0, 0xFFFF).astype(np.uint16)

    def resting(self) -> np.ndarray:
        """One frame of the array at rest: its noise about the zero."""
        return self._counts(self.rng.normal(size=self.shape) * self.noise)

    def next_readings(self) -> np.ndarray:
        """The next frame's readings about zero, float ``(rows, cols, 3)`` (the description's
        readings: a device whose counts are signed, as PaXini's, sends these)."""
        if not self._queue:
            self._refill()
        self.next_index += 1
        return self._queue.pop()

    def next_counts(self) -> np.ndarray:
        """The next frame's counts."""
        return self._counts(self.next_readings())

    def next_frame(self) -> Frame:
        """The next frame: ``taxels`` the counts, ``raw`` their z (what the 1-axis path reads)."""
        k = self.next_index
        counts = self.next_counts()
        return Frame(seq=k % (1 << 32), device_time_us=round(k * 1e6 / self.rate_hz),
                     raw=counts[..., 2].copy(), sensor_id=self.sensor_id, taxels=counts)

    def skip(self, n: int) -> None:
        """Drop the next ``n`` frames (a device behind schedule loses them)."""
        for _ in range(n):
            self.next_counts()

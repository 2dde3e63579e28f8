"""The simulated finger: ``sim://?seed=3&scene=demo&rate=1000&sensor_id=0&loop=1``.

A :class:`~tactiled.sim.FingerSimulator` plays a scripted scene; every frame is encoded with
:func:`~tactiled.frames.encode_frame` and handed over as wire bytes, so the shared decoder (and
everything after it) runs exactly as for the hardware.  Frames are paced on the event loop's
clock; a starved loop skips stale frames as a real device would lose them.
"""
# URL parameters (all optional):
# - sensor: the simulated array, a description's built-in name or .toml path (default
#   fearing1988, the paper's finger; docs/howto/sensors.md); its cover unless changed below;
# - scene: a built-in scene name (default demo; see tactiled.sim.SCENES); on a 3-axis sensor
#   also push, twist or pull (tactiled.sim.taxel_stream: x, y, z per taxel, version-2 frames;
#   noise, drift, hysteresis and the finger's parameters do not apply);
# - seed: integer seed of the noise and drift (default 0): the same seed gives the same bytes;
# - rate: frames per second of device time, Hz (default 1000);
# - sensor_id: the id the frames carry, 0..65535 (default 0);
# - loop: 1 (default) plays the scene over and over; 0 plays it once, then the stream ends;
# - speed: pace multiplier (default 1: real time; 2: twice as fast; 0: as fast as possible,
#   yielding to the event loop between reads);
# - noise: Gaussian strain noise sigma (default 0.0005; 0 for none);
# - drift: peak of the slow baseline drift wave, strain (default 0.002; 0 turns drift off);
# - hysteresis: fraction of a released strain the rubber keeps, decaying with tau 0.5 s
#   (default 0.05; 0 for none);
# - a finger that is not the paper's (tactiled.sensors.finger.FingerSpec): depth_x, nu_x,
#   depth_y, nu_y (impulse response, mm), modulus (N/mm^2), gain_error (relative sd of tactel
#   gains), position_error (sd of tactel displacements, mm), offset_counts (half-width of the
#   tactels' zero offsets, counts) and finger_seed.
# Pacing: frame k is due at start + k / (rate * speed) on the loop's clock, start the first
# read, so the stream never drifts; each read returns every frame already due (up to
# MAX_BATCH, ~1 ms of work, and yields to the loop at least once), or sleeps until the next is
# due.  Fallen more than MAX_LAG_S behind, the stale frames are skipped: seq jumps, the decoder
# counts them in stats.lost, and SimSource.frames_skipped counts them too.

from __future__ import annotations

import asyncio
import logging
from typing import ClassVar

from tactiled.sensors.finger import FingerSpec
from tactiled.sensors import DEFAULT_NAME, load_description
from tactiled.frames import encode_frame
from tactiled.sim import (
    DEFAULT_DRIFT,
    DEFAULT_HYSTERESIS,
    DriftModel,
    FingerSimulator,
    FrameSchedule,
    HysteresisModel,
    scene_from_spec,
)
from tactiled.sim.shear import SEQUENCES
from tactiled.sim.taxel_stream import TaxelScenes
from tactiled.sources import FrameSource, Framer, SourceURL
from tactiled_drivers.plumbing.futures import Pause

log = logging.getLogger(__name__)

MAX_BATCH = 8  # frames rendered per read: ~0.1 ms each, so a read holds the loop <~1 ms
MAX_LAG_S = 1.0  # seconds behind schedule beyond which stale frames are skipped


class SimSource(FrameSource):
    """Wire bytes of a simulated fingertip playing a scene (see the module docstring)."""

    PARAMS: ClassVar[frozenset[str]] = frozenset(
        {"seed", "scene", "rate", "sensor_id", "loop", "speed", "noise", "drift", "hysteresis",
         "sensor", *FingerSpec.PARAMS})

    def __init__(self, url: str | SourceURL, *, decoder: Framer | None = None) -> None:
        super().__init__(url, decoder=decoder)
        u = self.url
        self.seed: int = u.get_int("seed", 0, minimum=0)
        self.rate: float = u.get_float("rate", 1000.0, minimum=0.1, maximum=100_000.0)
        self.sensor_id: int = u.get_int("sensor_id", 0, minimum=0, maximum=0xFFFF)
        self.loop: bool = u.get_bool("loop", True)
        self.speed: float = u.get_float("speed", 1.0, minimum=0.0)
        noise = u.get_float("noise", 0.0, minimum=0.0) if "noise" in u.params else None
        drift = u.get_float("drift", DEFAULT_DRIFT.amplitude, minimum=0.0)
        fraction = u.get_float("hysteresis", DEFAULT_HYSTERESIS.fraction, minimum=0.0, maximum=1.0)
        try:
            #: the simulated array (a sensor description: built-in name or .toml path)
            self.description = load_description(u.get_str("sensor", DEFAULT_NAME))
            self.simulator = self._simulator(noise, drift, fraction)
        except ValueError as err:
            raise ValueError(f"{u.url!r}: {err}") from None
        self.frames_sent = 0
        self.frames_skipped = 0
        self._schedule: FrameSchedule | None = None
        self._pause = Pause()

    def _simulator(self, noise: float | None, drift: float,
                   fraction: float) -> FingerSimulator | TaxelScenes:
        """The scene's player: a 3-axis array's tangential scene, or the finger simulator."""
        u = self.url
        name = u.get_str("scene", "demo")
        if name in SEQUENCES:
            return TaxelScenes(self.description, name, self.seed, self.rate,
                               sensor_id=self.sensor_id)
        base = self.description.sensor_model()
        return FingerSimulator(
            sensor=base,
            scene=scene_from_spec(name, base.geometry),
            seed=self.seed,
            rate_hz=self.rate,
            noise=noise,
            drift=DriftModel(amplitude=drift) if drift > 0 else None,
            hysteresis=HysteresisModel(fraction=fraction) if fraction > 0 else None,
            sensor_id=self.sensor_id,
            loop=self.loop,
            finger=FingerSpec.from_params(u.params, base),
        )

    def sent_id(self) -> int:
        return self.sensor_id

    async def _open_internal(self) -> None:
        self._schedule = None  # the device starts on the first read

    async def _close_internal(self) -> None:
        self._pause.wake()  # a paced read may be waiting for its next frame

    async def _read_internal(self) -> bytes:
        loop = asyncio.get_running_loop()
        yielded = False
        while self.is_open:
            limit = self._batch_limit()
            if limit == 0:
                log.info("%s: scene played once (%d frames sent); end of stream",
                         self.url.url, self.frames_sent)
                self.connected = False
                return b""
            if self.speed == 0:
                await asyncio.sleep(0)  # as fast as possible, but let other tasks run
                if not self.is_open:
                    break
                return self._render(limit)
            if self._schedule is None:
                self._schedule = FrameSchedule(self.rate * self.speed, loop.time(), MAX_LAG_S)
            now = loop.time()
            if self._schedule.due(now) == 0:
                await self._pause(self._schedule.next_due() - now)
                yielded = True
                continue
            if not yielded:
                # Behind schedule (frames already due): still let other tasks run between
                # batches, or a source that cannot keep up would starve the whole loop.
                await asyncio.sleep(0)
                yielded = True
                continue
            # Nothing is awaited from here to the return: a cancelled read loses no frame.
            skip, send = self._schedule.take(now, limit)
            if skip:
                self._skip(skip)
            send = min(send, self._batch_limit())  # a skip may have run past a single pass
            if send:
                return self._render(send)
        return b""

    def _batch_limit(self) -> int:
        """Frames one read may render: MAX_BATCH, or fewer near the end of a single pass."""
        if self.loop:
            return MAX_BATCH
        return max(0, min(MAX_BATCH, self.simulator.ticks_per_pass - self.simulator.next_index))

    def _render(self, n: int) -> bytes:
        sim = self.simulator
        data = b"".join([encode_frame(sim.next_frame()) for _ in range(n)])
        self.frames_sent += n
        return data

    def _skip(self, n: int) -> None:
        self.simulator.skip(n)
        self.frames_skipped += n
        self.last_error = f"simulator fell behind schedule: skipped {self.frames_skipped} frame(s)"
        log.warning("%s: %d frame(s) behind schedule, skipped (seq gap)", self.url.url, n)


"""The simulated finger: a :class:`FingerSimulator` turns a scene, tick by tick, into what the
hardware would send: the true contact, the strain the tactels feel (physics + slow baseline
drift + rubber hysteresis + Gaussian noise) and the raw ``uint16`` counts through a
calibration table's inverse, packed in a :class:`~tactiled.frames.Frame`.
``docs/concepts/simulator.md`` documents the model and its numbers.  :class:`FrameSchedule`
paces a frame stream in real time.

Units: mm, N, seconds; strain is dimensionless and positive under compression.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from tactiled.calibration.lut import LookupTable
from tactiled.frames import Frame
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
from tactiled.sensors.finger import COUNTS_PER_STRAIN, ZERO_STRAIN_COUNTS, FingerSpec
from tactiled.sensors.model import SensorModel
from tactiled.sim.frames import as_line
from tactiled.sim.scenes import AnyScene, MultiScene, named_scene

@dataclass(frozen=True)
class DriftModel:
    """Slow baseline drift of each tactel's zero (temperature, rubber creep), in strain.

    ``drift[k](t) = amplitude * g[k] * sin(2 pi t / period_s) + w[k](t)``

    * a common slow wave (temperature) of peak ``amplitude`` = 0.002 strain and period
      ``period_s`` = 300 s, scaled per tactel by ``g[k]`` drawn uniformly from [0.5, 1]
      (tactels do not drift identically);
    * ``w[k]``: an independent random walk per tactel, pulled back to zero with time constant
      ``walk_tau_s`` = 60 s (Ornstein-Uhlenbeck), of long-run standard deviation
      ``walk_sigma`` = 0.0003 strain.

    Both parts start at 0 at ``t = 0``, so ``|drift| <= amplitude + ~4 walk_sigma`` (0.0032).
    The fastest change, ``2 pi amplitude / period_s`` ~ 4e-5 strain/s, is what a zeroer must
    follow while idle.
    """

    amplitude: float = 0.002
    period_s: float = 300.0
    walk_sigma: float = 0.0003
    walk_tau_s: float = 60.0

    def __post_init__(self) -> None:
        for name in ("amplitude", "walk_sigma"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ValueError(f"{name} must be a finite non-negative strain, got {getattr(self, name)!r}")
        for name in ("period_s", "walk_tau_s"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"{name} must be a positive time in s, got {getattr(self, name)!r}")


@dataclass(frozen=True)
class HysteresisModel:
    """The rubber's memory of compression: it springs back a little late after unloading.

    Each tactel keeps a peak-hold ``P`` of its (compressive) physics strain ``s+ = max(s, 0)``
    that decays with time constant ``tau_s``: ``P = max(s+, P * exp(-dt / tau_s))``.  The residual
    added to the strain is ``fraction * (P - s+)``: 0 while loading or holding, and after a
    release from strain ``s_r`` it is ``fraction * s_r * exp(-t / tau_s)``: by default 5 % of the
    released strain, decaying with ``tau_s`` = 0.5 s (gone to 1 % of that within 2.3 s).
    """

    fraction: float = 0.05
    tau_s: float = 0.5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.fraction) and 0 <= self.fraction <= 1):
            raise ValueError(f"fraction must lie in [0, 1], got {self.fraction!r}")
        if not (math.isfinite(self.tau_s) and self.tau_s > 0):
            raise ValueError(f"tau_s must be a positive time in s, got {self.tau_s!r}")


DEFAULT_DRIFT = DriftModel()
DEFAULT_HYSTERESIS = HysteresisModel()
#: Drift is a process of minutes: between updates 10 ms apart it moves by ~5e-6 strain (a tenth
#: of a count), so recomputing it every tick would be work for nothing.
DRIFT_UPDATE_S = 0.01
#: A hysteresis residual below this (strain; 1/50 count) counts as gone.
SETTLED_RESIDUAL = 1e-6


@dataclass(slots=True)
class Tick:
    """One reading of the simulated finger, with everything that went into it.

    ``physics``: the noise-free strain of :attr:`contact` from ``StrainModel.predict`` (a
    cached read-only array, zeros without contact); ``drift``, ``residual`` (hysteresis),
    ``strain`` (their sum plus Gaussian noise: what the tactels feel) and ``counts`` (``uint16``
    through the calibration's inverse) are ``(rows, cols)`` arrays.
    """

    index: int  # tick number, from 0
    time_s: float  # device time, s (index / rate_hz)
    scene_time_s: float  # time into the scene, s (wraps when looping)
    contact: Contact | None
    physics: np.ndarray = field(repr=False)
    drift: np.ndarray = field(repr=False)
    residual: np.ndarray = field(repr=False)
    strain: np.ndarray = field(repr=False)
    counts: np.ndarray = field(repr=False)
    sensor_id: int = 0
    device_time_us: int = 0
    #: every contact touching (a :class:`MultiScene`'s truth, in track order); ``contact`` is
    #: the one of the largest force
    contacts: tuple[Contact, ...] = ()

    @property
    def seq(self) -> int:
        """Frame sequence number: the tick index wrapped to uint32."""
        return self.index & 0xFFFFFFFF

    def frame(self) -> Frame:
        """The frame the device sends for this tick (raw counts only; host time unset)."""
        return Frame(seq=self.seq, device_time_us=self.device_time_us, raw=self.counts,
                     sensor_id=self.sensor_id)


class FingerSimulator:
    """A simulated fingertip playing a scene at ``rate_hz`` ticks per second of device time.

    Per tick ``k`` (device time ``t = k / rate_hz`` s): the scene's true contact at ``t``
    (``t`` modulo the scene's duration when ``loop``), its noise-free strain, plus
    :class:`DriftModel` drift, plus :class:`HysteresisModel` residual, plus Gaussian noise of
    ``noise`` (strain sigma; default the sensor's ``noise.sigma``, 0.0005; 0 for none), turned
    into counts by ``calibration.to_counts`` (default: :meth:`LookupTable.linear` with
    :data:`COUNTS_PER_STRAIN` and :data:`ZERO_STRAIN_COUNTS`).  ``drift=None`` /
    ``hysteresis=None`` switch those off.

    Deterministic given ``seed``: noise, drift and the per-tactel drift gains use independent
    streams, so switching one off leaves the others' numbers unchanged.

    Cheap enough for 1 kHz per sensor on a shared machine (~50 us per tick while the contact is
    still, plus ~30 us per strain prediction while it moves): the strain model runs only when
    the contact changes (never during a hold or idle), the drift (a minutes-long process) is
    updated every :data:`DRIFT_UPDATE_S`, the hysteresis state is left alone once settled, and
    the default linear table is inverted with its closed form (identical to ``to_counts``).
    """

    def __init__(
        self,
        sensor: SensorModel | None = None,
        scene: AnyScene | str = "demo",
        seed: int = 0,
        rate_hz: float = 1000.0,
        noise: float | None = None,
        drift: DriftModel | None = DEFAULT_DRIFT,
        hysteresis: HysteresisModel | None = DEFAULT_HYSTERESIS,
        calibration: LookupTable | None = None,
        *,
        sensor_id: int = 0,
        loop: bool = True,
        finger: FingerSpec | None = None,
    ) -> None:
        if finger is not None and sensor is not None:
            # the finger's rubber and tactel positions, on the given sensor's array and noise
            sensor = finger.sensor(sensor.geometry, sensor.noise)
        elif finger is not None:
            sensor = finger.sensor()
        self.sensor = sensor or SensorModel()
        self.finger = finger or FingerSpec()
        g = self.sensor.geometry
        self.shape = (g.rows, g.cols)
        self.scene = named_scene(scene, g) if isinstance(scene, str) else scene
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be a positive rate in Hz, got {rate_hz!r}")
        self.rate_hz = float(rate_hz)
        self.noise = self.sensor.noise.sigma if noise is None else float(noise)
        if not (math.isfinite(self.noise) and self.noise >= 0):
            raise ValueError(f"noise must be a finite non-negative strain sigma, got {noise!r}")
        if not (isinstance(sensor_id, int) and 0 <= sensor_id <= 0xFFFF):
            raise ValueError(f"sensor_id must be an integer 0..65535, got {sensor_id!r}")
        self.sensor_id = sensor_id
        self.drift_model = drift
        self.hysteresis_model = None if hysteresis is None or hysteresis.fraction == 0 else hysteresis
        # The default table's inverse is affine: computed directly it costs ~5 us, not ~50.
        # A finger spec's tactels are affine too, with their own gains and offsets.
        self._affine = calibration is None
        if calibration is not None and finger is not None and not finger.is_paper:
            raise ValueError("give the tactels' response either as a calibration table or a finger spec, not both")
        self._cps = self.finger.counts_per_strain(g) if self._affine else None
        self._zero = self.finger.zero_counts(g) if self._affine else None
        self.calibration = calibration or LookupTable.linear(
            g.rows, g.cols, self._cps, self._zero, sensor_id=sensor_id)
        if self.calibration.shape != self.shape:
            raise ValueError(f"calibration shape {self.calibration.shape} != sensor shape {self.shape}")
        self.loop = loop
        self.seed = seed
        self.model = StrainModel(self.sensor)
        noise_seq, drift_seq, gain_seq = np.random.SeedSequence(seed).spawn(3)
        self._noise_rng = np.random.default_rng(noise_seq)
        self._drift_rng = np.random.default_rng(drift_seq)
        self._drift_gain = np.random.default_rng(gain_seq).uniform(0.5, 1.0, self.shape)
        self._zeros = np.zeros(self.shape)
        self._zeros.setflags(write=False)
        self._walk = np.zeros(self.shape)
        self._drift = self._zeros
        self._drift_time = -math.inf  # device time of the last drift update, s
        self._peak = np.zeros(self.shape)  # hysteresis peak-hold P
        self._settled = True  # P equals the current load: no residual until the load changes
        self._cached: tuple[Contact | None, np.ndarray] = (None, self._zeros)
        self._multi = isinstance(self.scene, MultiScene)
        #: a MultiScene's contacts and their summed strain, reused while none changes
        self._cached_sum: tuple[tuple[Contact, ...], np.ndarray] = ((), self._zeros)
        self._track_cache: dict[int, tuple[Contact, np.ndarray]] = {}
        self._last_phys = self._zeros
        self.next_index = 0
        """Index of the tick :meth:`step` produces next."""
        self._last_index: int | None = None
        self.predictions = 0
        """How many times the strain model ran (cache misses), for tests and benchmarks."""

    @property
    def ticks_per_pass(self) -> int:
        """Ticks in one pass through the scene (at least 1)."""
        return max(1, round(self.scene.duration * self.rate_hz))

    def scene_time(self, index: int) -> float:
        """Scene time in seconds of tick ``index``."""
        if self.loop:
            return (index % self.ticks_per_pass) / self.rate_hz
        return index / self.rate_hz

    def physics(self, contact: Contact | None) -> np.ndarray:
        """Noise-free strain of ``contact`` (read-only; the last prediction is reused while the
        contact stays the same).  On a flat array a cylinder is a rod longer than the array
        (:func:`as_line`)."""
        if contact is None:
            return self._zeros
        last, strain = self._cached
        if contact != last:
            strain = self.model.predict(as_line(contact, self.sensor.geometry))
            strain.setflags(write=False)
            self._cached = (contact, strain)
            self.predictions += 1
        return strain

    def physics_of(self, contacts: Sequence[Contact]) -> np.ndarray:
        """Noise-free strain of several contacts at once, the sum of each one's
        (:meth:`physics`; read-only, reused while none of them changes)."""
        key = tuple(contacts)
        if not key:
            return self._zeros
        if len(key) == 1:
            return self.physics(key[0])
        last, strain = self._cached_sum
        if key != last:
            strain = np.zeros(self.shape)
            for c in key:
                strain += self._track_physics(c)
            strain.setflags(write=False)
            self._cached_sum = (key, strain)
        return strain

    def _track_physics(self, contact: Contact) -> np.ndarray:
        """One contact's strain, from a cache of the last few (each track's contact repeats
        while it holds, whatever the others do)."""
        key = hash(contact)
        hit = self._track_cache.get(key)
        if hit is not None and hit[0] == contact:
            return hit[1]
        strain = self.model.predict(as_line(contact, self.sensor.geometry))
        self.predictions += 1
        if len(self._track_cache) > 16:
            self._track_cache.clear()
        self._track_cache[key] = (contact, strain)
        return strain

    def to_counts(self, strain: np.ndarray) -> np.ndarray:
        """Raw ``uint16`` counts the tactels report for ``strain`` (the calibration's inverse)."""
        if not self._affine:
            return self.calibration.to_counts(strain)
        c = strain * self._cps
        c += self._zero
        np.rint(c, out=c)
        np.maximum(c, 0.0, out=c)  # two ufuncs: np.clip's wrapper costs more than the work
        np.minimum(c, 65535.0, out=c)
        return c.astype(np.uint16)

    def skip(self, n: int) -> None:
        """Let ``n`` ticks pass unseen (a device whose frames were lost): no frames, seq jumps.
        Drift and hysteresis are integrated over the gap at the next :meth:`step`."""
        if n < 0:
            raise ValueError(f"cannot skip a negative number of ticks, got {n!r}")
        self.next_index += n

    def step(self) -> Tick:
        """Produce the next tick."""
        k = self.next_index
        dt = 0.0 if self._last_index is None else (k - self._last_index) / self.rate_hz
        self._last_index = k
        self.next_index = k + 1
        t = k / self.rate_hz
        t_scene = self.scene_time(k)
        if self._multi:
            contacts = tuple(self.scene.contacts_at(t_scene))
            contact = max(contacts, key=lambda c: c.force, default=None)
            phys = self.physics_of(contacts)
        else:
            contact = self.scene.contact_at(t_scene)
            contacts = () if contact is None else (contact,)
            phys = self.physics(contact)
        drift = self._update_drift(t)
        residual = self._update_hysteresis(phys, dt)
        strain = phys + drift
        if residual is not self._zeros:
            strain += residual
        if self.noise > 0:
            strain += self._noise_rng.normal(0.0, self.noise, self.shape)
        return Tick(k, t, t_scene, contact, phys, drift, residual, strain, self.to_counts(strain),
                    self.sensor_id, round(k * 1e6 / self.rate_hz), contacts)

    def next_frame(self) -> Frame:
        """The next tick as the frame the device sends."""
        return self.step().frame()

    def frames(self, n: int) -> list[Frame]:
        """The next ``n`` frames."""
        return [self.next_frame() for _ in range(n)]

    def _update_drift(self, t: float) -> np.ndarray:
        """Drift at device time ``t``, recomputed every ``DRIFT_UPDATE_S`` (read-only array)."""
        d = self.drift_model
        if d is None or t - self._drift_time < DRIFT_UPDATE_S:
            return self._drift if d is not None else self._zeros
        dt = t - self._drift_time if math.isfinite(self._drift_time) else 0.0
        self._drift_time = t
        if dt > 0 and d.walk_sigma > 0:
            # Exact Ornstein-Uhlenbeck update for any step: variance tends to walk_sigma^2.
            a = math.exp(-dt / d.walk_tau_s)
            self._walk *= a
            self._walk += (d.walk_sigma * math.sqrt(1.0 - a * a)) * self._drift_rng.standard_normal(self.shape)
        drift = (d.amplitude * math.sin(2.0 * math.pi * t / d.period_s)) * self._drift_gain
        drift += self._walk
        drift.setflags(write=False)
        self._drift = drift
        return drift

    def _update_hysteresis(self, phys: np.ndarray, dt: float) -> np.ndarray:
        """Residual strain of the rubber's memory (:class:`HysteresisModel`) for this tick."""
        h = self.hysteresis_model
        unchanged = phys is self._last_phys
        self._last_phys = phys
        if h is None or (self._settled and unchanged):
            return self._zeros
        loaded = np.maximum(phys, 0.0)  # only compression is remembered
        self._peak *= math.exp(-dt / h.tau_s)
        np.maximum(self._peak, loaded, out=self._peak)
        residual = h.fraction * (self._peak - loaded)
        if float(residual.max()) < SETTLED_RESIDUAL:
            # Below a fiftieth of a count: drop the memory so a still contact costs nothing.
            self._peak = loaded
            self._settled = True
            return self._zeros
        self._settled = False
        residual.setflags(write=False)
        return residual


# ============================================================================================
# Pacing a frame stream in real time
# ============================================================================================


class FrameSchedule:
    """Frame ``k`` of a stream is due at ``start + k / rate_hz`` seconds, whatever happened
    before, so the stream never drifts from its clock.

    :meth:`take` says how many frames to send now.  When the sender has fallen more than
    ``max_lag_s`` seconds behind (the process was starved or suspended), the stale frames are
    skipped (a seq gap, as a real device's overflowing buffer loses frames) instead of being
    sent in a burst of old data.
    """

    def __init__(self, rate_hz: float, start: float, max_lag_s: float = 1.0) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be a positive rate in Hz, got {rate_hz!r}")
        self.rate_hz = float(rate_hz)
        self.start = float(start)
        self.max_lag_frames = max(1, int(max_lag_s * rate_hz))
        self.sent = 0  # frames sent or skipped so far
        self.skipped = 0

    def due(self, now: float) -> int:
        """Frames due by ``now`` (seconds on the ``start`` clock) and not yet taken."""
        return max(0, math.floor((now - self.start) * self.rate_hz) + 1 - self.sent)

    def next_due(self) -> float:
        """Clock time at which the next frame is due."""
        return self.start + self.sent / self.rate_hz

    def take(self, now: float, limit: int) -> tuple[int, int]:
        """``(skip, send)``: frames to drop as lost and frames to send now (at most ``limit``),
        both counted as taken."""
        due = self.due(now)
        skip = due - 1 if due > self.max_lag_frames else 0
        send = min(due - skip, limit)
        self.sent += skip + send
        self.skipped += skip
        return skip, send

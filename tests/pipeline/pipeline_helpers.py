"""Helpers of the pipeline tests (a uniquely named module, so test modules can import it
whatever other conftest.py files pytest has loaded): physics-true frames, recordings, a frame
source fed by the test, leak checks, estimate checks, and a pool whose jobs this process
answers as a worker would (for driving one SensorPipeline synchronously)."""

from __future__ import annotations

import asyncio
import json
import math
import time
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from procs import PACE  # noqa: F401 - the pipeline tests import it from here

from tactiled.calibration.lut import LookupTable
from tactiled.frames import Frame
from tactiled.physics.contact import Contact
from tactiled.pipeline import Daemon
from tactiled.io.recording import Recorder
from tactiled.sim import simulate_frames
from tactiled.sources import FrameSource

#: Device clock period of test frames: 5 ms (200 Hz).  The zeroer learns its baseline during
#: the first 0.25 s, so every stream starts with SETTLE_FRAMES frames of no contact.
PERIOD_US = 5000
SETTLE_FRAMES = 60


def contact_path(n: int, *, force: float = 1.0, r1: float = 10.0, moving: bool = True,
                 psi: float = 90.0) -> list[Contact]:
    """``n`` contacts of a cylinder on the array, force ``force`` N: held at x = 9 mm, or,
    when ``moving``, rolling along x from there at 0.03 mm per frame (slowing, back and forth
    between 5 and 13 mm, so it never leaves the array)."""
    def x(k: int) -> float:
        return 9.0 + 4.0 * math.sin(0.0075 * k) if moving else 9.0

    return [Contact(r1, math.inf, psi, force, x(k), 13.0) for k in range(n)]


def make_frames(contacts: list[Contact | None], *, sensor_id: int = 0, seed: int = 0,
                start_seq: int = 0, settle: int = SETTLE_FRAMES, tail: int = 0,
                sigma: float = 0.0005) -> list[Frame]:
    """Wire frames (uint16 counts through the nominal linear table) of ``settle`` empty frames,
    then ``contacts`` (None = no contact), then ``tail`` empty frames; strain noise ``sigma``."""
    from tactiled.sensors.model import NoiseModel

    scene: list[Contact | None] = [None] * settle + list(contacts) + [None] * tail
    strain = simulate_frames(scene, noise=NoiseModel(sigma=sigma), seed=seed)
    counts = LookupTable.linear(sensor_id=sensor_id).to_counts(strain)
    return [Frame(seq=start_seq + k, device_time_us=(start_seq + k) * PERIOD_US, raw=c,
                  sensor_id=sensor_id) for k, c in enumerate(counts)]


def write_recording(path: Path, frames: list[Frame], period_s: float = PERIOD_US * 1e-6) -> Path:
    """A recording of ``frames`` paced ``period_s`` apart."""
    path.unlink(missing_ok=True)
    with Recorder(path, sensor_id=frames[0].sensor_id) as rec:
        for k, frame in enumerate(frames):
            rec.record(frame, host_time=100.0 + k * period_s)
    return path


class QueueSource(FrameSource):
    """A frame source fed by the test: ``put(frame)`` (stamped with the host time now),
    ``end()`` ends the stream.  Frames bypass the wire codec, so they may hold NaN counts."""

    PARAMS: ClassVar[frozenset[str]] = frozenset()

    def __init__(self, url: str = "queue://test") -> None:
        from tactiled.sources import SourceURL

        super().__init__(SourceURL(url=url, scheme="queue", location="test", params={}))
        self.queue: asyncio.Queue[Frame | None] = asyncio.Queue()

    def put(self, frame: Frame) -> None:
        frame.host_time = time.monotonic()
        self.queue.put_nowait(frame)

    def end(self) -> None:
        self.queue.put_nowait(None)

    async def frames(self, timeout: float | None = None):  # type: ignore[override]
        while True:
            frame = await self.queue.get()
            if frame is None:
                self.connected = False
                return
            self.decoder.stats.frames += 1
            yield frame

    async def _open_internal(self) -> None:
        pass

    async def _close_internal(self) -> None:
        pass

    async def _read_internal(self) -> bytes:  # pragma: no cover - frames() is overridden
        return b""


def strict_json(obj: Any) -> str:
    """JSON text; raises ValueError on NaN or inf."""
    return json.dumps(obj, allow_nan=False)


def all_finite_numbers(obj: Any) -> bool:
    """True if every number in a JSON-like structure is finite."""
    if isinstance(obj, dict):
        return all(all_finite_numbers(v) for v in obj.values())
    if isinstance(obj, list):
        return all(all_finite_numbers(v) for v in obj)
    if isinstance(obj, float):
        return math.isfinite(obj)
    return True


def np_frames_equal(a: Frame, b: Frame) -> bool:
    return a.seq == b.seq and a.sensor_id == b.sensor_id and np.array_equal(a.raw, b.raw)


# --------------------------------------------------------------------------------------------
# Estimates


def collect(daemon: Daemon, kind: str = "estimate") -> list:
    items: list = []
    daemon.hub.add_listener(lambda item: items.append(item) if item.kind == kind else None)
    return items


def accounted(st: dict) -> int:
    """Every frame ends in exactly one of these."""
    return (st["published"] + st["superseded"] + st["stale_dropped"] + st["fit_failed"]
            + st["fit_errors"] + st["wrong_sensor"] + st["bad_shape"] + st["errors"])


def check_estimates(estimates: list, sensor: str, sensor_id: int) -> None:
    """Seqs strictly increasing, fitted_seq consistent, strict JSON without NaN."""
    seqs = [e.seq for e in estimates]
    assert seqs == sorted(set(seqs)), "an estimate was published out of order"
    for e in estimates:
        assert (e.sensor, e.sensor_id) == (sensor, sensor_id)
        if e.gate == "fit":
            assert e.fitted_seq == e.seq
        elif e.gate == "unchanged":
            # the fit it builds on: an earlier frame's, or (tracked, for a frame that waited
            # for that fit) a later one's
            assert e.fitted_seq is not None and e.fitted_seq != e.seq
        else:
            assert e.gate == "no_contact" and e.fitted_seq is None and not e.contact
        line = e.to_json_dict()
        strict_json(line)
        assert all_finite_numbers(line)
        assert line["latency_ms"] >= 0


class InProcessPool:
    """What SensorPipeline needs of a pool, no processes: jobs stay with the test, which
    answers them with :func:`answer` (:func:`play_read`: after each read, as the loop sends
    them)."""

    restarts = 0

    def register_spec(self, sensor, options, finger=None) -> int:
        self.sensor, self.options = sensor, options
        return 0

    def wake(self) -> None:
        pass

    def dispatch_now(self) -> None:
        pass


def play_read(p: Any, fitter: Any, read: list[Frame], respond: Any = None) -> None:
    """One read's frames through the SensorPipeline ``p`` (in slices, as the loop hands them
    over), then the fits they left waiting answered with ``fitter`` (``respond``, by default
    :func:`answer`)."""
    p.clock.stamp(read)
    done = 0
    while done < len(read):
        done = p.on_frames(read, done)
    while p._waiting is not None and p._in_flight is None:
        (respond or answer)(p, fitter, p.take_job())


def answer(p: Any, fitter: Any, job: Any) -> None:
    """Do ``job`` as a worker does (tactiled.pipeline.worker) with ``fitter``, in this
    process, and hand the answer back to the SensorPipeline ``p``."""
    from tactiled.fit.linearize import linearize
    from tactiled.pipeline.estimate import plain

    if job.kind == "lin":
        lin = linearize(fitter, job.strain, job.warm[0], np.asarray(job.warm[1]), job.mask)
        p.on_fit_result(job, {}, 1.0, None, None, lin)
        return
    r = fitter.fit(job.strain, job.model, mask=job.mask, warm=job.warm)
    lin = None  # as the worker: a fit with no model (no contact found) has nothing to linearise
    if r.params is not None and r.model:
        lin = linearize(fitter, job.strain, r.model, np.asarray(r.params), job.mask)
    p.on_fit_result(job, plain(r.to_json_dict()), 1.0, None, (r.model, r.params), lin)

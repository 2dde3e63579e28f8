"""The frames of one read are handled in one call (``SensorPipeline.on_frames``): the same
estimates as the frames handed over one by one, and a long read handled in slices."""

from __future__ import annotations

import asyncio
import time

import numpy as np
from pipeline_helpers import InProcessPool as Pool
from pipeline_helpers import answer, contact_path, make_frames

from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.frames import encode_frame
from tactiled.pipeline import sensor as sensor_module
from tactiled.pipeline.estimate import without_timing
from tactiled.pipeline.hub import Hub
from tactiled.pipeline.sensor import SensorPipeline
from tactiled.settings import SensorSettings


class _Pool(Pool):
    """The in-process pool, counting the sends the loop asks for at once."""

    dispatched = 0

    def dispatch_now(self) -> None:
        self.dispatched += 1


def _pipeline() -> tuple[SensorPipeline, list, Fitter]:
    hub = Hub()
    seen: list = []
    hub.add_listener(seen.append)
    pool = _Pool()
    # lossless: a frame waiting for a fit over MAX_WAIT_S of the host's clock is otherwise
    # flushed as predicted, so on a loaded machine the two pipelines' timing, not their
    # arithmetic, would make them differ
    p = SensorPipeline(SensorSettings(name="f", url="sim://", noise_sigma=0.0005), pool=pool,
                       hub=hub, lossless=True)
    return p, seen, Fitter(pool.sensor, FitOptions(**dict(pool.options)))


def _answer_all(p: SensorPipeline, fitter: Fitter) -> None:
    while p._waiting is not None and p._in_flight is None:
        answer(p, fitter, p.take_job())


def test_a_read_in_one_call_publishes_what_its_frames_one_by_one_do() -> None:
    frames = make_frames(contact_path(60), sensor_id=0, tail=10, seed=3)
    again = make_frames(contact_path(60), sensor_id=0, tail=10, seed=3)  # the same, anew
    batch, seen_b, fit_b = _pipeline()
    single, seen_s, fit_s = _pipeline()
    for i in range(0, len(frames), 7):  # 7 frames a read
        read = frames[i:i + 7]
        batch.clock.stamp(read)
        done = 0
        while done < len(read):  # in slices, as the loop does, if the machine is slow
            done = batch.on_frames(read, done)
        _answer_all(batch, fit_b)
        for frame in again[i:i + 7]:
            single.on_frame(frame)
        _answer_all(single, fit_s)
    est_b = [without_timing(e.to_json_dict()) for e in seen_b if e.kind == "estimate"]
    est_s = [without_timing(e.to_json_dict()) for e in seen_s if e.kind == "estimate"]
    assert len(est_b) > 60 and est_b == est_s
    assert batch.frames == single.frames == len(frames)
    assert batch.stats().to_json_dict()["skipped"] == single.stats().to_json_dict()["skipped"]
    # the fits the batch made due went to the pool at once; one by one, none is sent early
    assert batch.pool.dispatched >= 1 and single.pool.dispatched == 0


def test_a_long_read_is_handled_in_slices(monkeypatch) -> None:
    """Past ``SLICE_S`` the call returns where it stopped (the loop then lets the other
    sensors run): with no time allowed, one frame a call on the per-frame path, every frame
    handled once (the core's runs: tests/pipeline/test_frame_run.py)."""
    monkeypatch.setattr(sensor_module, "SLICE_S", -1.0)
    p, seen, _ = _pipeline()
    p.batched = False
    frames = make_frames([], sensor_id=0, settle=20)
    p.clock.stamp(frames)
    done, calls = 0, 0
    while done < len(frames):
        nxt = p.on_frames(frames, done)
        assert nxt == done + 1
        done, calls = nxt, calls + 1
    assert calls == len(frames) == p.frames
    seqs = [e.seq for e in seen if e.kind == "estimate"]
    assert seqs == [f.seq for f in frames]
    assert np.isfinite(p.stats().frame_rate_hz)


def test_a_read_in_slices_is_not_settled_until_its_last_frame(pty_device, arun, wait_until,
                                                               monkeypatch) -> None:
    """A read of many frames handled in slices (the loop's other tasks run between them, as
    on a slow machine or the reference) leaves the sensor unsettled until its last frame is
    handled: a test or a replay that waits for ``settled`` and then stops loses none of them.
    Over a real pty, the frames written at once, one frame a slice."""
    monkeypatch.setattr(sensor_module, "SLICE_S", -1.0)
    frames = make_frames([], sensor_id=0, settle=24)
    data = b"".join(encode_frame(f) for f in frames)

    async def play() -> list[tuple[int, int, bool]]:
        hub, pool = Hub(), _Pool()
        p = SensorPipeline(SensorSettings(name="f", url=f"serial://{pty_device.path}",
                                          noise_sigma=0.0005), pool=pool, hub=hub)
        p.start()
        try:
            await wait_until(lambda: p.source.is_open, 30)
            pty_device.write(data)
            seen: list[tuple[int, int, bool]] = []  # (decoded, handled, settled) each turn
            deadline = time.monotonic() + 60
            while p.frames < len(frames) and time.monotonic() < deadline:
                seen.append((p.source.decoder.stats.frames, p.frames, p.settled))
                await asyncio.sleep(0)
            seen.append((p.source.decoder.stats.frames, p.frames, p.settled))
            return seen
        finally:
            await p.close()

    seen = arun(play())
    assert seen[-1] == (len(frames), len(frames), True)
    behind = [s for s in seen if s[1] < s[0]]  # frames read, not all handled yet
    assert behind, "no read was handled in slices"
    assert not any(settled for _, _, settled in behind), behind[:3]

"""A read's frames in runs through the core (``tactiled.pipeline.frame_run``) publish what the
per-frame path (``SensorPipeline.batched = False``, the reference ``TACTILED_CORE=python``
runs) does: the same estimates and zeroed frames, bit for bit but the timing keys, and the
same counters, on a press that comes and goes, with hostile frames among the good.  Under
``TACTILED_CORE=python`` the runs are the reference's (``fused_reference.ZeroRun``)."""

from __future__ import annotations

import numpy as np
import pytest
from pipeline_helpers import InProcessPool, answer, contact_path, make_frames

from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.frames import Frame
from tactiled.pipeline import frame_run
from tactiled.pipeline import sensor as sensor_module
from tactiled.pipeline.estimate import without_timing
from tactiled.pipeline.hub import Hub
from tactiled.pipeline.sensor import SensorPipeline
from tactiled.settings import SensorSettings


class _Pool(InProcessPool):
    def dispatch_now(self) -> None:
        pass


def _pipeline(batched: bool, track: bool) -> tuple[SensorPipeline, list, Fitter]:
    hub = Hub()
    seen: list = []
    hub.add_listener(seen.append)
    pool = _Pool()
    p = SensorPipeline(SensorSettings(name="f", url="sim://", noise_sigma=0.0005, track=track,
                                      wire_id=0),
                       pool=pool, hub=hub)
    p.batched = batched
    return p, seen, Fitter(pool.sensor, FitOptions(**dict(pool.options)))


def _stream(seed: int) -> list[Frame]:
    """Rest, a rolling press, rest, a light press, rest; a frame of another sensor, one of
    another shape and one of float counts among them."""
    frames = make_frames(contact_path(40) + [None] * 50 + contact_path(30, force=0.4),
                         sensor_id=0, tail=40, seed=seed)
    for k, f in enumerate(frames):
        if k in (75, 150):
            f.sensor_id = 3
        elif k == 95:
            f.raw = f.raw[:, :4].copy()
        elif k == 170:
            f.raw = f.raw.astype(np.float64)
    return frames


def _play(p: SensorPipeline, fitter: Fitter, frames: list[Frame], sizes: list[int],
          tare_at: int) -> None:
    i = r = 0
    while i < len(frames):
        read = frames[i:i + sizes[r % len(sizes)]]
        p.clock.stamp(read)
        done = 0
        while done < len(read):
            done = p.on_frames(read, done)
        while p._waiting is not None and p._in_flight is None:
            answer(p, fitter, p.take_job())
        i, r = i + len(read), r + 1
        if i >= tare_at > i - len(read):
            p.tare()


@pytest.mark.parametrize("track", [True, False])
def test_runs_publish_what_the_per_frame_path_does(track: bool) -> None:
    runs, seen_r, fit_r = _pipeline(True, track)
    single, seen_s, fit_s = _pipeline(False, track)
    sizes = [7, 1, 12, 3, 16]
    _play(runs, fit_r, _stream(5), sizes, tare_at=190)
    _play(single, fit_s, _stream(5), sizes, tare_at=190)
    est_r = [without_timing(e.to_json_dict()) for e in seen_r if e.kind == "estimate"]
    est_s = [without_timing(e.to_json_dict()) for e in seen_s if e.kind == "estimate"]
    assert len(est_r) > 120 and est_r == est_s
    gates = {e["gate"] for e in est_r}
    assert "no_contact" in gates and ("fit" in gates)
    frm_r = [e for e in seen_r if e.kind == "frame"]
    frm_s = [e for e in seen_s if e.kind == "frame"]
    assert len(frm_r) == len(frm_s) > 150
    for a, b in zip(frm_r, frm_s):
        assert (a.seq, a.contact, a.statistic) == (b.seq, b.contact, b.statistic)
        np.testing.assert_array_equal(a.strain, b.strain)
        assert not a.strain.flags.writeable
    st_r, st_s = runs.stats(), single.stats()
    for key in ("frames", "published", "skipped", "superseded", "fitted", "wrong_sensor",
                "bad_shape", "errors"):
        assert getattr(st_r, key) == getattr(st_s, key), key
    assert (st_r.wrong_sensor, st_r.bad_shape, st_r.errors) == (2, 1, 0)


def test_a_long_quiet_read_goes_in_runs_and_slices(monkeypatch) -> None:
    """Past ``SLICE_S`` the call returns after the run it is in: with no time allowed, one
    run a call, every frame handled once, in order."""
    monkeypatch.setattr(sensor_module, "SLICE_S", -1.0)
    p, seen, _ = _pipeline(True, True)
    frames = make_frames([], sensor_id=0, settle=200)
    p.clock.stamp(frames)
    done, calls = 0, 0
    while done < len(frames):
        nxt = p.on_frames(frames, done)
        assert done < nxt <= done + max(1, frame_run.MAX_RUN)
        done, calls = nxt, calls + 1
    assert p.frames == len(frames) and calls < len(frames) / 4
    assert [e.seq for e in seen if e.kind == "estimate"] == [f.seq for f in frames]

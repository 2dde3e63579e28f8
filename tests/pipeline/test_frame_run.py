"""A read's frames in runs through the core (``tactiled.pipeline.frame_run``) publish what the
per-frame path (``SensorPipeline.batched = False``, the reference ``TACTILED_CORE=python``
runs) does: the same estimates and zeroed frames, bit for bit but the timing keys, and the
same counters, on a press that comes and goes, with hostile frames among the good.  Under
``TACTILED_CORE=python`` the runs are the reference's (``fused_reference.ZeroRun``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pipeline_helpers import InProcessPool, contact_path, make_frames, play_read

from tactiled import native
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.frames import Frame
from tactiled.pipeline import frame_run, sensor_tracking, tracked_run
from tactiled.pipeline import sensor as sensor_module
from tactiled.pipeline.estimate import without_timing
from tactiled.pipeline.hub import Hub
from tactiled.pipeline.sensor import SensorPipeline
from tactiled.settings import SensorSettings


def _pipeline(batched: bool, track: bool, listen: bool = True
              ) -> tuple[SensorPipeline, list, Fitter]:
    """A pipeline of a simulated sensor; ``listen``: a listener puts every published item in
    the list returned (else nobody takes its zeroed frames)."""
    hub = Hub()
    seen: list = []
    if listen:
        hub.add_listener(seen.append)
    pool = InProcessPool()
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
        play_read(p, fitter, read)
        i, r = i + len(read), r + 1
        if i >= tare_at > i - len(read):
            p.tare()


@pytest.mark.parametrize("track", [True, False])
def test_runs_publish_what_the_per_frame_path_does(track: bool, monkeypatch) -> None:
    # frames never wait so long that the clock decides (a fit of the reference's, in this
    # process, can outlast MAX_WAIT_S): both paths see the same
    monkeypatch.setattr(sensor_tracking, "MAX_WAIT_S", math.inf)
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


# -- the tracked run (tactiled.pipeline.tracked_run) ---------------------------------------------


def _answer_as_worker(p: SensorPipeline, fitter: Fitter, job) -> None:
    """``job`` done as tactiled.pipeline.worker does it (several contacts' fits and
    linearisations too), in this process, the answer handed to ``p``."""
    from tactiled.fit.linearize import linearize
    from tactiled.fit.multi import contacts_json, fit_contacts, linearize_several, warm_of
    from tactiled.fit.warm import SEVERAL
    from tactiled.pipeline.estimate import plain
    from tactiled.pipeline.worker import _several_lin

    if job.kind == "lin":
        lin = (linearize_several(fitter, job.strain, list(job.warm[1]), job.mask)
               if job.warm[0] == SEVERAL else
               linearize(fitter, job.strain, job.warm[0], np.asarray(job.warm[1]), job.mask))
        p.on_fit_result(job, {}, 1.0, None, None, lin)
        return
    results = fit_contacts(fitter, job.strain, job.model, mask=job.mask, warm=job.warm)
    lin = None
    if job.kind == "fit+lin":
        if len(results) > 1:
            lin = _several_lin(fitter, job.strain, results, job.mask)
        elif results[0].params is not None and results[0].model:
            lin = linearize(fitter, job.strain, results[0].model, np.asarray(results[0].params),
                            job.mask)
    p.on_fit_result(job, plain(contacts_json(results)), 1.0, None, warm_of(results), lin)


def _play_reads(p: SensorPipeline, fitter: Fitter, frames: list[Frame], sizes: list[int]) -> None:
    """``frames`` in reads of ``sizes`` (cycled), the fits they leave answered after each."""
    i = r = 0
    while i < len(frames):
        read = frames[i:i + sizes[r % len(sizes)]]
        play_read(p, fitter, read, _answer_as_worker)
        i, r = i + len(read), r + 1


@pytest.fixture
def stops(monkeypatch) -> dict[str, int]:
    """Frames the tracked runs stepped (``"tracked"``) and how many ended for each reason."""
    seen: dict[str, int] = {}
    publish = tracked_run.TrackedRun.publish

    def counted(self, *args, **kwargs):
        seen["tracked"] = seen.get("tracked", 0) + self.tracked
        why = tracked_run.STOPS[self.stop]
        seen[why] = seen.get(why, 0) + 1
        return publish(self, *args, **kwargs)

    monkeypatch.setattr(tracked_run.TrackedRun, "publish", counted)
    return seen


def _same_published(frames: list[Frame], sizes: list[int], model: str = "auto"
                    ) -> tuple[list[dict], SensorPipeline]:
    """``frames`` through the runs and through the per-frame path: the estimates (timing keys
    aside) and zeroed frames each published must be the same, bit for bit, and so the
    counters; returns the runs' estimates and pipeline."""
    out = []
    for batched in (True, False):
        p, seen, fitter = _pipeline(batched, True)
        p.model = model
        with pytest.MonkeyPatch.context() as mp:
            # (frames never wait so long that the clock decides: both paths see the same)
            mp.setattr(sensor_tracking, "MAX_WAIT_S", math.inf)
            _play_reads(p, fitter, [Frame(seq=f.seq, device_time_us=f.device_time_us,
                                          raw=f.raw, sensor_id=f.sensor_id) for f in frames],
                        sizes)
        out.append((p, [without_timing(e.to_json_dict()) for e in seen if e.kind == "estimate"],
                    [e for e in seen if e.kind == "frame"]))
    (runs, est_r, frm_r), (single, est_s, frm_s) = out
    assert len(est_r) > len(frames) // 2
    assert est_r == est_s
    assert len(frm_r) == len(frm_s)
    for a, b in zip(frm_r, frm_s):
        assert (a.seq, a.contact, a.statistic) == (b.seq, b.contact, b.statistic)
        np.testing.assert_array_equal(a.strain, b.strain)
    st_r, st_s = runs.stats(), single.stats()
    for key in ("frames", "published", "skipped", "superseded", "fitted", "errors"):
        assert getattr(st_r, key) == getattr(st_s, key), key
    tr_r, tr_s = runs.tracking, single.tracking
    for key in ("tracked", "predicted", "relinearized", "drift_followed", "pressed_elsewhere",
                "signal_grown"):
        assert getattr(tr_r, key) == getattr(tr_s, key), key
    assert runs.errors == 0
    return est_r, runs


def test_a_tracked_contact_goes_through_the_core_in_runs(stops) -> None:
    """A rolling press, then a light one, in reads of several sizes: most of the tracked
    frames go through tracked runs, which end where the per-frame path
    takes over (the residuals' fold, the zeroer's drift step, a relinearisation)."""
    frames = make_frames(contact_path(120) + [None] * 20 + contact_path(60, force=0.4),
                         sensor_id=0, tail=20, seed=3)
    est, runs = _same_published(frames, [16, 5, 33, 1, 12])
    assert sum(e["gate"] == "unchanged" for e in est) == runs.tracking.tracked > 100
    if native.core is None:  # the tracked run is the core's: the reference goes frame by frame
        assert stops == {}, stops
        return
    assert stops.get("tracked", 0) > 0.8 * runs.tracking.tracked, stops
    assert min(stops.get(why, 0) for why in ("fold", "drift", "relinearize")) >= 5, stops


def test_tracked_runs_nobody_takes_frames_from_keep_the_latest(stops, monkeypatch) -> None:
    """With no listener and no frame subscription a tracked run keeps its zeroed frames'
    fields (Hub.publish_frame): after each read the latest frame, built when asked, and the
    latest estimate are the per-frame path's, and so are the published counts."""
    monkeypatch.setattr(sensor_tracking, "MAX_WAIT_S", math.inf)
    frames = make_frames(contact_path(60, moving=False), sensor_id=0, tail=10, seed=4)
    ref, _, fit_ref = _pipeline(False, True)
    runs, _, fit_runs = _pipeline(True, True, listen=False)
    assert not runs.hub._frame_takers
    i = r = 0
    while i < len(frames):
        n = (9, 4, 17)[r % 3]
        for p, fitter in ((ref, fit_ref), (runs, fit_runs)):
            _play_reads(p, fitter, [Frame(seq=f.seq, device_time_us=f.device_time_us,
                                          raw=f.raw, sensor_id=f.sensor_id)
                                    for f in frames[i:i + n]], [n])
        i, r = i + n, r + 1
        a, b = runs.hub.latest_frame("f"), ref.hub.latest_frame("f")
        assert (a.sensor_id, a.seq, a.device_time_us, a.contact, a.statistic) == (
            b.sensor_id, b.seq, b.device_time_us, b.contact, b.statistic)
        np.testing.assert_array_equal(a.strain, b.strain)
        assert (without_timing(runs.hub.latest_estimate("f").to_json_dict())
                == without_timing(ref.hub.latest_estimate("f").to_json_dict()))
    assert runs.hub.published == ref.hub.published
    assert runs.tracking.tracked == ref.tracking.tracked > 20
    # the tracked run is the core's: the reference goes frame by frame
    assert stops.get("tracked", 0) > 20 if native.core is not None else stops == {}, stops


def _two_contacts(seed: int) -> list[Frame]:
    """One contact held (rolling slowly), a second pressed beside it and lifted, well apart
    (their windows do not overlap), as tests/pipeline/test_several_contacts.py's."""
    from tactiled.calibration.lut import LookupTable
    from tactiled.physics.contact import Contact
    from tactiled.physics.strain import StrainModel
    from pipeline_helpers import PERIOD_US, SETTLE_FRAMES

    model = StrainModel()
    rng = np.random.default_rng(seed)
    a = lambda k: Contact(5.0, 5.0, 0.0, 1.2, 5.0 + 0.01 * k, 12.0)  # noqa: E731
    b = Contact(8.0, 8.0, 0.0, 0.6, 18.0, 16.0)
    scene = ([[]] * SETTLE_FRAMES + [[a(k)] for k in range(20)]
             + [[a(20 + k), b] for k in range(60)] + [[a(80 + k)] for k in range(20)]
             + [[]] * 10)
    strain = [sum((model.predict(c) for c in cs), np.zeros((8, 8)))
              + rng.normal(0.0, 0.0005, (8, 8)) for cs in scene]
    counts = LookupTable.linear().to_counts(np.array(strain))
    return [Frame(seq=k, device_time_us=k * PERIOD_US, raw=c, sensor_id=0)
            for k, c in enumerate(counts)]


def test_several_contacts_in_tracked_runs_publish_what_the_per_frame_path_does(stops) -> None:
    est, runs = _same_published(_two_contacts(7), [9, 4, 20], model="sphere")
    several = [e for e in est if len(e["contacts"]) == 2 and e["gate"] == "unchanged"]
    assert len(several) > 20
    # the tracked run is the core's: the reference goes frame by frame
    assert stops.get("tracked", 0) > 20 if native.core is not None else stops == {}, stops


@pytest.mark.slow  # (about 20 s a scene on a loaded machine: the fits are real)
@settings(max_examples=6, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(force=st.floats(0.3, 2.0), r1=st.floats(4.0, 15.0), moving=st.booleans(),
       psi=st.floats(30.0, 150.0), seed=st.integers(0, 2**16),
       sizes=st.lists(st.integers(1, 40), min_size=1, max_size=4))
def test_drawn_scenes_publish_what_the_per_frame_path_does(force, r1, moving, psi, seed,
                                                           sizes) -> None:
    frames = make_frames(contact_path(60, force=force, r1=r1, moving=moving, psi=psi)
                         + [None] * 10 + contact_path(20, force=force / 2, r1=r1), sensor_id=0,
                         tail=10, seed=seed)
    _same_published(frames, sizes)


@pytest.mark.skipif(native.core is None, reason="TACTILED_CORE=python: no core to compare")
def test_the_tracked_run_refuses_arrays_that_do_not_fit() -> None:
    """Arrays of the wrong size or an index outside the frame are a clear error before any
    frame is touched, never a read out of bounds (the core's tracked run; the reference has
    none)."""
    p, _, fitter = _pipeline(True, True)
    frames = make_frames(contact_path(40, moving=False), sensor_id=0, seed=2)
    _play_reads(p, fitter, frames[:-1], [1])
    run = tracked_run.plan(p)
    assert run is not None  # a held contact, tracked
    stage = p.stage
    raws = [frames[-1].raw]
    times = np.array([frames[-1].device_time_us * 1e-6])
    state = stage._run_state.copy()
    state[:] = 0.0
    state[5] = 1.0

    def call(**change):
        args = dict(runner=stage._runner, raws=raws, times=times, z=np.empty((1, 8, 8)),
                    stats=np.empty(1), peaks=np.empty(1), state=state, steps=run.steps,
                    ats=run.ats, per=run.per, tests=run.tests, outside=run.outside,
                    expected=run.expected, mask=run.mask,
                    out=np.empty((1, len(run.steps), 14 + 2 * max(run.k))))
        args.update(change)
        return native.core.track_run(**args)

    before = [s.s.copy() for s in run.steps]
    with pytest.raises(ValueError, match="tests"):
        call(tests=run.tests[:-1])
    with pytest.raises(ValueError, match="ats"):
        call(ats=[np.zeros(3)])
    with pytest.raises(ValueError, match="out"):
        call(out=np.empty((1, 1, 3)))
    with pytest.raises(IndexError, match="outside"):
        call(outside=np.array([64]), expected=np.zeros(1))
    with pytest.raises(ValueError, match="mask"):
        call(mask=np.ones(3, dtype=np.uint8))
    for s, b in zip(run.steps, before):
        np.testing.assert_array_equal(s.s, b)

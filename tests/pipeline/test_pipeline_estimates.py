"""The daemon end to end with real fit workers: ids and seqs, latest-wins, stale results,
NaN frames, runtime configuration, tare, graceful stop with recording."""

from __future__ import annotations

import asyncio
import json
import math
import time
from pathlib import Path

import numpy as np
import pytest
from pipeline_helpers import (
    SETTLE_FRAMES,
    QueueSource,
    accounted,
    all_finite_numbers,
    check_estimates,
    collect,
    contact_path,
    make_frames,
    strict_json,
    write_recording,
)
from worker_hooks import hang

from tactiled.errors import ConfigError
from tactiled.frames import Frame
from tactiled.pipeline import Daemon, UnknownSensorError
from tactiled.io.recording import read_recording
from tactiled.settings import load_settings


def test_every_frame_gets_its_estimate_with_its_sensor_and_seq(tmp_path: Path, arun) -> None:
    truth = contact_path(40)
    thumb = make_frames(truth, sensor_id=3, seed=1, tail=20)
    index = make_frames(truth, sensor_id=7, seed=2, start_seq=1000, tail=20)
    wrong = make_frames([], sensor_id=4, settle=10)
    overrides = {
        "sensor[0].name": "thumb", "sensor[0].wire_id": 3,
        "sensor[0].url": f"replay://{write_recording(tmp_path / 't.tact', thumb)}?speed=0",
        "sensor[1].name": "index",
        "sensor[1].url": f"replay://{write_recording(tmp_path / 'i.tact', index)}?speed=0",
        "sensor[2].name": "miswired", "sensor[2].wire_id": 3,
        "sensor[2].url": f"replay://{write_recording(tmp_path / 'w.tact', wrong)}?speed=0",
        "fit.workers": 2,
    }

    async def main() -> tuple[list, dict]:
        daemon = Daemon(load_settings(None, {}, overrides), lossless=True)
        estimates = collect(daemon)
        await daemon.start()
        assert await daemon.wait_finished(60)
        stats = daemon.stats()
        await daemon.stop()
        return estimates, stats

    estimates, stats = arun(main())
    by_sensor = {name: [e for e in estimates if e.sensor == name]
                 for name in ("thumb", "index", "miswired")}
    for name, frames, wire in (("thumb", thumb, 3), ("index", index, 7)):
        got = by_sensor[name]
        check_estimates(got, name, wire)
        assert [e.seq for e in got] == [f.seq for f in frames]  # lossless: one per frame
        assert [e.device_time_us for e in got] == [f.device_time_us for f in frames]
        st = stats["sensors"][name]
        assert st["frames"] == len(frames) == accounted(st)
        assert st["superseded"] == 0 and st["stale_dropped"] == 0 and st["fitted"] > 0
        assert st["published"] == (st["skipped"]["no_contact"] + st["skipped"]["unchanged"]
                                   + st["fitted"])
        assert all(not e.contact for e in got[:SETTLE_FRAMES])
        answered = [e for e in got[SETTLE_FRAMES:SETTLE_FRAMES + 40] if e.contact]
        assert len(answered) >= 30 and any(e.gate == "fit" for e in answered)
        # the worker really fitted the physics, and the tracker followed the moving contact
        # from there: centre and force recovered on every frame
        for e in answered:
            c = truth[e.seq - frames[0].seq - SETTLE_FRAMES]
            assert abs(e.fit["x_mm"] - c.x0) < 0.3 and abs(e.fit["y_mm"] - c.y0) < 0.3
            assert e.fit["force_n"] == pytest.approx(c.force, rel=0.15)
            assert e.fit["model"] in ("cylinder", "general", "sphere")
    assert by_sensor["miswired"] == []
    assert stats["sensors"]["miswired"]["wrong_sensor"] == len(wrong)
    assert stats["workers"]["restarts"] == 0
    assert stats["hub"]["published"]["frame"] == len(thumb) + len(index)


def test_the_calibration_file_is_applied_and_its_dead_tactels_are_left_out(
        tmp_path: Path, arun) -> None:
    from tactiled.calibration import LookupTable
    from tactiled.io.calibration import save_calibration
    from tactiled.sensors.model import NoiseModel
    from tactiled.sim import simulate_frames

    # A sensor twice as sensitive as the nominal table, with tactel [3, 3] (under the contact's
    # peak) dead: it reads its rest value whatever the load.
    truth = contact_path(30, moving=False)
    nominal = LookupTable.linear(sensor_id=9, counts_per_strain=40000.0)
    counts_of = [list(nominal.knots(k // 8, k % 8)[0]) for k in range(64)]
    strain_of = [list(nominal.knots(k // 8, k % 8)[1]) for k in range(64)]
    flags = [("dead",) if k == 3 * 8 + 3 else () for k in range(64)]
    table = LookupTable(8, 8, counts_of, strain_of, sensor_id=9, flags=flags)
    save_calibration(table, tmp_path / "cal.json")
    strain = simulate_frames([None] * SETTLE_FRAMES + truth, noise=NoiseModel(sigma=0.0005),
                             seed=12)
    counts = table.to_counts(strain)
    counts[:, 3, 3] = counts[0, 3, 3]
    frames = [Frame(seq=k, device_time_us=k * 5000, raw=c, sensor_id=9)
              for k, c in enumerate(counts)]
    overrides = {"sensor[0].url": f"replay://{write_recording(tmp_path / 'c.tact', frames)}"
                                  "?speed=0",
                 "sensor[0].calibration": str(tmp_path / "cal.json"),
                 "sensor[0].model": "cylinder", "sensor[0].reuse_unchanged": False}

    async def main() -> tuple[list, dict]:
        daemon = Daemon(load_settings(None, {}, overrides), lossless=True)
        estimates = collect(daemon)
        await daemon.start()
        assert await daemon.wait_finished(60)
        st = daemon.stats("finger0")
        await daemon.stop()
        return estimates, st

    estimates, st = arun(main())
    check_estimates(estimates, "finger0", 9)  # the wire id came from the calibration file
    fits = [e.fit for e in estimates if e.gate == "fit"]
    assert len(fits) >= 25
    for fit in fits:
        # The table's gain is applied (a nominal table would halve the force) and the dead
        # tactel is left out: fitted with its stuck reading, x and y come out ~0.8 and ~1.4 mm
        # off and the force 30 % low.  Bounds: ~4 Cramer-Rao sigma (x 0.07, y 0.09 mm here).
        assert fit["force_n"] == pytest.approx(1.0, rel=0.08)
        assert abs(fit["x_mm"] - 9.0) < 0.3 and abs(fit["y_mm"] - 13.0) < 0.4
    assert st["wrong_sensor"] == 0


def test_latest_frame_wins_while_the_worker_is_busy(tmp_path: Path, arun) -> None:
    frames = make_frames(contact_path(150), seed=3)  # ends in contact: the last one waits
    url = f"replay://{write_recording(tmp_path / 'a.tact', frames)}?speed=0"
    # tracking off: each estimate is its own frame's fit (the tracked case is the next test)
    overrides = {"sensor[0].url": url, "sensor[0].reuse_unchanged": False,
                 "sensor[0].model": "auto", "sensor[0].track": False}

    async def main() -> tuple[list, dict]:
        daemon = Daemon(load_settings(None, {}, overrides))
        estimates = collect(daemon)
        await daemon.start()
        assert await daemon.wait_finished(60)
        st = daemon.stats("finger0")
        await daemon.stop()
        return estimates, st

    estimates, st = arun(main())
    check_estimates(estimates, "finger0", 0)
    assert all(e.fit["frames_used"] in (0, 1) for e in estimates)
    # Frames come every loop iteration, a fit takes milliseconds: most are superseded.
    assert st["superseded"] > 50, st
    assert st["frames"] == len(frames) == accounted(st)
    assert st["fitted"] < 150 - 50
    assert not st["waiting"] and not st["in_flight"]
    # Latest wins: the newest frame is never lost, it is fitted once the worker is free.
    assert estimates[-1].seq == frames[-1].seq and estimates[-1].gate == "fit"


async def _settled_daemon(source: QueueSource, **sensor: object) -> tuple[Daemon, list]:
    """A started daemon whose one sensor reads ``source`` (sensor settings ``sensor``, with
    one-frame contact decisions), after SETTLE_FRAMES empty frames went through it: (the
    daemon, its estimates so far)."""
    overrides = {"sensor[0].url": "replay://unused.tact", "sensor[0].detector_average": 1}
    overrides.update({f"sensor[0].{k}": v for k, v in sensor.items()})
    daemon = Daemon(load_settings(None, {}, overrides), sources={"finger0": source})
    estimates = collect(daemon)
    await daemon.start()
    for frame in make_frames([], settle=SETTLE_FRAMES):
        source.put(frame)
    while len(estimates) < SETTLE_FRAMES:
        await asyncio.sleep(0.005)
    return daemon, estimates


def test_a_result_older_than_the_last_estimate_is_dropped(arun, hookable_workers) -> None:
    source = QueueSource()
    settle = make_frames([], settle=SETTLE_FRAMES)
    pressed = make_frames(contact_path(1), settle=0, start_seq=SETTLE_FRAMES)[0]
    released = make_frames([], settle=1, start_seq=SETTLE_FRAMES + 1, seed=9)[0]

    async def main() -> tuple[list, dict]:
        # one-frame contact decisions, so a single release frame ends the contact
        # (tracking off: with it, the frame waiting for that fit is given up when the contact
        # ends, counted superseded; test_sensor_tracking.py)
        daemon, estimates = await _settled_daemon(source, track=False)
        sensor = daemon.sensors["finger0"]
        # Keep the worker busy for 0.3 s (under the 1 s fit timeout): the fit of the pressed
        # frame queues behind it, and the release frame is published first.
        assert hang(daemon.pool, 0, 0.3) is not None
        source.put(pressed)
        while not sensor.stats().in_flight:
            await asyncio.sleep(0.001)
        source.put(released)
        while sensor.stats().published < len(settle) + 1:
            await asyncio.sleep(0.001)
        await sensor.wait_settled()
        source.end()
        st = daemon.stats("finger0")
        latest = daemon.hub.latest_estimate("finger0")
        await daemon.stop()
        assert latest is not None and latest.seq == released.seq
        return estimates, st

    estimates, st = arun(main())
    check_estimates(estimates, "finger0", 0)
    assert st["stale_dropped"] == 1 and st["fitted"] == 1, json.dumps(st)
    assert pressed.seq not in [e.seq for e in estimates]
    assert estimates[-1].seq == released.seq and estimates[-1].gate == "no_contact"
    assert st["frames"] == accounted(st)


def test_frames_with_nan_entries_break_nothing(arun) -> None:
    source = QueueSource()
    base = make_frames(contact_path(30), seed=5, tail=5)
    frames = []
    for k, f in enumerate(base):
        raw = f.raw.astype(np.float64)
        if k % 3 == 0:
            raw[2, 3] = np.nan
        if k % 7 == 0:
            raw[4, 4] = np.inf  # under the contact, near the peak
        if k == SETTLE_FRAMES + 10:
            raw[:, :] = np.nan  # a whole frame of garbage
        frames.append(Frame(seq=f.seq, device_time_us=f.device_time_us, raw=raw))

    async def main() -> tuple[list, list, dict]:
        daemon = Daemon(load_settings(None, {}, {"sensor[0].url": "replay://unused.tact"}),
                        sources={"finger0": source}, lossless=True)
        estimates = collect(daemon)
        zeroed = collect(daemon, "frame")
        await daemon.start()
        for frame in frames:
            source.put(frame)
        source.end()
        assert await daemon.wait_finished(30)
        st = daemon.stats("finger0")
        await daemon.stop()
        return estimates, zeroed, st

    estimates, zeroed, st = arun(main())
    check_estimates(estimates, "finger0", 0)
    assert [e.seq for e in estimates] == [f.seq for f in frames]
    assert st["errors"] == 0 and st["fit_errors"] == 0
    assert st["nonfinite_frames"] >= len(frames) // 3
    assert all(np.isfinite(z.strain).all() for z in zeroed)
    assert all(all_finite_numbers(z.to_json_dict()) for z in zeroed)
    assert any(e.gate == "fit" and e.contact for e in estimates)
    json.dumps([e.to_json_dict() for e in estimates], allow_nan=False)


def test_runtime_config_tare_and_unknown_sensors(arun) -> None:
    source = QueueSource()
    frames = make_frames(contact_path(20, moving=False), seed=6)

    async def main() -> tuple[list, dict]:
        daemon = Daemon(load_settings(None, {}, {"sensor[0].url": "replay://unused.tact",
                                                 "sensor[0].model": "cylinder"}),
                        sources={"finger0": source}, lossless=True)
        estimates = collect(daemon)
        await daemon.start()
        before = daemon.get_config()
        assert before["sensors"]["finger0"]["model"] == "cylinder"
        for bad, message in [
            ({"sensors": {"finger0": {"model": "cone"}}}, "sensors.finger0.model: must be one of"),
            ({"sensors": {"finger0": {"url": "sim://"}}}, "sensors.finger0.url: cannot be changed"),
            ({"sensors": {"finger0": {"modle": "sphere"}}}, "sensors.finger0.modle: unknown key"),
            ({"sensors": {"thumb": {"model": "sphere"}}}, "sensors.thumb: unknown sensor"),
            ({"sensors": {"finger0": {"model": "sphere", "window": 1}}}, "sensors.finger0.window"),
            ({"fit": {"timeout": -1}}, "fit.timeout: must be a positive"),
            ({"fit": {"workers": 3}}, "fit.workers: cannot be changed"),
            ({"server": {"port": 1}}, "server: not changeable"),
            ({"sensors": {"finger0": {"false_rate": 1e-300}}},
             "sensors.finger0.false_rate: must be a probability in 1e-12..0.5"),
        ]:
            with pytest.raises(ConfigError) as info:
                daemon.update_config(bad)
            assert str(info.value).startswith(message), str(info.value)
        assert daemon.get_config() == before  # all or nothing
        for frame in frames[:SETTLE_FRAMES + 10]:
            source.put(frame)
        while len(estimates) < SETTLE_FRAMES + 10:
            await asyncio.sleep(0.005)
        after = daemon.update_config({"sensors": {"finger0": {"model": "sphere",
                                                              "unchanged_z": 5}},
                                      "fit": {"timeout": 2.0}})
        assert after["sensors"]["finger0"]["model"] == "sphere"
        assert after["fit"]["timeout"] == 2.0 and daemon.pool.settings.timeout == 2.0
        for frame in frames[SETTLE_FRAMES + 10:SETTLE_FRAMES + 15]:
            source.put(frame)
        while len(estimates) < SETTLE_FRAMES + 15:
            await asyncio.sleep(0.005)
        # Tare while pressed: the next frame becomes the zero, so the contact disappears.
        daemon.tare("finger0")
        with pytest.raises(UnknownSensorError, match="unknown sensor 'thumb'"):
            daemon.tare("thumb")
        with pytest.raises(UnknownSensorError):
            daemon.stats("thumb")
        for frame in frames[SETTLE_FRAMES + 15:]:
            source.put(frame)
        source.end()
        assert await daemon.wait_finished(30)
        await daemon.stop()
        return estimates, before

    estimates, _ = arun(main())
    early = [e for e in estimates[:SETTLE_FRAMES + 10] if e.gate == "fit"]
    assert early and all(e.fit["model"] == "cylinder" for e in early)
    late = [e for e in estimates[SETTLE_FRAMES + 10:SETTLE_FRAMES + 15] if e.gate == "fit"]
    assert late and all(e.fit["model"] == "sphere" for e in late)
    assert estimates[SETTLE_FRAMES + 14].contact
    after_tare = estimates[SETTLE_FRAMES + 15:]
    assert len(after_tare) == 5 and not any(e.contact for e in after_tare)


def test_stop_is_graceful_and_flushes_the_recording(tmp_path: Path, arun,
                                                   hookable_workers) -> None:
    frames = make_frames(contact_path(100), seed=7)
    url = f"replay://{write_recording(tmp_path / 'in.tact', frames, period_s=0.002)}?speed=1"
    overrides = {"sensor[0].url": url, "record.path": str(tmp_path / "{sensor}.tact"),
                 "fit.timeout": 10.0}

    async def main() -> tuple[float, dict]:
        daemon = Daemon(load_settings(None, {}, overrides))
        await daemon.start()
        sensor = daemon.sensors["finger0"]
        while sensor.frames < SETTLE_FRAMES + 20:
            await asyncio.sleep(0.005)
        hang(daemon.pool, 0, 30.0)  # a worker that will not finish: stop must kill it
        await asyncio.sleep(0.05)
        t0 = time.monotonic()
        await daemon.stop(timeout=0.3)
        took = time.monotonic() - t0
        return took, daemon.stats("finger0")

    took, st = arun(main())
    assert took < 2.0, f"stop took {took:.2f} s"
    recorded = read_recording(tmp_path / "finger0.tact")
    assert len(recorded) == st["frames"] == st["recorded"] > SETTLE_FRAMES
    assert math.isfinite(took)


def test_a_persisting_contact_is_fitted_from_the_previous_solution(tmp_path: Path, arun) -> None:
    """Warm starts: once a contact is fitted, each next fit starts from that solution (and under
    'auto' keeps the model the data chose while it fits within noise)."""
    truth = contact_path(30)
    frames = make_frames(truth, seed=4, tail=5)
    overrides = {
        "sensor[0].url": f"replay://{write_recording(tmp_path / 'w.tact', frames)}?speed=0",
        "sensor[0].reuse_unchanged": False,  # every contact frame is fitted
    }

    async def main() -> list:
        daemon = Daemon(load_settings(None, {}, overrides), lossless=True)
        estimates = collect(daemon)
        await daemon.start()
        assert await daemon.wait_finished(60)
        await daemon.stop()
        return estimates

    estimates = arun(main())
    fitted = [e for e in estimates if e.gate == "fit" and e.contact]
    assert len(fitted) >= 20
    warm = [e for e in fitted if e.fit["message"].startswith("model ") and "kept from the previous frame" in e.fit["message"]]
    # the first fit of the contact is cold; nearly all that follow are warm
    assert not fitted[0].fit["message"].startswith("model ")
    assert len(warm) >= len(fitted) - 3, [e.fit["message"] for e in fitted]


def test_a_patch_that_fails_while_being_applied_is_rolled_back(arun, monkeypatch) -> None:
    """All or nothing even past validation: if applying a checked value fails for the second
    sensor (simulated: its detector refuses; no real value that passes the checks does that
    any more, 1e-300 for false_rate did), the first sensor's change is undone too."""
    sources = {"finger0": QueueSource(), "finger1": QueueSource()}

    async def main() -> tuple[dict, dict, str]:
        daemon = Daemon(load_settings(None, {}, {
            "sensor[0].url": "replay://a.tact", "sensor[1].url": "replay://b.tact",
            "sensor[1].name": "finger1"}), sources=sources, lossless=True)
        await daemon.start()
        try:
            for name, source in sources.items():  # the calibration stage forms on a frame
                source.put(make_frames(contact_path(1, moving=False), seed=6)[0])
                while daemon.sensors[name].stage is None:
                    await asyncio.sleep(0.005)
            before = daemon.get_config()
            detector = daemon.sensors["finger1"].stage.zeroer.detector
            real = detector.configure

            def refuse(**kwargs):
                if kwargs.get("false_rate") == 0.01:
                    raise ValueError("threshold out of reach")
                return real(**kwargs)

            monkeypatch.setattr(detector, "configure", refuse)
            with pytest.raises(ConfigError) as info:
                daemon.update_config({"sensors": {"finger0": {"model": "sphere"},
                                                  "finger1": {"false_rate": 0.01}}})
            return before, daemon.get_config(), str(info.value)
        finally:
            for source in sources.values():
                source.end()
            await daemon.stop()

    before, after, message = arun(main())
    assert message == "sensors.finger1: cannot be applied: threshold out of reach"
    assert after == before


def test_a_frame_that_needs_a_fit_is_sent_before_the_rest_of_its_read(arun) -> None:
    """A read brings many frames at once (a serial read after a stall): the first that needs a
    fit (the contact's first) goes to a worker before the loop decodes and tracks the rest, so
    its answer is not a whole read late.  Before, the pool dispatched after the read, and the
    newest frame of it was the first fitted."""
    source = QueueSource()
    burst = make_frames(contact_path(30), settle=0, start_seq=SETTLE_FRAMES)

    async def main() -> list:
        daemon, estimates = await _settled_daemon(source)
        sensor = daemon.sensors["finger0"]
        for frame in burst:  # queued at once: one read's worth, taken without waiting
            source.put(frame)
        while sensor.stats().published + sensor.stats().superseded < SETTLE_FRAMES + len(burst):
            await asyncio.sleep(0.005)
        source.end()
        await daemon.stop()
        return estimates

    estimates = arun(main())
    fitted = [e.seq for e in estimates if e.gate == "fit"]
    assert fitted, "no frame was fitted"
    assert fitted[0] <= burst[1].seq, (fitted, burst[0].seq)

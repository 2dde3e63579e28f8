"""``fit.max_fits_per_worker``: a worker that has answered that many fits is replaced by a
successor started *before* it retires, with real worker processes: no fit is lost (a lossless
replay gets exactly one estimate per frame, in order), the slot always has a ready worker
(the successor is ready before the old worker stops taking fits), and the old process exits."""

from __future__ import annotations

import asyncio
from pathlib import Path

from pipeline_helpers import (
    PACE,
    accounted,
    check_estimates,
    collect,
    contact_path,
    make_frames,
    write_recording,
)
from procs import alive

from tactiled.pipeline import Daemon
from tactiled.pipeline import supervision
from tactiled.settings import load_settings


def moving_recording(tmp_path: Path, frames: int) -> Path:
    """A contact that moves on every frame, so every frame is fitted (no gate reuse)."""
    return write_recording(tmp_path / "moving.tact",
                           make_frames(contact_path(frames), seed=5, tail=5))


def test_recycled_workers_lose_no_fit_in_a_lossless_replay(tmp_path: Path, arun) -> None:
    path = moving_recording(tmp_path, 120)
    overrides = {"sensor[0].url": f"replay://{path}?speed=0", "fit.workers": 1,
                 "fit.max_fits_per_worker": 25, "sensor[0].model": "cylinder",
                 "sensor[0].reuse_unchanged": False}
    first_pid = len(supervision.SPAWNED_PIDS)

    async def main() -> tuple[list, dict, dict, list[dict]]:
        daemon = Daemon(load_settings(None, {}, overrides), lossless=True)
        estimates = collect(daemon)
        recycles: list[dict] = []
        await daemon.start()
        pool = daemon.pool
        seen = None
        while not daemon.sensors["finger0"].finished or not daemon.sensors["finger0"].settled:
            last = pool.last_recycle
            if last is not None and last is not seen:
                seen = last
                recycles.append(dict(last))
            # Whatever moment this looks: the slot's worker is ready or its successor is
            # being started while the old one still serves (never "nobody can fit").
            states = [w["state"] for w in pool.stats()["workers"]]
            assert states != ["spawning"] and states != ["dead"], states
            await asyncio.sleep(0.001)
        assert await daemon.wait_finished(30)
        for _ in range(200):  # the last retired worker exits
            if not pool.stats()["recycling"]:
                break
            await asyncio.sleep(0.01)
        st = daemon.stats("finger0")
        workers = daemon.stats()["workers"]
        await daemon.stop()
        return estimates, st, workers, recycles

    estimates, st, workers, recycles = arun(main())
    fits = sum(e.gate == "fit" for e in estimates)
    assert fits >= 100
    # a successor takes a while to start, and the old worker goes on fitting meanwhile (no
    # gap), so how many recycles 120 fits see depends on the fitter's speed against the
    # spawn: at least one, each after 25 fits or more (checked below)
    assert workers["recycles"] >= 1, workers
    assert workers["restarts"] == 0 and st["fit_failed"] == 0 and st["fit_errors"] == 0
    # Lossless: every frame got exactly one estimate, in order.
    assert st["published"] == st["frames"] == len(estimates) == accounted(st)
    check_estimates(estimates, "finger0", 0)
    # Each successor was ready before its predecessor stopped; the predecessor stopped after
    # its last fit was answered (its result is among the estimates: none failed).
    assert all(r["old_stopped_at"] is None or r["old_stopped_at"] >= r["successor_ready_at"]
               for r in recycles), recycles
    assert workers["last_recycle"]["old_fits"] >= 25
    started = supervision.SPAWNED_PIDS[first_pid:]
    assert len(set(started)) == 1 + workers["recycles"]
    assert not [p for p in started if alive(p)]  # every retired worker has exited


def test_recycling_while_live_keeps_fitting(tmp_path: Path, arun) -> None:
    """At 1 kHz in real time with two sensors sharing one worker: recycling costs no fit and
    fitting goes on across every replacement.  4 s of frames: on a loaded machine a successor
    takes up to a second to start and the one worker fits fewer frames (the rest superseded),
    and two recycles after 20 fits each must still fit in the run (a worker answers 80 fits
    in it at a load average of 25)."""
    path = moving_recording(tmp_path, 4000)
    overrides = {"fit.workers": 1, "fit.max_fits_per_worker": 20,
                 "sensor[0].url": f"replay://{path}?speed={5 / PACE:g}",
                 "sensor[1].url": f"replay://{path}?speed={5 / PACE:g}", "sensor[1].name": "finger1",
                 "sensor[0].reuse_unchanged": False, "sensor[1].reuse_unchanged": False,
                 "sensor[0].track": False, "sensor[1].track": False}

    async def main() -> tuple[list, dict, dict]:
        daemon = Daemon(load_settings(None, {}, overrides))
        estimates = collect(daemon)
        await daemon.start()
        assert await daemon.wait_finished(60)
        stats = daemon.stats()
        await daemon.stop()
        return estimates, stats["sensors"], stats["workers"]

    estimates, sensors, workers = arun(main())
    assert workers["recycles"] >= 2 and workers["restarts"] == 0, (workers, sensors)
    for name, st in sensors.items():
        assert st["fit_failed"] == 0 and st["fit_errors"] == 0, (name, st)
        assert st["frames"] == accounted(st)
        check_estimates([e for e in estimates if e.sensor == name], name, 0)
    # Fits were answered by more workers than the one slot had at start.
    assert workers["fits"] >= 3 * 20

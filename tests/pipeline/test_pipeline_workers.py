"""Fit workers: SIGKILL and hangs are noticed, counted and repaired without stale or NaN
estimates; the pool survives bad input; the leak check catches a worker left running."""

from __future__ import annotations

import asyncio
import os
import signal
import time
from pathlib import Path
from typing import Any

import numpy as np
from procs import leftover
from worker_hooks import garble, hang
from pipeline_helpers import (
    PACE,
    SETTLE_FRAMES,
    accounted,
    check_estimates,
    collect,
    contact_path,
    make_frames,
    strict_json,
    write_recording,
)

from tactiled.sensors.model import DEFAULT_SENSOR
from tactiled.physics.contact import Contact
from tactiled.physics.strain import predict_strain
from tactiled.pipeline import Daemon
from tactiled.pipeline.jobs import FitJob
from tactiled.pipeline.pool import WorkerPool
from tactiled.settings import FitSettings, load_settings


def live_stream(tmp_path: Path, frames: int, period_s: float = 0.002) -> str:
    """A replay URL paced in real time: a contact moving all the time (always refitted)."""
    recording = write_recording(tmp_path / "live.tact",
                                make_frames(contact_path(frames), seed=11), period_s)
    return f"replay://{recording}?speed={1.0 / PACE:g}"


def test_sigkilled_worker_is_replaced_within_a_second(tmp_path: Path, arun) -> None:
    overrides = {"sensor[0].url": live_stream(tmp_path, 700),
                 "sensor[0].reuse_unchanged": False, "sensor[0].model": "cylinder"}

    async def main() -> tuple[list, dict, dict, float, float]:
        daemon = Daemon(load_settings(None, {}, overrides))
        estimates = collect(daemon)
        await daemon.start()
        pool = daemon.pool
        t0 = time.monotonic()
        while sum(e.gate == "fit" for e in estimates) < 10:
            assert time.monotonic() - t0 < 60.0, "fewer than 10 fits"
            await asyncio.sleep(0.002)
        while not pool.busy_pids():  # kill it mid-fit
            assert time.monotonic() - t0 < 60.0, "no worker busy"
            await asyncio.sleep(0)
        victim = pool.busy_pids()[0]
        killed_at = time.monotonic()
        os.kill(victim, signal.SIGKILL)
        while not (pool.restarts == 1 and pool.stats()["workers"][0]["state"] == "ready"):
            assert time.monotonic() - killed_at < 5.0, "no replacement worker"
            await asyncio.sleep(0.002)
        replaced_in = time.monotonic() - killed_at
        assert pool.pids()[0] != victim
        assert await daemon.wait_finished(30)
        st = daemon.stats("finger0")
        workers = daemon.stats()["workers"]
        await daemon.stop()
        return estimates, st, workers, killed_at, replaced_in

    estimates, st, workers, killed_at, replaced_in = arun(main())
    # replaced at once (a spawn: under a second here, seconds on a loaded machine), not after
    # a backoff
    assert replaced_in < 5.0, f"replacement ready after {replaced_in:.3f} s"
    assert workers["restarts"] == 1 and workers["restarts_by_reason"] == {"died": 1}
    assert workers["last_restart"]["spawned_s"] <= workers["last_restart"]["ready_s"] < 5.0
    assert st["worker_restarts"] == 1
    assert st["fit_failed"] <= 1  # the fit in flight is lost (unless it answered first)
    check_estimates(estimates, "finger0", 0)  # in order, consistent, strict JSON
    after = [e for e in estimates if e.gate == "fit" and e.published_time > killed_at + replaced_in]
    assert len(after) >= 5, "fitting did not resume"
    assert st["frames"] == accounted(st)


def test_hung_worker_is_killed_and_replaced(tmp_path: Path, arun, hookable_workers) -> None:
    # tracking off: every contact frame wants a fit of its own (the tracked case is in
    # test_sensor_tracking.py)
    overrides = {"sensor[0].url": live_stream(tmp_path, 500), "fit.timeout": 0.3,
                 "sensor[0].reuse_unchanged": False, "sensor[0].model": "cylinder",
                 "sensor[0].track": False}

    async def main() -> tuple[list, dict, dict, float, int]:
        daemon = Daemon(load_settings(None, {}, overrides))
        estimates = collect(daemon)
        await daemon.start()
        pool = daemon.pool
        sensor = daemon.sensors["finger0"]
        t0 = time.monotonic()
        while sum(e.gate == "fit" for e in estimates) < 5:
            assert time.monotonic() - t0 < 60.0, "fewer than 5 fits"
            await asyncio.sleep(0.002)
        superseded_before = sensor.superseded
        hung_at = time.monotonic()
        victim = hang(pool, 0, 30.0)  # the fit queued behind it never gets answered
        assert victim is not None
        while pool.restarts == 0:
            assert time.monotonic() - hung_at < 3.0, "hung worker not noticed"
            await asyncio.sleep(0.005)
        noticed = time.monotonic() - hung_at
        superseded_during = sensor.superseded - superseded_before
        assert await daemon.wait_finished(30)
        st = daemon.stats("finger0")
        workers = daemon.stats()["workers"]
        await daemon.stop()
        return estimates, st, workers, noticed, superseded_during

    estimates, st, workers, noticed, superseded_during = arun(main())
    # at fit.timeout (0.3 s), not before; after it by a ping and a loaded machine's margin
    assert 0.3 <= noticed < 0.3 + 1.5, f"hang noticed after {noticed:.3f} s"
    assert workers["restarts_by_reason"] == {"hung": 1}
    # replaced at once (a spawn, seconds on a loaded machine), not after a backoff
    assert workers["last_restart"]["ready_s"] < 5.0
    assert st["fit_failed"] == 1  # the fit queued behind the hang
    assert superseded_during > 10  # frames kept coming and replaced each other: no queue
    check_estimates(estimates, "finger0", 0)
    assert sum(e.gate == "fit" for e in estimates if e.seq > SETTLE_FRAMES + 200) >= 5
    assert st["frames"] == accounted(st)


class Owner:
    """A minimal JobOwner: hands out given strain frames, keeps the answers."""

    name = "owner"

    def __init__(self, spec: int) -> None:
        self.spec = spec
        self.todo: list[np.ndarray] = []
        self.since = time.monotonic()
        self.results: list[tuple[dict[str, Any] | None, str | None]] = []
        self.failed: list[str] = []

    def job_waiting_since(self) -> float | None:
        return self.since if self.todo else None

    background = False  # its jobs answer no frame (as the tracker's relinearisations)
    taken: list[str] | None = None  # where take_job notes the order jobs left, if given

    def job_background(self) -> bool:
        return self.background

    def take_job(self) -> FitJob:
        if self.taken is not None:
            self.taken.append(self.name)
        return FitJob(owner=self, ordinal=len(self.results), seq=0, strain=self.todo.pop(0),
                      model="auto", spec=self.spec)

    def on_fit_result(self, job, fit, worker_ms, error, warm=None, lin=None) -> None:
        self.results.append((fit, error))

    def on_fit_failed(self, job, reason) -> None:
        self.failed.append(reason)


def test_worker_answers_nan_and_malformed_frames_and_survives(arun) -> None:
    clean = clean_strain()
    with_nan = clean.copy()
    with_nan[3, 3] = np.nan
    with_nan[0, :] = np.inf
    all_nan = np.full((8, 8), np.nan)
    wrong_shape = np.zeros((3, 5))

    async def main() -> Owner:
        pool = WorkerPool(1, FitSettings())
        owner = Owner(pool.register_spec(DEFAULT_SENSOR, (("window", 4),)))
        pool.attach(owner)
        await pool.start()
        owner.todo = [with_nan, all_nan, wrong_shape, clean]
        pool.wake()
        t0 = time.monotonic()
        while len(owner.results) < 4:
            assert time.monotonic() - t0 < 10
            await asyncio.sleep(0.005)
        restarts = pool.restarts
        await pool.stop()
        assert restarts == 0
        return owner

    owner = arun(main())
    (nan_fit, e1), (empty_fit, e2), (bad, error), (good, e4) = owner.results
    assert e1 is None and e2 is None and e4 is None
    for fit in (nan_fit, empty_fit, good):
        strict_json(fit)
    assert nan_fit["contact"] and abs(nan_fit["x_mm"] - 11.0) < 0.5
    assert empty_fit["contact"] is False
    assert bad is None and "ValueError" in error and "shape" in error
    assert good["r1_mm"] is not None and abs(good["r1_mm"] - 10.0) < 1.0


def test_a_frame_waiting_for_its_fit_goes_before_background_work(arun) -> None:
    """With one worker, a relinearisation that has waited longer still goes after every
    frame's fit (a frame that waits past 5 ms is published with a prediction); among frames,
    the longest-waiting first."""
    clean = clean_strain()

    async def main() -> list[str]:
        pool = WorkerPool(1, FitSettings())
        spec = pool.register_spec(DEFAULT_SENSOR, (("window", 4),))
        taken: list[str] = []
        now = time.monotonic()
        owners = []
        for name, since, background in (("lin", now - 3.0, True), ("late", now - 1.0, False),
                                        ("early", now - 2.0, False)):
            o = Owner(spec)
            o.name, o.since, o.background, o.taken, o.todo = name, since, background, taken, [clean]
            pool.attach(o)
            owners.append(o)
        await pool.start()
        t0 = time.monotonic()
        while sum(len(o.results) for o in owners) < 3:
            assert time.monotonic() - t0 < 10, "fits not answered"
            await asyncio.sleep(0.005)
        await pool.stop()
        return taken

    assert arun(main()) == ["early", "late", "lin"]


def clean_strain() -> np.ndarray:
    """The strain of the tests' press: a 10 mm cylinder at 1 N across the finger's centre."""
    return predict_strain(Contact(10.0, float("inf"), 90.0, 1.0, 11.0, 13.0))


def pool_of_owners(size: int, owners: tuple[tuple[str, bool], ...]
                   ) -> tuple[WorkerPool, dict[str, Owner], list[str]]:
    """A pool of ``size`` workers serving an :class:`Owner` per ``(name, background)``, which
    note in one list the order their jobs leave (not started)."""
    pool = WorkerPool(size, FitSettings())
    spec = pool.register_spec(DEFAULT_SENSOR, (("window", 4),))
    taken: list[str] = []
    made = {}
    for name, background in owners:
        o = Owner(spec)
        o.name, o.background, o.taken = name, background, taken
        pool.attach(o)
        made[name] = o
    return pool, made, taken


def test_a_frame_dispatched_now_leaves_before_the_callbacks_the_loop_holds(arun) -> None:
    """``dispatch_now`` hands a waiting job to a free worker within the call: a frame's fit does
    not wait behind the other sensors' reads already queued on the loop (``wake`` only queues
    a dispatch, after them)."""
    clean = clean_strain()

    async def main() -> tuple[list[str], list[str]]:
        pool, owners, order = pool_of_owners(1, (("woken", False), ("now", False)))
        await pool.start()
        loop = asyncio.get_running_loop()
        queued: list[str] = []
        # a job queued by wake() leaves only after what the loop already holds ...
        owners["woken"].todo.append(clean)
        loop.call_soon(lambda: queued.append("another sensor's read"))
        pool.wake()
        loop.call_soon(lambda: queued.append(f"taken: {order}"))
        await asyncio.sleep(0.01)
        while len(owners["woken"].results) < 1:
            await asyncio.sleep(0.005)
        # ... one dispatched now is in its worker's hands before the call returns
        owners["now"].todo.append(clean)
        pool.dispatch_now()
        at_once = list(order)
        while len(owners["now"].results) < 1:
            await asyncio.sleep(0.005)
        await pool.stop()
        return queued, at_once

    queued, at_once = arun(main())
    assert queued == ["another sensor's read", "taken: ['woken']"]
    assert at_once == ["woken", "now"]


def test_a_waiting_job_goes_to_the_worker_that_answers_before_the_loop_moves_on(arun) -> None:
    """When a worker answers, the job waiting for it (another sensor's frame) is in its hands
    before the loop runs any other callback: it does not wait behind the reads the loop holds."""
    clean = clean_strain()

    async def main() -> tuple[list[str], list[str]]:
        pool, owners, order = pool_of_owners(1, (("first", False), ("second", False)))
        await pool.start()
        loop = asyncio.get_running_loop()
        seen: list[str] = []
        answered = owners["first"].on_fit_result

        def on_result(*args: Any, **kwargs: Any) -> None:
            answered(*args, **kwargs)
            # what the loop runs next after this answer: another sensor's read, say
            loop.call_soon(lambda: seen.append(f"taken: {order}"))

        owners["first"].on_fit_result = on_result  # type: ignore[method-assign]
        owners["first"].todo.append(clean)
        pool.dispatch_now()
        owners["second"].todo.append(clean)
        pool.dispatch_now()  # the one worker is busy: the second job waits
        waiting = list(order)
        t0 = time.monotonic()
        while len(owners["second"].results) < 1:
            assert time.monotonic() - t0 < 10, "fits not answered"
            await asyncio.sleep(0.005)
        await pool.stop()
        return waiting, seen

    waiting, seen = arun(main())
    assert waiting == ["first"]
    assert seen == ["taken: ['first', 'second']"]


def test_the_last_free_worker_is_kept_for_a_frame(arun) -> None:
    """With more than one worker, relinearisations (jobs that answer no frame) never take the
    last free one: two wait and two workers are free, one goes out; a frame's fit that comes
    next finds the other worker at once, not behind a relinearisation."""
    clean = clean_strain()

    async def main() -> tuple[list[str], list[str]]:
        pool, owners, taken = pool_of_owners(2, (("lin1", True), ("lin2", True), ("frame", False)))
        await pool.start()
        owners["lin1"].todo.append(clean)
        owners["lin2"].todo.append(clean)
        pool.dispatch_now()
        first = list(taken)
        owners["frame"].todo.append(clean)
        pool.dispatch_now()
        second = list(taken)
        while sum(len(o.results) for o in owners.values()) < 3:
            await asyncio.sleep(0.005)
        await pool.stop()
        return first, second

    first, second = arun(main())
    assert len(first) == 1 and first[0] in ("lin1", "lin2")
    assert second == [*first, "frame"]


def test_a_fitter_that_cannot_be_built_costs_its_fits_not_the_worker(arun) -> None:
    """A spec whose Fitter raises when built (a noise sigma so small its weights divide by
    zero; settings refuse it, but a worker must not depend on that) is registered before the
    pool starts and after: the worker still becomes ready, that spec's fits answer with the
    build error, and the healthy spec is fitted by the same worker, with no restart."""
    import dataclasses

    from tactiled.sensors.model import NoiseModel

    broken = dataclasses.replace(DEFAULT_SENSOR, noise=NoiseModel(sigma=1e-300, quantum=0.0))
    clean = clean_strain()

    async def main() -> tuple[Owner, Owner, Owner, int]:
        pool = WorkerPool(1, FitSettings(startup_timeout=20.0))
        bad_at_start = Owner(pool.register_spec(broken, (("window", 4),)))
        good = Owner(pool.register_spec(DEFAULT_SENSOR, (("window", 4),)))
        for owner in (bad_at_start, good):
            pool.attach(owner)
        await pool.start()
        bad_later = Owner(pool.register_spec(broken, (("window", 3),)))
        pool.attach(bad_later)
        bad_at_start.todo, good.todo, bad_later.todo = [clean], [clean, clean], [clean]
        pool.wake()
        t0 = time.monotonic()
        while len(bad_at_start.results) + len(good.results) + len(bad_later.results) < 4:
            assert time.monotonic() - t0 < 20, "fits not answered"
            await asyncio.sleep(0.005)
        restarts = pool.restarts
        await pool.stop()
        return bad_at_start, good, bad_later, restarts

    bad_at_start, good, bad_later, restarts = arun(main())
    assert restarts == 0
    for owner in (bad_at_start, bad_later):
        ((fit, error),) = owner.results
        assert fit is None and "ZeroDivisionError" in error, error
    assert "building it failed" in bad_at_start.results[0][1]
    for fit, error in good.results:
        assert error is None and abs(fit["r1_mm"] - 10.0) < 1.0


def test_the_leak_check_sees_a_worker_left_running(arun) -> None:
    """The autouse fixture's check must be able to fail: a started pool is seen alive."""

    async def main() -> None:
        pool = WorkerPool(1, FitSettings())
        await pool.start()
        pids = [p for p in pool.pids() if p]
        assert pids and leftover(pids, grace=0.0) == pids
        await pool.stop()
        assert leftover(pids) == []

    arun(main())


def test_two_fingers_of_one_model_never_share_a_fitter() -> None:
    """A fitter learns its finger (the model-error floor, the flat field): fingers with one
    sensor model get a fitter each, and one finger keeps its own across registrations."""
    pool = WorkerPool(1, FitSettings())
    a = pool.register_spec(DEFAULT_SENSOR, (("window", 4),), "left")
    b = pool.register_spec(DEFAULT_SENSOR, (("window", 4),), "right")
    assert a != b
    assert pool.register_spec(DEFAULT_SENSOR, (("window", 4),), "left") == a
    assert pool.specs[a] == pool.specs[b] == (DEFAULT_SENSOR, (("window", 4),))


def test_workers_run_without_a_blas_thread_pool(tmp_path) -> None:
    """A worker fits one frame at a time beside the others: its BLAS must not start threads
    that spin on their cores.  Checked in the environment of a real worker's process (in a
    fresh interpreter: the forkserver is one per process and reads it when it starts)."""
    import subprocess
    import sys

    script = tmp_path / "pool_env.py"
    script.write_text(
        "import asyncio, os\n"
        "from tactiled.pipeline.pool import WorkerPool\n"
        "from tactiled.pipeline.supervision import BLAS_THREADS\n"
        "from tactiled.settings import FitSettings\n"
        "async def main():\n"
        "    pool = WorkerPool(1, FitSettings())\n"
        "    await pool.start()\n"
        "    pid = pool.stats()['workers'][0]['pid']\n"
        "    env = dict(v.split(b'=', 1) for v in open(f'/proc/{pid}/environ', 'rb').read().split(b'\\0') if b'=' in v)\n"
        "    await pool.stop()\n"
        "    print(' '.join(env.get(n.encode(), b'-').decode() for n in BLAS_THREADS))\n"
        "if __name__ == '__main__':\n"
        "    asyncio.run(main())\n")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120, env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["1", "1", "1"], out.stdout


def test_a_worker_answer_that_does_not_unpickle_replaces_the_worker(arun,
                                                                    hookable_workers) -> None:
    """An answer this process cannot read (bytes that are no pickle; a worker of other code,
    an upgrade under a running daemon, would send one) costs that worker, counted as a
    protocol loss, not the event loop's callback: the replacement answers the next fit."""
    clean = clean_strain()

    async def main() -> tuple[int | None, dict[str, int], list[int | None], Owner]:
        pool = WorkerPool(1, FitSettings())
        owner = Owner(pool.register_spec(DEFAULT_SENSOR, (("window", 4),)))
        pool.attach(owner)
        await pool.start()
        pid = garble(pool, 0)
        t0 = time.monotonic()
        while pool.restarts == 0:
            assert time.monotonic() - t0 < 5, "the unreadable answer went unnoticed"
            await asyncio.sleep(0.005)
        assert await pool.wait_ready(10.0)
        owner.todo = [clean]
        pool.wake()
        while not owner.results:
            assert time.monotonic() - t0 < 15, "the replacement answered no fit"
            await asyncio.sleep(0.005)
        pids = pool.pids()
        reasons = dict(pool.restarts_by_reason)
        await pool.stop()
        return pid, reasons, pids, owner

    pid, reasons, pids, owner = arun(main())
    assert pid is not None and pids != [pid]
    assert reasons == {"protocol": 1}
    (fit, error), = owner.results
    assert error is None and fit["contact"]

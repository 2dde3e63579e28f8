"""The pool of fit worker processes, seen from the event loop: which job goes to which worker.

One pool serves every sensor of the daemon (``fit.workers`` processes, by default
``min(sensors, CPUs)``); docs/concepts/pipeline.md gives the reasons.  Keeping the processes
alive (deadlines, pings, restarts, recycling) is :mod:`tactiled.pipeline.supervision`'s part.
"""

# A sensor (a :class:`JobOwner`) decides what it offers: the pipeline keeps at most one frame's
# fit in flight (its results come back in order) and beside it at most one background job; the
# pool hands a free worker to the sensor whose waiting frame is oldest, background jobs last, and
# with more than one worker never the last free one to a background job (a frame's fit may come
# next).

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import time
from typing import Any

from tactiled.pipeline.jobs import FitJob, JobOwner
from tactiled.pipeline.worker_packing import pack_array
from tactiled.pipeline.supervision import WorkerSupervision
from tactiled.sensors.model import SensorModel
from tactiled.settings import FitSettings

#: Share of ``fit.timeout`` a fit may spend before the fitter stops itself (its time budget);
#: the rest is margin for one last evaluation and the answer, so the worker is not killed.
FIT_BUDGET_FRACTION = 0.5

log = logging.getLogger(__name__)


class WorkerPool(WorkerSupervision):
    """``size`` fit worker processes shared by the sensors ``attach``-ed to it."""

    def __init__(self, size: int, settings: FitSettings | None = None) -> None:
        super().__init__(size, settings)
        self._spec_ids: dict[tuple[SensorModel, Any, str], int] = {}
        self._owners: list[JobOwner] = []
        self._dispatch_pending = False
        self.fits = 0

    # -- set-up -------------------------------------------------------------------------------

    def register_spec(self, sensor: SensorModel, options: tuple[tuple[str, Any], ...],
                      finger: str = "") -> int:
        """An id for a SensorModel and ``FitOptions`` keyword arguments (``(("window", 4),)``),
        which the workers turn into a Fitter.  ``finger`` names whose frames it fits: a
        fitter learns its finger's departure from the model (tactiled.fit.floor,
        tactiled.fit.flatfield), so two fingers with one model never share a fitter."""
        key = (sensor, options, finger)
        spec = self._spec_ids.get(key)
        if spec is None:
            spec = len(self._spec_ids)
            self._spec_ids[key] = spec
            self.specs[spec] = (sensor, options)
        return spec

    def attach(self, owner: JobOwner) -> None:
        """Serve ``owner``'s fit jobs from now on."""
        self._owners.append(owner)

    async def start(self, wait_ready: bool = True) -> None:
        """Start the workers; with ``wait_ready``, return once all are ready to fit (or after
        ``fit.startup_timeout``, logging the ones that are not)."""
        if self._started:
            raise RuntimeError("worker pool already started")
        self._started = True
        self._loop = asyncio.get_running_loop()
        self._executor = concurrent.futures.ThreadPoolExecutor(
            max_workers=1, thread_name_prefix="tactiled-spawn")
        for w in self._workers:
            self._spawn_task(w.slot, 0.0, None)
        self._supervisor = asyncio.create_task(self._supervise(), name="tactiled-pool-supervisor")
        if wait_ready:
            await self.wait_ready(self.settings.startup_timeout)

    async def wait_ready(self, timeout: float) -> bool:
        """Wait until every worker is ready (True) or ``timeout`` seconds pass (False)."""
        deadline = time.monotonic() + timeout
        while not all(w.state == "ready" for w in self._workers):
            remaining = deadline - time.monotonic()
            if remaining <= 0 or self._stopping:
                log.warning("fit workers not ready after %.1f s: %s", timeout,
                            [w.state for w in self._workers])
                return False
            self._ready.clear()
            try:
                await asyncio.wait_for(self._ready.wait(), remaining)
            except TimeoutError:
                pass
        return True

    # -- dispatching -----------------------------------------------------------------------------

    def _on_result(self, job: FitJob, msg: tuple[Any, ...], now: float) -> None:
        """A worker's ``result`` answer to ``job``: count it and hand it to its sensor."""
        self.fits += 1
        _, _, fit, _compute_s, error, warm, lin = msg
        job.owner.on_fit_result(job, fit, (now - job.sent_at) * 1e3, error, warm, lin)

    def wake(self) -> None:
        """Hand waiting jobs to free workers soon (once per loop iteration, so a burst of
        frames from one read is dispatched once, newest first)."""
        if not self._dispatch_pending and self._loop is not None and not self._stopping:
            self._dispatch_pending = True
            self._loop.call_soon(self._dispatch)

    def dispatch_now(self) -> None:
        """Hand waiting jobs to free workers at once, not after the callbacks the loop already
        holds (a frame's fit: those are other sensors' reads, ~0.5 ms at the median with three
        fingers at 1 kHz, and several at the 90th percentile)."""
        if self._loop is not None and not self._stopping:
            self._dispatch()

    def _dispatch(self) -> None:
        self._dispatch_pending = False
        free = [w for w in self._workers if w.state == "ready" and w.job is None]
        for n, w in enumerate(free):
            # frames before background work, then the longest-waiting first: fairness
            waiting = [(o.job_background(), t, i) for i, o in enumerate(self._owners)
                       if (t := o.job_waiting_since()) is not None]
            if not waiting:
                return
            background, _, first = min(waiting)
            if background and self.size > 1 and n == len(free) - 1:
                # the last free worker is kept for a frame's fit: a relinearisation there
                # would make the next frame to leave its linear range wait for it
                return
            owner = self._owners[first]
            job = owner.take_job()
            if job.spec not in w.known_specs:
                sensor, options = self.specs[job.spec]
                w.known_specs.add(job.spec)
                if not self._send(w, ("setup", job.spec, sensor, options), "setup",
                                  self.settings.startup_timeout):
                    job.owner.on_fit_failed(job, "died")
                    continue
            job.sent_at = time.monotonic()
            w.job = job
            # The fitter stops itself at half the deadline (FIT_BUDGET_FRACTION), so a frame
            # far outside the model costs a non-converged estimate, not a killed worker.
            budget = FIT_BUDGET_FRACTION * self.settings.timeout
            if not self._send(w, ("fit", job.spec, pack_array(job.strain), job.model,
                                  pack_array(job.mask), job.warm, budget, job.kind), "fit",
                              self.settings.timeout, job):
                continue  # _lose has failed the job already

    # -- reporting --------------------------------------------------------------------------------

    def pids(self) -> list[int | None]:
        """The current worker processes' pids, by slot (None while one is being started)."""
        return [w.pid if w.state in ("starting", "ready") else None for w in self._workers]

    def process_pids(self) -> list[int]:
        """Pids of every worker process alive now: the slots' workers, successors being
        started and recycled workers not yet gone."""
        return [w.pid for w in self._all() if w.pid is not None and w.alive]

    def busy_pids(self) -> list[int]:
        """Pids of workers fitting right now."""
        return [w.pid for w in self._all() if w.busy and w.pid is not None]

    def request_memory(self) -> int:
        """Ask every ready worker where its memory is (answered after the fit it holds, into
        :meth:`stats`' ``memory`` per worker); returns how many were asked.  A worker that
        does not answer within ``fit.timeout + fit.ping_timeout`` of being free to (the
        figures take a few ms; a starved machine can take longer) counts as hung."""
        asked = 0
        deadline = self.settings.timeout + self.settings.ping_timeout
        for w in self._workers:
            if w.state == "ready" and w.conn is not None and not any(
                    r.kind == "memory" for r in w.outstanding):
                asked += self._send(w, ("memory",), "memory", deadline)
        return asked

    def stats(self) -> dict[str, Any]:
        """Worker states and counters, JSON-ready (times in seconds)."""
        now = time.monotonic()
        return {
            "size": self.size,
            "start_method": self.settings.start_method,
            "fits": self.fits,
            "restarts": self.restarts,
            "deadline_extended": self.deadline_extended,
            "restarts_by_reason": dict(self.restarts_by_reason),
            "last_restart": None if self.last_restart is None else {
                k: v for k, v in self.last_restart.items() if k != "lost_at"},
            "max_fits_per_worker": self.settings.max_fits_per_worker,
            "recycles": self.recycles,
            "last_recycle": None if self.last_recycle is None else {
                "slot": self.last_recycle["slot"], "old_pid": self.last_recycle["old_pid"],
                "new_pid": self.last_recycle["new_pid"],
                "old_fits": self.last_recycle["old_fits"],
                "old_stopped_s": (None if self.last_recycle["old_stopped_at"] is None else
                                  self.last_recycle["old_stopped_at"]
                                  - self.last_recycle["successor_ready_at"])},
            "workers": [
                {"slot": w.slot, "pid": w.pid, "state": w.state, "busy": w.busy,
                 "fits": w.fits, "uptime_s": None if w.ready_at is None else now - w.ready_at,
                 "memory": w.memory,
                 "memory_age_s": None if w.memory_at is None else now - w.memory_at}
                for w in self._workers
            ],
            "recycling": [{"slot": w.slot, "pid": w.pid, "state": w.state, "fits": w.fits}
                          for w in (*self._successors.values(), *self._retiring)],
        }

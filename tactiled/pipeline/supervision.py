"""The fit worker processes' supervision: starting, deadlines, pings, restarts, recycling."""

# :class:`WorkerSupervision` is the half of :class:`~tactiled.pipeline.pool.WorkerPool` that keeps
# its processes alive (the other half, in ``pool.py``, hands them jobs).  Nothing here blocks the
# loop:
#
# * answers arrive through ``loop.add_reader`` on each worker's Connection, and a death through
#   ``add_reader`` on the process sentinel, so a SIGKILLed worker is noticed at once;
# * process starts run in a one-thread executor (the first one waits for the forkserver to
#   import and warm up, about 2 s);
# * every request has a deadline, counted from when the worker could start on it (it answers in
#   order), and a supervisor task ticking every 50 ms kills (SIGKILL) a worker that misses one:
#   a fit must answer within ``fit.timeout``, an idle worker is pinged every
#   ``fit.ping_interval`` and must answer within ``fit.ping_timeout`` (as uvicorn's supervisor
#   pings its workers), a new one must be ready within ``fit.startup_timeout``;
# * a lost worker is replaced at once; one that keeps dying before it answers a single fit is
#   restarted with backoff (0.1 s doubling to 5 s), so a crash loop cannot eat the CPU the other
#   workers need;
# * with ``fit.max_fits_per_worker`` set (a safety net, off by default), a worker that has
#   answered that many fits is *recycled*: a successor is started beside it, and only once the
#   successor is ready does the old one stop taking fits; it finishes the fit it holds (whose
#   result is delivered as usual), is told to stop and is reaped.  No fit is lost, and the slot
#   always has a ready worker (``WorkerPool.stats()["last_recycle"]``).

from __future__ import annotations

import asyncio
import concurrent.futures
import importlib
import logging
import multiprocessing
import os
import select
import time
from collections import deque
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from typing import Any

from tactiled.pipeline.jobs import FitJob
from tactiled.pipeline.worker_packing import dumps
from tactiled.sensors.model import SensorModel
from tactiled.settings import FitSettings

log = logging.getLogger(__name__)

PRELOAD_MODULE = "tactiled.pipeline.preload"
TICK = 0.05  # s, supervisor period: the resolution of hang detection
BACKOFF_MIN, BACKOFF_MAX = 0.1, 5.0  # s, restart delays of a worker that keeps dying young
YOUNG = 2.0  # s, a worker lost this soon after being ready, before any fit, counts as failing
#: A worker past a request's deadline that is runnable yet got less than this share of a core
#: since the deadline is starved (a machine loaded by other processes), not hung: it gets
#: another deadline, up to ``STARVED_MAX_S`` past its first.  One asleep, stopped or blocked
#: (a deadlock, a ``sleep``) or computing at full speed through the extension is hung.
STARVED_CPU_SHARE = 0.5
STARVED_MAX_S = 10.0
_CLK_TCK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def cpu_state(pid: int) -> tuple[float, str] | None:
    """A process's CPU time (user + system, s) and scheduler state (``"R"`` runnable, ``"S"``
    asleep, ...), from Linux's ``/proc/PID/stat``; None where it cannot be read."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            data = f.read()
        rest = data.rsplit(b")", 1)[1].split()
        return (int(rest[11]) + int(rest[12])) / _CLK_TCK, rest[0].decode()
    except (OSError, IndexError, ValueError):
        return None


#: pid of every worker process any pool started (for tests that check none is left alive).
SPAWNED_PIDS: list[int] = []


@dataclass
class _Request:
    kind: str
    rid: int
    timeout: float
    job: FitJob | None = None



@dataclass
class _Worker:
    slot: int
    #: spawning -> starting -> ready -> (retiring: recycled, finishing its fit) -> stopping | dead
    state: str = "spawning"
    process: BaseProcess | None = None
    conn: Connection | None = None
    #: ``conn``'s descriptor in a poll object of its own: whether another answer is waiting,
    #: asked after each one (``Connection.poll`` builds a selector at every call)
    readable: Any = None
    pid: int | None = None
    exited: asyncio.Future[int | None] | None = None
    outstanding: deque[_Request] = field(default_factory=deque)
    head_since: float = 0.0  # when the oldest outstanding request became the worker's to do
    last_answer: float = 0.0
    started_at: float = 0.0
    ready_at: float | None = None
    known_specs: set[int] = field(default_factory=set)
    job: FitJob | None = None
    fits: int = 0
    #: earliest monotonic time a successor may be started for it (after a failed one)
    recycle_after: float = 0.0
    #: the worker's last answer to a ``memory`` request (``tactiled.heapstats``), and when
    memory: dict[str, Any] | None = None
    memory_at: float | None = None
    #: (request id, CPU s, monotonic s at the last extension, first deadline) while a request
    #: runs past its deadline on a starved worker (``STARVED_CPU_SHARE``)
    overdue: tuple[int, float, float, float] | None = None

    @property
    def busy(self) -> bool:
        return self.job is not None

    @property
    def alive(self) -> bool:
        """Its process runs (or is being started) and the pool still owns it."""
        return self.state in ("spawning", "starting", "ready", "retiring")


#: The environment variables that size the BLAS libraries' thread pools (OpenBLAS, OpenMP, MKL).
BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


class WorkerSupervision:
    """The worker processes of a :class:`~tactiled.pipeline.pool.WorkerPool`, kept alive."""

    #: The function each worker process runs, as ``"module:function"`` (imported when a
    #: worker starts; the tests substitute a worker that also obeys their test hooks).
    worker_main = "tactiled.pipeline.worker:worker_main"

    def __init__(self, size: int, settings: FitSettings | None = None) -> None:
        if size < 1:
            raise ValueError(f"a worker pool needs at least one worker, got {size}")
        self.size = size
        self.settings = settings or FitSettings()
        self._ctx = multiprocessing.get_context(self.settings.start_method)
        # A worker fits one frame at a time beside the other workers and the daemon: a BLAS
        # thread pool in it only spins on the cores they need (a learning fitter's 192 x 192
        # solves cost it 3 times its own CPU).  Read by the forkserver or spawned child at its
        # start; a value the user set is kept.
        for name in BLAS_THREADS:
            os.environ.setdefault(name, "1")
        if self.settings.start_method == "forkserver":
            # Only effective before the forkserver first starts (it is one per process).
            # '__main__' first, as multiprocessing does by default: a child re-imports the main
            # module unless the forkserver already has (so it must be import-safe, guarded by
            # ``if __name__ == "__main__"``); imported once there, no restart pays for it.
            self._ctx.set_forkserver_preload(["__main__", PRELOAD_MODULE])
        #: the fitters' specs by id (:meth:`WorkerPool.register_spec`): every new worker gets all
        self.specs: dict[int, tuple[SensorModel, Any]] = {}
        self._workers: list[_Worker] = [_Worker(slot) for slot in range(size)]
        #: recycling: the successor being started for a slot, and the workers it replaced
        #: that are finishing their last fit or exiting
        self._successors: dict[int, _Worker] = {}
        self._retiring: list[_Worker] = []
        self._failures = [0] * size  # consecutive young deaths per slot
        self._rid = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._executor: concurrent.futures.ThreadPoolExecutor | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._supervisor: asyncio.Task[None] | None = None
        self._ready = asyncio.Event()
        self._started = False
        self._stopping = False
        self.restarts = 0
        #: deadlines extended for a starved worker (``_starved``)
        self.deadline_extended = 0
        self.restarts_by_reason: dict[str, int] = {}
        self.last_restart: dict[str, Any] | None = None
        self.recycles = 0
        self.last_recycle: dict[str, Any] | None = None

    # -- what the dispatcher (WorkerPool) provides -----------------------------------------------

    def wake(self) -> None:
        """Hand waiting jobs to free workers soon (a worker became free or ready)."""

    def dispatch_now(self) -> None:
        """Hand waiting jobs to free workers at once (a worker has just answered)."""

    def _on_result(self, job: FitJob, msg: tuple[Any, ...], now: float) -> None:
        """A worker answered ``job`` with ``msg``, a ``result``."""

    # -- process lifecycle ----------------------------------------------------------------------

    def _spawn_task(self, slot: int, delay: float, old: _Worker | None,
                    successor: _Worker | None = None) -> None:
        self._track(self._respawn(slot, delay, old, successor), f"tactiled-spawn-{slot}")

    def _track(self, coro: Any, name: str) -> None:
        task = asyncio.create_task(coro, name=name)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _respawn(self, slot: int, delay: float, old: _Worker | None,
                       successor: _Worker | None = None) -> None:
        """Start a worker process for ``slot``: the slot's worker (replacing ``old``, reaped
        first), or, given ``successor`` (already registered), the slot's successor."""
        if old is not None:
            await self._reap(old, 1.0)
        if delay > 0:
            await asyncio.sleep(delay)
        if self._stopping:
            if successor is not None:
                self._successors.pop(slot, None)
            return
        if successor is not None:
            w = successor
        else:
            w = _Worker(slot)
            self._workers[slot] = w
        parent_conn, child_conn = self._ctx.Pipe(duplex=True)
        module, _, name = self.worker_main.partition(":")
        worker_main = getattr(importlib.import_module(module), name)
        process = self._ctx.Process(target=worker_main, args=(child_conn, dict(self.specs)),
                                    name=f"tactiled-fit-{slot}", daemon=True)
        known = set(self.specs)
        assert self._loop is not None and self._executor is not None
        try:
            # Never cancelled half-way: a cancelled await would lose the handle of a process
            # the executor thread still starts.
            await asyncio.shield(self._loop.run_in_executor(self._executor, process.start))
        except Exception as err:  # e.g. the forkserver could not start
            log.error("cannot start fit worker %d: %s", slot, err)
            parent_conn.close()
            w.state = "dead"
            self._failures[slot] += 1
            if self._successors.get(slot) is w:
                self._successor_failed(w)
            elif not self._stopping:
                self._spawn_task(slot, self._backoff(slot), None)
            return
        finally:
            child_conn.close()  # the child has its own copy; ours would hide its EOF
        SPAWNED_PIDS.append(process.pid or 0)
        w.process, w.conn, w.pid = process, parent_conn, process.pid
        w.readable = select.poll()
        w.readable.register(parent_conn.fileno(), select.POLLIN)
        w.exited = self._loop.create_future()
        now = time.monotonic()
        w.started_at = w.last_answer = w.head_since = now
        w.known_specs = known
        w.state = "starting"
        self._loop.add_reader(parent_conn.fileno(), self._on_readable, w)
        self._loop.add_reader(process.sentinel, self._on_sentinel, w)
        if successor is None and self.last_restart is not None \
                and self.last_restart.get("slot") == slot \
                and self.last_restart.get("spawned_s") is None:
            self.last_restart["spawned_s"] = now - self.last_restart["lost_at"]
        log.info("fit worker %d %sstarted (pid %s)", slot,
                 "successor " if successor is not None else "", process.pid)
        if self._stopping:
            self._lose(w, "stopped", "pool stopping", count=False)

    def _backoff(self, slot: int) -> float:
        n = self._failures[slot]
        return 0.0 if n <= 1 else min(BACKOFF_MIN * 2 ** (n - 2), BACKOFF_MAX)

    def _detach(self, w: _Worker) -> None:
        """Stop watching the worker's connection and close it (the sentinel stays watched
        until the process has exited, so the exit is still noticed)."""
        if w.conn is not None:
            assert self._loop is not None
            try:
                self._loop.remove_reader(w.conn.fileno())
            except (OSError, ValueError):
                pass
            w.conn.close()
            w.conn = w.readable = None

    def _on_sentinel(self, w: _Worker) -> None:
        assert self._loop is not None and w.process is not None
        self._loop.remove_reader(w.process.sentinel)
        # The process has exited; exitcode reads its status without blocking.
        code = w.process.exitcode
        if w.exited is not None and not w.exited.done():
            w.exited.set_result(code)
        if w.state in ("starting", "ready", "retiring"):
            self._lose(w, "died", f"exit code {code}")

    def _lose(self, w: _Worker, reason: str, detail: str, count: bool = True) -> None:
        """The worker is gone or unusable: kill it, fail its job, schedule a replacement
        (for the slot's serving worker; a lost successor or retiring worker is not replaced:
        the slot has its worker)."""
        if w.state in ("dead", "stopping"):
            return
        was_ready_at = w.ready_at
        role = ("successor" if self._successors.get(w.slot) is w
                else "retiring" if w.state == "retiring" else "serving")
        w.state = "dead"
        self._detach(w)
        if w.process is not None and w.exited is not None and not w.exited.done():
            w.process.kill()  # SIGKILL: a hung worker may be stuck where SIGTERM can't reach
        job, w.job = w.job, None
        w.outstanding.clear()
        now = time.monotonic()
        if count:
            self.restarts += 1
            self.restarts_by_reason[reason] = self.restarts_by_reason.get(reason, 0) + 1
            self.last_restart = {"slot": w.slot, "pid": w.pid, "reason": reason,
                                 "detail": detail, "lost_at": now, "spawned_s": None,
                                 "ready_s": None}
            log.warning("fit worker %d (pid %s) %s: %s; restarting", w.slot, w.pid, reason,
                        detail)
        if job is not None:
            job.owner.on_fit_failed(job, reason)
        if role == "retiring":
            self._track(self._reap_retired(w), f"tactiled-reap-{w.slot}")
            self.wake()
            return
        # A worker lost before it ever answered a fit is a crash loop in the making (a bad
        # environment, a frame that kills the fitter): back off.  One that has been doing its
        # job (killed by the OOM killer, by hand) is replaced at once.
        young = was_ready_at is None or (w.fits == 0 and now - was_ready_at < YOUNG)
        self._failures[w.slot] = self._failures[w.slot] + 1 if young else 1
        if role == "successor":
            self._successor_failed(w)
            self._track(self._reap(w, 1.0), f"tactiled-reap-{w.slot}")
        elif (succ := self._successors.pop(w.slot, None)) is not None:
            # A successor is on its way: it becomes the slot's worker (ready when it is).
            self._workers[w.slot] = succ
            self._track(self._reap(w, 1.0), f"tactiled-reap-{w.slot}")
        elif not self._stopping:
            self._spawn_task(w.slot, self._backoff(w.slot), w)
        self.wake()

    # -- recycling (fit.max_fits_per_worker) ------------------------------------------------------

    def _maybe_recycle(self, w: _Worker, now: float) -> None:
        """Start a successor for ``w`` once it has answered ``max_fits_per_worker`` fits."""
        limit = self.settings.max_fits_per_worker
        if (not limit or w.fits < limit or w.state != "ready" or self._stopping
                or self._workers[w.slot] is not w or w.slot in self._successors
                or now < w.recycle_after):
            return
        succ = _Worker(w.slot)
        self._successors[w.slot] = succ
        log.info("fit worker %d (pid %s) answered %d fits (fit.max_fits_per_worker): starting "
                 "its successor", w.slot, w.pid, w.fits)
        self._spawn_task(w.slot, 0.0, None, successor=succ)

    def _successor_failed(self, succ: _Worker) -> None:
        """A successor could not be started or died before it was ready: the serving worker
        goes on, and a new successor is tried no sooner than the backoff."""
        if self._successors.get(succ.slot) is succ:
            del self._successors[succ.slot]
        serving = self._workers[succ.slot]
        serving.recycle_after = time.monotonic() + max(1.0, self._backoff(succ.slot))

    def _promote(self, succ: _Worker, now: float) -> None:
        """``succ`` is ready: it serves the slot from now on; the worker it replaces takes no
        new fit, finishes the one it holds, and is then told to stop."""
        old = self._workers[succ.slot]
        del self._successors[succ.slot]
        self._workers[succ.slot] = succ
        self.recycles += 1
        self.last_recycle = {"slot": succ.slot, "old_pid": old.pid, "new_pid": succ.pid,
                             "old_fits": old.fits, "successor_ready_at": now,
                             "old_stopped_at": None, "old_state": old.state}
        log.info("fit worker %d: successor pid %s ready, pid %s retires after %d fits",
                 succ.slot, succ.pid, old.pid, old.fits)
        if old.state == "ready":
            old.state = "retiring"
            self._retiring.append(old)
            if old.job is None:
                self._retire(old)

    def _retire(self, w: _Worker) -> None:
        """A retiring worker holds no fit any more: tell it to stop and reap it."""
        if self.last_recycle is not None and self.last_recycle.get("old_pid") == w.pid:
            self.last_recycle["old_stopped_at"] = time.monotonic()
        if w.conn is not None:
            try:
                w.conn.send(("stop",))
            except (OSError, ValueError):
                pass
        w.state = "stopping"
        w.outstanding.clear()
        self._detach(w)
        self._track(self._reap_retired(w), f"tactiled-retire-{w.slot}")

    async def _reap_retired(self, w: _Worker) -> None:
        """Wait for a retired worker to exit (``fit.stop_timeout``, then SIGKILL), reap it."""
        if w.process is not None and w.exited is not None and not w.exited.done():
            try:
                await asyncio.wait_for(asyncio.shield(w.exited), self.settings.stop_timeout)
            except TimeoutError:
                log.warning("retired fit worker %d (pid %s) did not exit; killing it", w.slot,
                            w.pid)
                w.process.kill()
        await self._reap(w, 2.0)
        if w in self._retiring:
            self._retiring.remove(w)

    async def _reap(self, w: _Worker, timeout: float) -> None:
        """Wait (up to ``timeout`` s) for the process to exit, then release its resources."""
        if w.process is None:
            return
        if w.exited is not None and not w.exited.done():
            try:
                await asyncio.wait_for(asyncio.shield(w.exited), timeout)
            except TimeoutError:
                log.error("fit worker %d (pid %s) did not exit after SIGKILL", w.slot, w.pid)
                return
        try:
            w.process.close()
        except ValueError:  # still running by multiprocessing's books; leave it be
            pass

    # -- talking to workers -----------------------------------------------------------------------

    def _send(self, w: _Worker, message: tuple[Any, ...], kind: str, timeout: float,
              job: FitJob | None = None) -> bool:
        assert w.conn is not None
        now = time.monotonic()
        if not w.outstanding:
            w.head_since = now
        self._rid += 1
        w.outstanding.append(_Request(kind, self._rid, timeout, job))
        try:
            # Small messages on a socketpair, at most a few outstanding: never blocks.
            w.conn.send_bytes(dumps((message[0], self._rid, *message[1:])))
        except (OSError, ValueError) as err:
            w.outstanding.pop()
            self._lose(w, "died", f"send failed: {err}")
            return False
        return True

    def _on_readable(self, w: _Worker) -> None:
        try:
            while w.conn is not None and w.readable.poll(0):
                try:
                    msg = w.conn.recv()
                except (EOFError, OSError):
                    raise
                except Exception as err:  # noqa: BLE001 - a message this process cannot read
                    # (a worker of other code than this process's: an upgrade under a
                    # running daemon): the worker is replaced, its job counted as failed
                    self._lose(w, "protocol", f"unreadable answer: {type(err).__name__}: {err}")
                    return
                self._handle(w, msg)
        except (EOFError, OSError) as err:
            self._lose(w, "died", f"connection lost: {str(err) or type(err).__name__}")

    def _handle(self, w: _Worker, msg: tuple[Any, ...]) -> None:
        now = time.monotonic()
        w.last_answer = now
        kind = msg[0]
        if kind == "ready":
            w.state, w.ready_at, w.head_since = "ready", now, now
            w.pid = msg[1]
            if self._successors.get(w.slot) is w:
                self._promote(w, now)
            elif self.last_restart is not None and self.last_restart.get("slot") == w.slot \
                    and self.last_restart.get("ready_s") is None:
                self.last_restart["ready_s"] = now - self.last_restart["lost_at"]
            log.info("fit worker %d ready (pid %s, warm-up %.3f s)", w.slot, msg[1], msg[2])
            for spec, error in msg[3].items():
                log.error("fit worker %d: fitter setup failed for spec %d: %s", w.slot, spec,
                          error)
            self._ready.set()
            self.wake()
            return
        if not w.outstanding or w.outstanding[0].rid != msg[1]:
            self._lose(w, "protocol", f"unexpected answer {kind!r}")
            return
        req = w.outstanding.popleft()
        w.head_since = now
        if kind == "result":
            job, w.job = req.job, None
            assert job is not None
            w.fits += 1
            self._on_result(job, msg, now)
            if w.state == "retiring":
                self._retire(w)
            else:
                self._maybe_recycle(w, now)
            # the next waiting job goes to the worker now, not after the callbacks the loop
            # already holds (the other sensors' reads: a frame's fit queued behind another's
            # waited that much longer)
            self.dispatch_now()
        elif kind == "memory":
            w.memory, w.memory_at = msg[2], now
        elif kind == "setup_done" and msg[3] is not None:
            log.error("fit worker %d: fitter setup failed: %s", w.slot, msg[3])

    # -- supervision ------------------------------------------------------------------------------

    async def _supervise(self) -> None:
        s = self.settings
        while True:
            await asyncio.sleep(TICK)
            now = time.monotonic()
            for w in self._all():
                if w.state == "starting":
                    if now - w.started_at > s.startup_timeout:
                        self._lose(w, "startup", f"not ready within {s.startup_timeout:g} s")
                elif w.state in ("ready", "retiring"):
                    if w.outstanding:
                        head = w.outstanding[0]
                        if now - w.head_since > head.timeout and not self._starved(w, head, now):
                            self._lose(w, "hung", f"no answer to {head.kind!r} within "
                                                  f"{head.timeout:g} s")
                    elif w.state == "ready" and now - w.last_answer >= s.ping_interval:
                        self._send(w, ("ping",), "ping", s.ping_timeout)

    def _starved(self, w: _Worker, head: _Request, now: float) -> bool:
        """``w`` is past ``head``'s deadline because the machine gives it too little CPU, not
        because it hangs (``STARVED_CPU_SHARE``): its deadline is extended by one more
        ``head.timeout`` (counted ``deadline_extended``)."""
        st = cpu_state(w.pid) if w.pid is not None else None
        if st is None:
            return False
        cpu, state = st
        if w.overdue is None or w.overdue[0] != head.rid:
            if state != "R":
                return False
            w.overdue = (head.rid, cpu, now, now)
        else:
            _, cpu0, t0, first = w.overdue
            if (state != "R" or now - first > STARVED_MAX_S
                    or cpu - cpu0 >= STARVED_CPU_SHARE * (now - t0)):
                return False
            w.overdue = (head.rid, cpu, now, first)
        w.head_since = now
        self.deadline_extended += 1
        log.info("fit worker %d: %r past its %g s deadline, runnable but starved of CPU by "
                 "other processes: given %g s more", w.slot, head.kind, head.timeout, head.timeout)
        return True

    def _all(self) -> list[_Worker]:
        """Every worker the pool owns: the slots' workers, successors being started, and
        recycled workers finishing or exiting."""
        return [*self._workers, *self._successors.values(), *self._retiring]

    # -- stopping ---------------------------------------------------------------------------------

    async def stop(self, timeout: float | None = None) -> None:
        """Let in-flight fits finish (up to ``timeout`` s, default ``fit.stop_timeout``), ask the
        workers to exit, SIGKILL those that do not, and reap them all.  Idempotent."""
        if not self._started or self._stopping:
            return
        timeout = self.settings.stop_timeout if timeout is None else timeout
        deadline = time.monotonic() + timeout
        while any(w.busy for w in self._all()) and time.monotonic() < deadline:
            await asyncio.sleep(0.005)
        self._stopping = True
        if self._supervisor is not None:
            self._supervisor.cancel()
            await asyncio.gather(self._supervisor, return_exceptions=True)
        # Spawns under way finish (and see _stopping); they are never cancelled mid-start.
        if self._tasks:
            await asyncio.gather(*list(self._tasks), return_exceptions=True)
        everyone = self._all()
        for w in everyone:
            job, w.job = w.job, None
            if job is not None:
                job.owner.on_fit_failed(job, "stopped")
            if w.conn is not None and w.state in ("starting", "ready", "retiring"):
                try:
                    w.conn.send(("stop",))
                except (OSError, ValueError):
                    pass
            if w.state != "dead":
                w.state = "stopping"
            self._detach(w)
        pending = [w.exited for w in everyone if w.exited is not None and not w.exited.done()]
        if pending:
            await asyncio.wait(pending, timeout=max(0.0, deadline - time.monotonic()))
        for w in everyone:
            if w.process is not None and w.exited is not None and not w.exited.done():
                log.warning("fit worker %d (pid %s) did not stop in time; killing it", w.slot,
                            w.pid)
                w.process.kill()
        for w in everyone:
            await self._reap(w, 2.0)
            if w.process is not None and self._loop is not None:
                try:
                    self._loop.remove_reader(w.process.sentinel)
                except (OSError, ValueError):
                    pass
        if self._executor is not None:
            self._executor.shutdown(wait=True)

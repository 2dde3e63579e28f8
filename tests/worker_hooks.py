"""A fit worker with test hooks, and how a test makes a pool hang or garble one of its workers.

The hooks are not in the product: :func:`hooked_worker_main` runs the real
:func:`tactiled.pipeline.worker.worker_main` in a real worker process, over a connection that
answers two more requests before the worker sees them:

- ``("sleep", rid, seconds)`` -> ``("slept", rid)`` after sleeping: a hung worker;
- ``("garble", rid)`` -> bytes that do not unpickle: an answer the parent cannot read.

A test asks for the ``hookable_workers`` fixture (tests/procs.py), which makes every pool it
builds start this worker, then calls :func:`hang` or :func:`garble`.
"""

from __future__ import annotations

import time
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Any

from tactiled.pipeline.worker import Spec, worker_main

if TYPE_CHECKING:  # (a worker process imports this module: it needs no more than the worker)
    from tactiled.pipeline.pool import WorkerPool

#: what ``WorkerPool.worker_main`` names for a worker with these hooks
HOOKED_WORKER_MAIN = f"{__name__}:hooked_worker_main"


class _HookedConnection:
    """The worker's connection, answering the hooks' requests itself."""

    def __init__(self, conn: Connection) -> None:
        self._conn = conn

    def recv(self) -> Any:
        while True:
            msg = self._conn.recv()
            if msg[0] == "sleep":
                time.sleep(msg[2])  # deliberately unresponsive: the parent must notice
                self._conn.send(("slept", msg[1]))
            elif msg[0] == "garble":
                self._conn.send_bytes(b"\x80\x05not a pickle")
            else:
                return msg

    def __getattr__(self, name: str) -> Any:
        return getattr(self._conn, name)


def hooked_worker_main(conn: Connection, specs: dict[int, Spec]) -> None:
    """A worker process's entry point: the real worker, plus the hooks above."""
    worker_main(_HookedConnection(conn), specs)  # type: ignore[arg-type]


def _ask(pool: WorkerPool, slot: int, message: tuple[Any, ...]) -> int | None:
    w = pool._workers[slot]
    if w.state != "ready":
        return None
    assert pool.worker_main == HOOKED_WORKER_MAIN, "use the hookable_workers fixture"
    pool._send(w, message, message[0], pool.settings.timeout)
    return w.pid


def hang(pool: WorkerPool, slot: int, seconds: float) -> int | None:
    """Make worker ``slot`` unresponsive for ``seconds``; its pid, or None if it is not ready.

    The request has the fit deadline, so a sleep longer than ``fit.timeout`` gets the worker
    killed and replaced."""
    return _ask(pool, slot, ("sleep", float(seconds)))


def garble(pool: WorkerPool, slot: int) -> int | None:
    """Make worker ``slot`` answer with bytes that do not unpickle (it is replaced, as for any
    answer the pool cannot read); its pid, or None if it is not ready."""
    return _ask(pool, slot, ("garble",))

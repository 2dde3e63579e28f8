"""Fixtures of the pipeline tests: a fixture that fails a test which leaves a worker process
or a pipeline thread running, and ``arun``, which also fails one that leaves a task running.

Tests run coroutines with ``arun`` (``asyncio.run`` plus the task check), never an asyncio
plug-in.  Worker processes are real (forkserver children running the real fitter).
"""

from __future__ import annotations

import asyncio
import multiprocessing
import threading
from collections.abc import Callable, Coroutine, Iterator
from typing import Any

import pytest
from pipeline_helpers import leftover_workers

from tactiled.pipeline import pool as pool_module


@pytest.fixture(autouse=True)
def no_leftover_workers() -> Iterator[None]:
    """Fail a test that leaves a fit worker (or any multiprocessing child) or a pipeline thread
    running.  Workers are found through the pool's record of every pid it started."""
    first = len(pool_module.SPAWNED_PIDS)
    yield
    started = pool_module.SPAWNED_PIDS[first:]
    alive = leftover_workers(started)
    children = [p for p in multiprocessing.active_children() if p.pid in started]
    threads = [t.name for t in threading.enumerate() if t.name.startswith("tactiled-")]
    assert not alive, f"worker process(es) left running: {alive}"
    assert not children, f"multiprocessing children left: {children}"
    assert not threads, f"pipeline threads left running: {threads}"


@pytest.fixture
def arun() -> Callable[[Coroutine[Any, Any, Any]], Any]:
    """``arun(coro)``: ``asyncio.run(coro)``, failing if the coroutine returns while other
    tasks are still running (asyncio.run would cancel them silently)."""

    def run(coro: Coroutine[Any, Any, Any]) -> Any:
        leftovers: list[str] = []

        async def main() -> Any:
            result = await coro
            me = asyncio.current_task()
            leftovers.extend(t.get_name() for t in asyncio.all_tasks() if t is not me)
            return result

        result = asyncio.run(main())
        assert not leftovers, f"tasks left running: {leftovers}"
        return result

    return run

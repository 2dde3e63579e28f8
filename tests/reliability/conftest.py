"""Fixtures of the reliability tests: the same leak check as the pipeline tests (no worker
process, multiprocessing child or pipeline thread may outlive a test), ``arun`` (asyncio.run
that fails a test leaving tasks behind), and more pty devices of the project's kind."""

from __future__ import annotations

import asyncio
import multiprocessing
import threading
from collections.abc import Callable, Coroutine, Iterator
from pathlib import Path
from typing import Any

import pytest
from rel_helpers import leftover

from tactiled.pipeline import pool as pool_module


@pytest.fixture(autouse=True)
def no_leftover_workers() -> Iterator[None]:
    first = len(pool_module.SPAWNED_PIDS)
    yield
    started = pool_module.SPAWNED_PIDS[first:]
    running = leftover(started)
    children = [p for p in multiprocessing.active_children() if p.pid in started]
    threads = [t.name for t in threading.enumerate() if t.name.startswith("tactiled-")]
    assert not running, f"worker process(es) left running: {running}"
    assert not children, f"multiprocessing children left: {children}"
    assert not threads, f"pipeline threads left running: {threads}"


@pytest.fixture
def arun() -> Callable[[Coroutine[Any, Any, Any]], Any]:
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


@pytest.fixture
def more_ptys(pty_device, tmp_path: Path) -> Iterator[Callable[[str], Any]]:
    """``more_ptys(name)``: another device of the ``pty_device`` fixture's class (tests/conftest.py)
    at ``tmp_path/name``; all closed after the test."""
    made = []

    def make(name: str) -> Any:
        device = type(pty_device)(tmp_path / name)
        made.append(device)
        return device

    yield make
    for device in made:
        device.close()


HERE = Path(__file__).parent


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Tests marked ``slow`` here run only when asked for (``-m slow``, as the marker's
    description in pyproject.toml says); the short version of each is always on."""
    if "slow" in (config.getoption("markexpr") or ""):
        return
    skip = pytest.mark.skip(reason="slow: opt in with -m slow")
    for item in items:
        if "slow" in item.keywords and Path(str(item.path)).is_relative_to(HERE):
            item.add_marker(skip)

"""Fixtures of the reliability tests: the same leak check as the pipeline tests (no worker
process, multiprocessing child or pipeline thread may outlive a test), ``arun`` (asyncio.run
that fails a test leaving tasks behind), and more pty devices of the project's kind."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from procs import (  # noqa: F401 - fixtures, shared with pipeline
    arun, hookable_workers, no_leftover_workers)


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

"""Fixtures: a real notification socket on a path and one in the abstract namespace."""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from deploy_helpers import NotifySocket


@pytest.fixture
def notify_socket(tmp_path: Path) -> Iterator[NotifySocket]:
    s = NotifySocket(str(tmp_path / "notify"))
    yield s
    s.close()


@pytest.fixture
def abstract_notify_socket() -> Iterator[NotifySocket]:
    s = NotifySocket(f"@tactiled-test/{os.getpid()}/{uuid.uuid4().hex}")
    yield s
    s.close()

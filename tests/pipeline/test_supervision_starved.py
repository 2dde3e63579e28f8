"""A worker starved of CPU by other processes is given more time, not killed as hung.

``cpu_state`` is read from the real kernel (this process, running; a child, asleep).  The
pool's decision is then driven through a scripted ``cpu_state``: a mock of the scheduler,
because a reproducible starvation (a worker runnable for seconds without the CPU) cannot be
arranged on a shared test machine."""

from __future__ import annotations

import os
import subprocess
import time

import pytest

from tactiled.pipeline import supervision
from tactiled.pipeline.pool import WorkerPool
from tactiled.pipeline.supervision import STARVED_MAX_S, _Request, _Worker, cpu_state


def test_cpu_state_reads_the_kernel() -> None:
    t0 = time.process_time()
    while time.process_time() - t0 < 0.05:  # burn some CPU so the count moves
        pass
    me = cpu_state(os.getpid())
    assert me is not None and me[1] == "R" and me[0] >= 0.04
    child = subprocess.Popen(["sleep", "5"])
    try:
        deadline = time.monotonic() + 5.0
        while (st := cpu_state(child.pid)) is not None and st[1] != "S" and time.monotonic() < deadline:
            time.sleep(0.01)
        assert st is not None and st[1] == "S" and st[0] < 0.05
    finally:
        child.kill()
        child.wait()
    assert cpu_state(2 ** 22 + 12345) is None  # no such process


@pytest.fixture
def scripted(monkeypatch: pytest.MonkeyPatch) -> list[tuple[float, str]]:
    """The worker's (CPU s, state) as the test scripts them, one per read."""
    script: list[tuple[float, str]] = []
    monkeypatch.setattr(supervision, "cpu_state", lambda pid: script.pop(0))
    return script


def _overdue() -> tuple[WorkerPool, _Worker, _Request]:
    pool = WorkerPool(1)
    w = _Worker(slot=0, state="ready", pid=4242)
    head = _Request("fit", 7, 1.0)
    w.outstanding.append(head)
    return pool, w, head


def test_starved_worker_gets_more_time_until_it_computes(scripted) -> None:
    pool, w, head = _overdue()
    scripted += [(0.30, "R"), (0.40, "R"), (0.45, "R"), (1.45, "R")]
    assert pool._starved(w, head, 100.0)        # runnable at the deadline: extended
    assert w.head_since == 100.0
    assert pool._starved(w, head, 101.0)        # 0.1 s of CPU in 1 s: still starved
    assert pool._starved(w, head, 102.0)        # 0.05 s in 1 s
    assert not pool._starved(w, head, 103.0)    # a full second of CPU and no answer: hung
    assert pool.deadline_extended == 3


def test_asleep_or_past_the_cap_is_hung(scripted) -> None:
    pool, w, head = _overdue()
    scripted.append((0.0, "S"))                 # asleep at its deadline (a deadlock, a sleep)
    assert not pool._starved(w, head, 100.0)
    pool, w, head = _overdue()
    scripted += [(0.1, "R"), (0.1, "R"), (0.1, "R")]
    assert pool._starved(w, head, 100.0)
    assert pool._starved(w, head, 100.0 + STARVED_MAX_S)
    assert not pool._starved(w, head, 101.0 + STARVED_MAX_S)  # starved for too long
    pool, w, head = _overdue()
    scripted.append((0.1, "R"))
    assert pool._starved(w, head, 100.0)
    other = _Request("fit", 8, 1.0)              # the next request starts afresh
    scripted.append((0.2, "S"))
    assert not pool._starved(w, other, 101.0)

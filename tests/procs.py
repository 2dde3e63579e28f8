"""Process checks and fixtures shared by the pipeline and reliability suites (Linux /proc).

Their conftests import :func:`no_leftover_workers`, :func:`arun` and
:func:`hookable_workers` (pytest takes fixtures from a conftest's namespace); any test may import :func:`block_until`; the service suite has its own variants, which tolerate the
workers of module-scoped servers and cap ``arun`` at 60 s.  :class:`SimulatedDevice` is
``tactiled simulate`` as a device of its own, for every suite that needs one.
"""

from __future__ import annotations

import asyncio
import multiprocessing
import queue
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Coroutine, Iterator
from typing import Any

import pytest

from tactiled import native
from tactiled.pipeline import supervision

#: How much slower a test's real-time stream plays on the Python reference
#: (``TACTILED_CORE=python``) than on the core: the reference's fits cost 15-30 times the
#: core's CPU (``Fitter.fit`` of noisy cylinder frames: 3.6 against 0.2 ms with model
#: ``cylinder``, 13 against 0.4 ms with ``auto``), so a stream paced for the core would end
#: before the reference had made the fits a test counts (at a tenth of the pace it makes
#: about as many per frame), and a test's wait for a daemon's fits is ten times as long.
PACE = 1.0 if native.core is not None else 10.0


def alive(pid: int) -> bool:
    """True if ``pid`` runs (a zombie has exited: it is not running)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
            state = fh.read().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")


def leftover(pids: list[int], grace: float = 2.0) -> list[int]:
    """Of ``pids``, those still running after up to ``grace`` seconds."""
    deadline = time.monotonic() + grace
    while True:
        running = [pid for pid in pids if pid and alive(pid)]
        if not running or time.monotonic() > deadline:
            return running
        time.sleep(0.02)


def block_until(condition: Callable[[], bool], timeout: float, what: str = "condition",
                poll: float = 0.01) -> float:
    """Poll ``condition`` (blocking: for threads, or a test that holds the event loop on
    purpose) until true; the seconds taken, or AssertionError naming ``what`` after
    ``timeout`` s.  In a coroutine, ``await wait_until(...)`` (tests/conftest.py) instead."""
    start = time.monotonic()
    while not condition():
        if time.monotonic() - start > timeout:
            raise AssertionError(f"{what}: not within {timeout} s")
        time.sleep(poll)
    return time.monotonic() - start


class SimulatedDevice:
    """``tactiled simulate ARGS`` in a process of its own: a simulated device on a pty or a
    WebSocket, as a user starts one.  Use it as a context manager (it is stopped at the end).

    Its output is read by two threads as it comes: :meth:`line` takes the lines it prints on
    stdout (its address first: ``pty: PATH``, ``link: PATH``, ``xela: ws://HOST:PORT``), with
    a deadline; :meth:`stderr` is what it wrote there (its log and its final counts), so
    neither pipe can fill and stall it."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "tactiled.cli", "simulate", *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self._lines: queue.Queue[str | None] = queue.Queue()
        self._err: list[str] = []
        self._readers = [
            threading.Thread(target=self._read, args=(self.proc.stdout, self._lines.put),
                             name="simulate-stdout", daemon=True),
            threading.Thread(target=self._read, args=(self.proc.stderr, self._err.append),
                             name="simulate-stderr", daemon=True)]
        for reader in self._readers:
            reader.start()

    @staticmethod
    def _read(pipe: Any, put: Callable[[Any], None]) -> None:
        for text in pipe:
            put(text)
        put(None)  # end of output
        pipe.close()

    def line(self, timeout: float = 60.0) -> str:
        """The next line it prints on stdout, stripped; AssertionError with its stderr if none
        comes within ``timeout`` s (its start imports numpy and the core: seconds on a loaded
        machine) or it ends first."""
        try:
            text = self._lines.get(timeout=timeout)
        except queue.Empty:
            text = None
        if text is None:
            self.stop()
            raise AssertionError(f"`tactiled simulate` printed no line within {timeout} s "
                                 f"(exit {self.proc.returncode}): {self.stderr()[-2000:]}")
        return text.strip()

    def signal(self, signum: int, timeout: float = 30.0) -> int:
        """Send ``signum`` and wait for the exit; its exit status (killed after ``timeout``
        s: the interpreter takes seconds to exit on a loaded machine)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signum)
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise AssertionError(f"`tactiled simulate` still running {timeout} s after "
                                 f"signal {signum}") from None

    def stop(self, timeout: float = 30.0) -> int:
        """SIGTERM, then its exit status (SIGKILL after ``timeout`` s)."""
        import signal

        try:
            return self.signal(signal.SIGTERM, timeout)
        except AssertionError:
            return self.proc.returncode

    def stderr(self) -> str:
        """What it wrote on stderr; all of it once it has exited."""
        if self.proc.poll() is not None:
            self._readers[1].join(10.0)
        return "".join(t for t in self._err if t is not None)

    def __enter__(self) -> SimulatedDevice:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


@pytest.fixture
def hookable_workers(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every worker pool built in the test starts workers that obey the test hooks of
    tests/worker_hooks.py (:func:`worker_hooks.hang`, :func:`worker_hooks.garble`)."""
    from tactiled.pipeline.pool import WorkerPool
    from worker_hooks import HOOKED_WORKER_MAIN

    monkeypatch.setattr(WorkerPool, "worker_main", HOOKED_WORKER_MAIN)


@pytest.fixture(autouse=True)
def no_leftover_workers() -> Iterator[None]:
    """Fail a test that leaves a fit worker (or any multiprocessing child) or a pipeline thread
    running.  Workers are found through the pool's record of every pid it started."""
    first = len(supervision.SPAWNED_PIDS)
    yield
    started = supervision.SPAWNED_PIDS[first:]
    running = leftover(started)
    children = [p for p in multiprocessing.active_children() if p.pid in started]
    threads = [t.name for t in threading.enumerate() if t.name.startswith("tactiled-")]
    assert not running, f"worker process(es) left running: {running}"
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


def read_source(url: str, enough: Callable[[list], bool], seconds: float) -> tuple[list, Any]:
    """Open the source at ``url`` (a real pty), gather its frames until ``enough(frames)`` or
    ``seconds`` have passed, close it; the frames and its decoder's counters.  A source that
    delivers nothing fails the wait after ``seconds`` + 10 s rather than hanging the test."""
    from tactiled.sources import open_source

    async def read() -> tuple[list, Any]:
        src = open_source(url)
        got: list = []
        await src.open()
        deadline = time.monotonic() + seconds
        try:
            async for batch in src.frame_batches():
                got += batch
                if enough(got) or time.monotonic() > deadline:
                    break
        finally:
            stats = src.decoder.stats
            await src.close()
        return got, stats

    return asyncio.run(asyncio.wait_for(read(), seconds + 10.0))

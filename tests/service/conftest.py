"""Fixtures of the service tests: real servers (uvicorn on 127.0.0.1, an ephemeral port, the
real daemon on the simulated finger), `tactiled run` as a subprocess, headless Chromium.

* :class:`LiveServer` runs a :class:`~tactiled_service.server.Service` in a thread with its own
  event loop, so tests talk to it over real sockets with real clients while the test function
  stays plain (``asyncio.run`` inside, no plug-in).
* :func:`no_leftovers` (autouse) fails a test that leaves a server, a ``tactiled run``
  process or a fit worker running; it cleans up first so one failure does not cascade.
* :func:`chromium` installs Debian's ``chromium`` with apt-get when it is missing and we are
  root (CI has Debian's mirrors), once per session; :func:`browser_page` is a fresh page of it
  (Playwright) and the errors that page reports.
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Coroutine, Iterator
from pathlib import Path
from typing import Any

import pytest
from live import TEST_OPTIONS, LiveServer
from procs import alive as pid_alive
from svc_helpers import sim_settings

from tactiled.pipeline import supervision
from tactiled.settings import Settings
from tactiled_service.options import ServiceOptions

CHROMIUM = "/usr/bin/chromium"
PYTHON = sys.executable


# --------------------------------------------------------------------------------------------
# In-process servers


@pytest.fixture(scope="module")
def shared_server(request: pytest.FixtureRequest) -> Iterator[LiveServer]:
    """Two simulated fingers served for the whole module (read-only tests share it), at the
    module's ``SHARED_RATE_HZ`` if it sets one (the simulator's 1 kHz if not)."""
    rate_hz = getattr(request.module, "SHARED_RATE_HZ", None)
    server = LiveServer(sim_settings(2, rate_hz=rate_hz), shared=True).start()
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture
def live_server() -> Iterator[Callable[..., LiveServer]]:
    """``live_server(settings=None, options=TEST_OPTIONS, sources=None)``: a started server of
    this test only, stopped at the end."""
    started: list[LiveServer] = []

    def make(settings: Settings | None = None, options: ServiceOptions = TEST_OPTIONS,
             sources: Callable[[], dict[str, Any]] | None = None,
             notifier: Any = None) -> LiveServer:
        server = LiveServer(settings or sim_settings(1), options, sources=sources,
                            notifier=notifier)
        started.append(server)
        return server.start()

    yield make
    for server in started:
        server.stop()


# --------------------------------------------------------------------------------------------
# `tactiled run` subprocesses


class DaemonProcess:
    """``tactiled run ARGS`` with a marker in its environment (inherited by its workers), so
    the leak check can find every process it started."""

    instances: list[DaemonProcess] = []

    def __init__(self, args: list[str], env: dict[str, str] | None = None) -> None:
        self.marker = uuid.uuid4().hex
        full_env = {k: v for k, v in os.environ.items() if not k.startswith("TACTILED_")}
        full_env.update(env or {})
        full_env["TACTILED_TEST_MARKER"] = self.marker
        self.proc = subprocess.Popen(
            [PYTHON, "-m", "tactiled.cli", "run", *args], env=full_env,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        DaemonProcess.instances.append(self)
        self.url: str | None = None

    def wait_url(self, timeout: float = 90.0) -> str:
        """The first stdout line (the dashboard address), or fail with stderr."""
        result: list[str] = []
        reader = threading.Thread(target=lambda: result.append(self.proc.stdout.readline()),
                                  daemon=True)
        reader.start()
        reader.join(timeout)
        if not result or not result[0]:
            self.kill()
            err = self.proc.stderr.read() if self.proc.stderr else ""
            pytest.fail(f"tactiled run printed no address within {timeout} s; stderr:\n{err}")
        self.url = result[0].rstrip("\n")
        return self.url

    def processes(self) -> list[int]:
        """Pids of live processes carrying this daemon's marker (it and its workers)."""
        return marked_processes(self.marker)

    def terminate(self, timeout: float = 15.0) -> None:
        """SIGTERM if still running, SIGKILL (it and its workers) if that takes longer than
        ``timeout`` s: the end of a module fixture's daemon."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.kill()

    def kill(self) -> None:
        for pid in self.processes():
            with _suppress():
                os.kill(pid, signal.SIGKILL)
        with _suppress():
            self.proc.kill()
        with _suppress():
            self.proc.wait(5)


class _suppress:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> bool:
        return True


def marked_processes(marker: str) -> list[int]:
    """Live (not zombie) processes whose environment holds ``TACTILED_TEST_MARKER=marker``."""
    needle = f"TACTILED_TEST_MARKER={marker}".encode()
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/environ", "rb") as fh:
                if needle not in fh.read().split(b"\0"):
                    continue
            with open(f"/proc/{entry}/stat", encoding="ascii") as fh:
                state = fh.read().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state not in ("Z", "X"):
            found.append(int(entry))
    return found


@pytest.fixture(scope="session")
def daemon_process() -> Callable[..., DaemonProcess]:
    """``daemon_process(args, env=None)``: start ``tactiled run``.  Session-scoped (it only
    hands out the class) so module fixtures can start daemons shared by their tests; those
    stop them themselves, and the leak check counts only what a test started."""
    return DaemonProcess


# --------------------------------------------------------------------------------------------
# Leak check


@pytest.fixture(autouse=True)
def no_leftovers() -> Iterator[None]:
    """Fail a test that leaves a server thread, a `tactiled run` process or a fit worker
    running (servers of module fixtures excepted while they run)."""
    first_pid = len(supervision.SPAWNED_PIDS)
    servers_before = set(map(id, LiveServer.instances))
    procs_before = len(DaemonProcess.instances)
    yield
    problems = []
    for server in LiveServer.instances:
        if id(server) not in servers_before and not server.shared and server.running:
            problems.append(f"server on port {server.port} still running")
            with _suppress():
                server.stop()
    for proc in DaemonProcess.instances[procs_before:]:
        deadline = time.monotonic() + 3.0
        while proc.processes() and time.monotonic() < deadline:
            time.sleep(0.05)
        left = proc.processes()
        if left or proc.proc.poll() is None:
            problems.append(f"tactiled run (pid {proc.proc.pid}) left processes {left}")
            proc.kill()
    owned = {pid for s in LiveServer.instances if s.shared and s.running
             for pid in s.worker_pids()}
    deadline = time.monotonic() + 3.0
    while True:
        alive = [p for p in supervision.SPAWNED_PIDS[first_pid:]
                 if p and p not in owned and pid_alive(p)]
        if not alive or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    if alive:
        problems.append(f"fit worker(s) left running: {alive}")
        for pid in alive:
            with _suppress():
                os.kill(pid, signal.SIGKILL)
    assert not problems, "; ".join(problems)


# --------------------------------------------------------------------------------------------
# Browser


@pytest.fixture(scope="session")
def chromium() -> str:
    """Path of Debian's Chromium, installed with apt-get if missing (as root)."""
    if os.path.exists(CHROMIUM):
        return CHROMIUM
    if os.geteuid() != 0:
        pytest.fail(f"{CHROMIUM} is missing and the tests are not root, so they cannot "
                    "install it: run `apt-get install -y chromium` as root first")
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for cmd in (["apt-get", "update"], ["apt-get", "install", "-y", "chromium"]):
        try:
            done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=900)
        except (OSError, subprocess.TimeoutExpired) as err:
            pytest.fail(f"cannot install chromium: `{' '.join(cmd)}` failed: {err}")
        if done.returncode != 0:
            pytest.fail(f"cannot install chromium: `{' '.join(cmd)}` exited "
                        f"{done.returncode}:\n{done.stderr[-2000:]}")
    if not os.path.exists(CHROMIUM):
        pytest.fail(f"apt-get installed chromium but {CHROMIUM} is still missing")
    return CHROMIUM


CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]


@pytest.fixture
def browser_page(chromium: str, tmp_path: Path) -> Iterator[tuple[Any, list[str]]]:
    """A fresh Chromium profile and page; yields (page, errors seen by the page)."""
    from playwright.sync_api import sync_playwright

    errors: list[str] = []
    with sync_playwright() as p:
        context = p.chromium.launch_persistent_context(
            str(tmp_path / "profile"), executable_path=chromium, headless=True,
            args=CHROMIUM_ARGS, viewport={"width": 1400, "height": 1000})
        try:
            page = context.pages[0] if context.pages else context.new_page()
            page.on("pageerror", lambda err: errors.append(f"page error: {err}"))
            page.on("console", lambda msg: errors.append(f"console: {msg.text}")
                    if msg.type == "error" else None)
            yield page, errors
        finally:
            context.close()


@pytest.fixture
def arun() -> Callable[[Coroutine[Any, Any, Any]], Any]:
    """``arun(coro)``: asyncio.run with a 60 s cap."""

    def run(coro: Coroutine[Any, Any, Any], timeout: float = 60.0) -> Any:
        async def capped() -> Any:
            return await asyncio.wait_for(coro, timeout)

        return asyncio.run(capped())

    return run


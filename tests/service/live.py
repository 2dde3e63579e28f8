"""A real service (daemon + uvicorn) on its own thread and event loop, for tests."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Coroutine
from concurrent.futures import Future
from typing import Any

from tactiled.settings import Settings
from tactiled_service.options import ServiceOptions

#: Short timeouts so a test never waits long for anything.
TEST_OPTIONS = ServiceOptions(send_timeout_s=1.0, close_timeout_s=1.0, tcp_user_timeout_s=3.0)


class LiveServer:
    """A Service on its own thread and loop.  ``start()`` returns once it serves."""

    instances: list[LiveServer] = []

    def __init__(self, settings: Settings, options: ServiceOptions = TEST_OPTIONS, *,
                 sources: Callable[[], dict[str, Any]] | None = None,
                 shared: bool = False, notifier: Any = None) -> None:
        self.settings = settings
        self.notifier = notifier
        self.options = options
        self.sources = sources
        self.shared = shared
        self.service: Any = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.error: BaseException | None = None
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._main, name="live-server", daemon=True)
        LiveServer.instances.append(self)

    # -- lifecycle ------------------------------------------------------------------------------

    def start(self, timeout: float = 90.0) -> LiveServer:
        self._thread.start()
        if not self._ready.wait(timeout):
            raise RuntimeError(f"server not ready within {timeout} s")
        if self.error is not None:
            raise self.error
        return self

    def _main(self) -> None:
        asyncio.run(self._amain())

    async def _amain(self) -> None:
        from tactiled_service.server import Service

        self.loop = asyncio.get_running_loop()
        try:
            self.service = Service(self.settings, self.options,
                                   sources=self.sources() if self.sources else None,
                                   notifier=self.notifier)
            await self.service.start()
        except BaseException as err:  # reported by start()
            self.error = err
            self._ready.set()
            return
        self._ready.set()
        await self.service.wait()
        await self.service.stop()

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    def stop(self, timeout: float = 15.0) -> None:
        if self.loop is not None and self.running and self.service is not None:
            self.loop.call_soon_threadsafe(self.service.request_stop)
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise RuntimeError(f"server thread still running {timeout} s after stop")

    # -- access ---------------------------------------------------------------------------------

    @property
    def port(self) -> int:
        return self.service.port

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def ws_url(self) -> str:
        return f"ws://127.0.0.1:{self.port}/v1/stream"

    def call(self, fn: Callable[[], Any], timeout: float = 10.0) -> Any:
        """Run ``fn()`` on the server's loop (the daemon is not thread-safe); its result."""
        assert self.loop is not None
        fut: Future[Any] = Future()

        def run() -> None:
            try:
                fut.set_result(fn())
            except BaseException as err:
                fut.set_exception(err)

        self.loop.call_soon_threadsafe(run)
        return fut.result(timeout)

    def run(self, coro: Coroutine[Any, Any, Any], timeout: float = 10.0) -> Any:
        """Run ``coro`` on the server's loop; its result."""
        assert self.loop is not None
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def worker_pids(self) -> list[int]:
        if self.service is None or self.service.daemon is None or not self.running:
            return []
        return [p for p in self.call(self.service.daemon.pool.pids) if p]

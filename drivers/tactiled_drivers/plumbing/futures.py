"""What the drivers' asyncio code shares."""

from __future__ import annotations

import asyncio


def resolve(future: asyncio.Future[None]) -> None:
    """Complete ``future`` unless it already is: the drivers' wake-up for a waiting read or
    pause (safe to schedule after the waiter has given up)."""
    if not future.done():
        future.set_result(None)


class Pause:
    """A sleep that :meth:`wake` cuts short: how a paced source's read waits for its next frame
    while :meth:`close` can still end it at once."""

    def __init__(self) -> None:
        self._waker: asyncio.Future[None] | None = None

    async def __call__(self, delay: float) -> None:
        """Sleep ``delay`` seconds (none if negative), or less if :meth:`wake` is called."""
        loop = asyncio.get_running_loop()
        waker: asyncio.Future[None] = loop.create_future()
        handle = loop.call_later(max(delay, 0.0), resolve, waker)
        self._waker = waker
        try:
            await waker
        finally:
            handle.cancel()
            self._waker = None

    def wake(self) -> None:
        """End the sleep under way, if any."""
        if self._waker is not None:
            resolve(self._waker)

"""What the drivers' asyncio code shares."""

from __future__ import annotations

import asyncio


def resolve(future: asyncio.Future[None]) -> None:
    """Complete ``future`` unless it already is: the drivers' wake-up for a waiting read or
    pause (safe to schedule after the waiter has given up)."""
    if not future.done():
        future.set_result(None)

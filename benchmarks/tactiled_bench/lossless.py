"""The daemon run lossless on a simulated finger, for the benches that score its stream."""

from __future__ import annotations

import asyncio
from typing import Any


def play_lossless(overrides: dict[str, Any]) -> list[Any]:
    """Start a daemon with the settings ``overrides`` (a ``sim://`` sensor playing its scene
    once), lossless (each frame waits for any fit it needs: deterministic), until the stream
    ends; every estimate it published, in order (the hub's items)."""
    from tactiled.pipeline import Daemon
    from tactiled.settings import load_settings

    async def main() -> list[Any]:
        daemon = Daemon(load_settings(None, {}, overrides), lossless=True)
        out: list[Any] = []
        daemon.hub.add_listener(lambda it: out.append(it) if it.kind == "estimate" else None)
        await daemon.start()
        await daemon.wait_finished(600)
        await daemon.stop()
        return out

    return asyncio.run(main())

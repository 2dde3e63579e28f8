"""The acquisition pipeline: per-sensor asyncio loops, the fit worker pool, the hub.

The frame's path (docs/concepts/pipeline.md): source bytes -> FrameDecoder -> Frame -> lookup table ->
zeroing + contact detection -> :class:`Gate` -> worker process fit (latest frame wins) ->
:class:`Estimate` -> :class:`Hub` (REST cache, subscribers) ; raw frames -> recorder.

Public API: :class:`Daemon` (start/stop, stats, tare, get_config/update_config, hub),
:class:`Hub` / :class:`Subscription`, :class:`Estimate` / :class:`ZeroedFrame`,
:class:`Gate`, :class:`WorkerPool`, :class:`SensorPipeline`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # what type checkers and editors see; at run time __getattr__ below
    from tactiled.pipeline.daemon import Daemon, UnknownSensorError
    from tactiled.pipeline.estimate import TIMING_KEYS, Estimate, ZeroedFrame, without_timing
    from tactiled.pipeline.gate import Gate, GateDecision
    from tactiled.pipeline.hub import Hub, Subscription, SubscriptionClosed
    from tactiled.pipeline.pool import WorkerPool
    from tactiled.pipeline.sensor import SensorPipeline

#: What ``from tactiled.pipeline import X`` gives, imported when first asked for: a light
#: module of the package (the contacts' association, the estimate's records) must not load
#: the daemon, the pool and the hub with it.
_EXPORTS = {
    "Daemon": "daemon", "UnknownSensorError": "daemon",
    "TIMING_KEYS": "estimate", "Estimate": "estimate", "ZeroedFrame": "estimate",
    "without_timing": "estimate",
    "Gate": "gate", "GateDecision": "gate",
    "Hub": "hub", "Subscription": "hub", "SubscriptionClosed": "hub",
    "WorkerPool": "pool",
    "SensorPipeline": "sensor",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'tactiled.pipeline' has no attribute {name!r}")
    return getattr(importlib.import_module(f"tactiled.pipeline.{module}"), name)

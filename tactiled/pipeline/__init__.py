"""The acquisition pipeline: per-sensor asyncio loops, the fit worker pool, the hub.

The frame's path (docs/concepts/pipeline.md): source bytes -> FrameDecoder -> Frame -> lookup table ->
zeroing + contact detection -> :class:`Gate` -> worker process fit (latest frame wins) ->
:class:`Estimate` -> :class:`Hub` (REST cache, subscribers) ; raw frames -> recorder.

Public API: :class:`Daemon` (start/stop, stats, tare, get_config/update_config, hub),
:class:`Hub` / :class:`Subscription`, :class:`Estimate` / :class:`ZeroedFrame`,
:class:`Gate`, :class:`WorkerPool`, :class:`SensorPipeline`.
"""

from tactiled.pipeline.daemon import Daemon, UnknownSensorError
from tactiled.pipeline.estimate import TIMING_KEYS, Estimate, ZeroedFrame
from tactiled.pipeline.gate import Gate, GateDecision
from tactiled.pipeline.hub import Hub, Subscription, SubscriptionClosed
from tactiled.pipeline.pool import WorkerPool
from tactiled.pipeline.sensor import SensorPipeline

__all__ = [
    "TIMING_KEYS",
    "Daemon",
    "Estimate",
    "Gate",
    "GateDecision",
    "Hub",
    "SensorPipeline",
    "Subscription",
    "SubscriptionClosed",
    "UnknownSensorError",
    "WorkerPool",
    "ZeroedFrame",
]

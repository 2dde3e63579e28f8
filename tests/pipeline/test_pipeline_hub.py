"""Hub: fan-out with bounded queues (newest wins), filters, the latest-item cache, closing."""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest

from tactiled.pipeline.estimate import Estimate, ZeroedFrame, make_estimate
from tactiled.pipeline.hub import Hub, SubscriptionClosed


def estimate(sensor: str, seq: int) -> Estimate:
    return make_estimate(sensor=sensor, sensor_id=1, seq=seq, device_time_us=seq * 1000,
                         host_time=time.monotonic(), gate="no_contact", fitted_seq=None,
                         worker_ms=0.0, fit={"contact": False})


def frame(sensor: str, seq: int) -> ZeroedFrame:
    return ZeroedFrame(sensor=sensor, sensor_id=1, seq=seq, device_time_us=0, host_time=0.0,
                       contact=False, statistic=0.0, strain=np.zeros((8, 8)))


def test_slow_subscriber_drops_oldest_without_slowing_the_others(arun) -> None:
    async def main() -> None:
        hub = Hub(["f0"])
        fast = hub.subscribe(None, {"estimate"}, maxsize=8)
        slow = hub.subscribe(None, {"estimate"}, maxsize=8)
        received: list[int] = []

        async def read_fast() -> None:
            async for item in fast:
                received.append(item.seq)

        reader = asyncio.create_task(read_fast())
        n = 2000
        for seq in range(n):
            hub.publish(estimate("f0", seq))
            # the slow one holds at most maxsize items: publishing never waits on it, it drops
            assert slow.qsize() == min(seq + 1, 8)
            if seq % 4 == 3:
                await asyncio.sleep(0)  # the fast reader keeps up; the slow one never reads
        await asyncio.sleep(0)
        fast.close()
        await reader
        assert received == list(range(n)), "the fast subscriber lost items"
        assert fast.dropped == 0
        # The slow one kept the newest maxsize items and counted every other one as dropped.
        assert slow.dropped == n - 8
        assert [slow.get_nowait().seq for _ in range(8)] == list(range(n - 8, n))
        slow.close()

    arun(main())


def test_filters_by_sensor_and_kind_and_caches_latest(arun) -> None:
    async def main() -> None:
        hub = Hub(["f0", "f1"])
        only_f1 = hub.subscribe({"f1"}, {"estimate"}, maxsize=10)
        frames = hub.subscribe(None, {"frame"}, maxsize=10)
        both = hub.subscribe({"f0"}, {"estimate", "frame"}, maxsize=10)
        hub.publish(estimate("f0", 1))
        hub.publish(estimate("f1", 2))
        hub.publish(frame("f0", 3))
        hub.publish(frame("f1", 4))
        assert [(i.kind, i.seq) for i in _drain(only_f1)] == [("estimate", 2)]
        assert [(i.kind, i.seq) for i in _drain(frames)] == [("frame", 3), ("frame", 4)]
        assert [(i.kind, i.seq) for i in _drain(both)] == [("estimate", 1), ("frame", 3)]
        assert hub.latest_estimate("f0").seq == 1
        assert hub.latest_frame("f1").seq == 4
        assert hub.latest_estimate("nobody") is None
        with pytest.raises(ValueError, match="unknown sensor.*'f9'"):
            hub.subscribe({"f9"}, {"estimate"}, maxsize=1)
        with pytest.raises(ValueError, match="kinds"):
            hub.subscribe(None, {"bogus"}, maxsize=1)
        with pytest.raises(ValueError, match="maxsize"):
            hub.subscribe(None, {"estimate"}, maxsize=0)
        hub.close()

    arun(main())


def _drain(sub):
    out = []
    while (item := sub.get_nowait()) is not None:
        out.append(item)
    return out


def test_close_wakes_a_waiting_reader_and_ends_iteration(arun) -> None:
    async def main() -> None:
        hub = Hub()
        sub = hub.subscribe(None, {"estimate"}, maxsize=4)
        waiter = asyncio.create_task(sub.get())
        await asyncio.sleep(0.01)
        assert not waiter.done()
        hub.publish(estimate("a", 7))
        assert (await waiter).seq == 7
        hub.publish(estimate("a", 8))
        hub.close()  # queued items are still delivered, then the iteration stops
        assert [i.seq async for i in sub] == [8]
        with pytest.raises(SubscriptionClosed):
            await sub.get()
        assert hub.subscriptions == ()
        late = hub.subscribe(None, {"estimate"}, maxsize=1)
        assert late.closed

    arun(main())


def test_a_cancelled_getter_does_not_break_the_subscription(arun) -> None:
    async def main() -> None:
        hub = Hub()
        sub = hub.subscribe(None, {"estimate"}, maxsize=4)
        getter = asyncio.create_task(sub.get())
        await asyncio.sleep(0)
        getter.cancel()
        await asyncio.gather(getter, return_exceptions=True)
        hub.publish(estimate("a", 1))
        assert (await asyncio.wait_for(sub.get(), 1.0)).seq == 1
        sub.close()

    arun(main())


def test_a_failing_listener_is_logged_not_raised(arun, caplog) -> None:
    async def main() -> None:
        hub = Hub()
        seen = []

        def bad(item) -> None:
            raise RuntimeError("boom")

        hub.add_listener(bad)
        remove = hub.add_listener(seen.append)
        hub.publish(estimate("a", 1))
        remove()
        hub.publish(estimate("a", 2))
        assert [i.seq for i in seen] == [1]
        assert "boom" in caplog.text

    arun(main())


def test_a_frame_nobody_takes_is_built_when_latest_frame_asks(arun) -> None:
    # publish_frame keeps a frame's fields while no listener or subscription takes frames: the
    # latest frame is then the record its constructor gives, and every frame published while
    # someone takes frames is that record, delivered.
    strain = np.full((8, 8), 1e-5)
    fields = ("f0", 1, 7, 7000, 2.5, False, 3e-6, strain, 1.7e9, None)

    async def main() -> None:
        hub = Hub(["f0"])
        estimates = hub.subscribe(None, {"estimate"}, maxsize=4)  # takes no frames
        hub.publish_frame(*fields)
        assert hub.published["frame"] == 1 and estimates.qsize() == 0
        built = hub.latest_frame("f0")
        assert isinstance(built, ZeroedFrame)
        assert repr(built) == repr(ZeroedFrame(*fields)) and built.strain is strain
        assert hub.latest_frame("f0") is built  # built once
        frames = hub.subscribe({"f0"}, {"frame"}, maxsize=4)
        hub.publish_frame(*fields[:2], 8, *fields[3:])
        got = frames.get_nowait()
        assert got is hub.latest_frame("f0") and got.seq == 8
        frames.close()
        seen: list[int] = []
        remove = hub.add_listener(lambda item: seen.append(item.seq))
        hub.publish_frame(*fields[:2], 9, *fields[3:])
        remove()
        hub.publish_frame(*fields[:2], 10, *fields[3:])
        assert seen == [9] and hub.latest_frame("f0").seq == 10
        assert hub.published["frame"] == 4
        hub.close()

    arun(main())

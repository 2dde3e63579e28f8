"""One behaviour, every source: frames come out exactly as they went in, through the shared
decoder, and closing releases everything."""

from __future__ import annotations

import asyncio

from tactiled.sources import open_source


def test_delivers_identical_frames(feedable_source, frame_factory, same_frame, wait_until,
                                   open_fd_count) -> None:
    sent = frame_factory(40, seed=21, start_seq=7, sensor_id=2)
    url = feedable_source.url_for(sent)

    async def main() -> None:
        before = open_fd_count()
        src = open_source(url)
        got = []

        async def consume() -> None:
            async for frame in src.frames(timeout=5.0):
                got.append(frame)

        async with src:
            task = asyncio.create_task(consume())
            await feedable_source.feed(sent)
            await wait_until(lambda: len(got) == len(sent), 5.0)
            if feedable_source.ends:
                await asyncio.wait_for(task, 5.0)
        await asyncio.wait_for(task, 1.0)
        assert all(same_frame(a, b) for a, b in zip(got, sent, strict=True))
        assert src.decoder.stats.frames == len(sent) and src.decoder.stats.rejected == 0
        assert not src.connected and open_fd_count() == before

    asyncio.run(main())

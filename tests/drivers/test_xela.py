"""The XELA driver against a real WebSocket server on 127.0.0.1 speaking as ``xela_server``
does: good and bad messages, a server that goes away and comes back, a refused connection."""

from __future__ import annotations

import asyncio
import socket

import numpy as np
import pytest
from websockets.asyncio.server import serve
from websockets.exceptions import ConnectionClosed

from tactiled.errors import DeviceConnectionError, DriverError
from tactiled.sources import open_source
from tactiled_drivers import xela


class FakeServer:
    """A xela_server stand-in: sends the welcome, then whatever the test queues."""

    def __init__(self) -> None:
        self.queue: asyncio.Queue[str | bytes] = asyncio.Queue()
        self.server = None
        self.port = 0
        self.clients = 0

    async def _handler(self, ws) -> None:  # noqa: ANN001
        self.clients += 1
        await ws.send(xela.WELCOME)
        closed = asyncio.ensure_future(ws.wait_closed())
        try:
            while True:
                get = asyncio.ensure_future(self.queue.get())
                await asyncio.wait({get, closed}, return_when=asyncio.FIRST_COMPLETED)
                if closed.done():  # the server is stopping: end, so that close() completes
                    get.cancel()
                    return
                await ws.send(get.result())
        except ConnectionClosed:
            return

    async def start(self, port: int = 0) -> None:
        self.server = await serve(self._handler, "127.0.0.1", port, max_size=None)
        self.port = self.server.sockets[0].getsockname()[1]

    async def stop(self) -> None:
        self.server.close()
        await self.server.wait_closed()


def grids(n: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 65536, (4, 6, 3)) for _ in range(n)]


def test_xela_frames_bad_messages_and_a_server_that_returns(wait_until) -> None:
    first, second = grids(10, 1), grids(5, 2)

    async def main() -> None:
        server = FakeServer()
        await server.start()
        src = open_source(f"xela://127.0.0.1:{server.port}?sensor=2")
        got = []

        async def consume() -> None:
            try:
                async for f in src.frames():
                    got.append(f)
            except DriverError:
                if src.is_open:
                    raise

        async with src:
            task = asyncio.create_task(consume())
            for k, g in enumerate(first):
                await server.queue.put(xela.message(k + 1, {1: ("XR1944", g[:, :4]),
                                                            2: ("XR1946", g)}, 50.0 + k))
                if k == 3:
                    for bad in ("not json", "[1]", '{"message": 9, "2": {"taxels": 24}}',
                                '{"message": 9, "2": {"taxels": 5, "data": "1,2,3"}}',
                                xela.message(99, {1: ("XR1944", g[:, :4])}, 1.0)):
                        await server.queue.put(bad)
            await wait_until(lambda: len(got) == 10, 5.0)
            assert src.connected and src.device_array().shape == (4, 4)
            await server.stop()
            await wait_until(lambda: src.disconnects == 1 and not src.connected, 5.0)
            await server.start(server.port)
            await wait_until(lambda: src.reconnects == 1 and src.connected, 5.0)
            for k, g in enumerate(second):
                await server.queue.put(xela.message(k + 1, {2: ("XR1946", g)}, 90.0 + k))
            await wait_until(lambda: len(got) == 15, 5.0)
            st = src.status()
        await asyncio.wait_for(task, 2.0)
        await server.stop()
        sent = first + second
        assert all(np.array_equal(f.raw, g[..., 2]) and f.raw.shape == (4, 6)
                   for f, g in zip(got, sent, strict=True))
        assert all(np.array_equal(f.taxels, g) for f, g in zip(got, sent))
        assert [f.seq for f in got] == [*range(1, 11), *range(1, 6)]
        assert all(f.sensor_id == 2 for f in got)
        assert got[0].device_time_us == 50_000_000
        assert (st.decoder["parse_errors"], st.decoder["length_errors"]) == (3, 1)
        assert st.decoder["restarts"] == 0 and st.decoder["lost"] == 0
        assert "lost" in st.last_error or "xela_server" in st.last_error

    asyncio.run(asyncio.wait_for(main(), 30.0))


def test_xela_refused_connection_is_a_driver_error() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # nothing listens once closed

    async def main() -> None:
        src = open_source(f"xela://127.0.0.1:{port}")
        with pytest.raises(DeviceConnectionError, match=f"127.0.0.1:{port}"):
            await src.open()
        assert not src.is_open

    asyncio.run(main())


def test_the_simulated_server_pulls_sideways() -> None:
    """`tactiled simulate --as xela --scene pull` (a real WebSocket server): sensor 1's x, y, z
    follow the 3-axis model (here of `--sensor xela_uskin_4x6`), at rest first then moved far
    beyond the noise (2 counts); sensor 2 rests."""
    from procs import SimulatedDevice

    with SimulatedDevice("--as", "xela", "--device", "0", "--rate", "1000", "--seed", "3",
                         "--scene", "pull", "--sensor", "xela_uskin_4x6") as device:
        line = device.line()
        assert line.startswith("xela: ws://"), line
        addr = line.removeprefix("xela: ws://")

        async def read(number: int, enough: int) -> list:
            """Sensor ``number``'s frames until one has moved by 100 counts, or ``enough``."""
            got: list = []
            async with open_source(f"xela://{addr}?sensor={number}&rows=4&cols=6") as src:
                async for batch in src.frame_batches():
                    got += batch
                    moved = max(np.abs(f.taxels.astype(float) - got[0].taxels).max()
                                for f in batch)
                    if moved > 100 or len(got) >= enough:
                        return got
            return got

        pulled = asyncio.run(asyncio.wait_for(read(1, 5000), 90.0))
        resting = asyncio.run(asyncio.wait_for(read(2, 50), 60.0))
    xyz = np.stack([f.taxels for f in pulled]).astype(float)
    assert xyz.shape[1:] == (4, 6, 3)
    assert np.abs(xyz - xyz[0]).max() > 100  # the pull moves the magnets
    rest = np.stack([f.taxels for f in resting]).astype(float)
    assert np.abs(rest - rest.mean(axis=0)).max() < 10 * 2.0

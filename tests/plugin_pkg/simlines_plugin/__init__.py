"""simlines://?seed=1 - the scene simulator printed as text lines, framed by the lines driver."""
import asyncio

from tactiled.sim import FingerSimulator
from tactiled.sources import FrameSource
from tactiled_drivers.lines import LinesFramer, encode


class SimLinesSource(FrameSource):
    PARAMS = frozenset({"seed"})

    def _new_decoder(self):  # the framer: bytes -> frames, no I/O
        return LinesFramer(rows=8, cols=8)

    async def _open_internal(self):  # acquire the device
        self.sim = FingerSimulator(seed=self.url.get_int("seed", 0))

    async def _close_internal(self):  # release it; must not raise
        pass

    async def _read_internal(self):  # the next bytes (b"" at the end of the stream)
        await asyncio.sleep(0.01)
        return encode(self.sim.next_frame().raw)

"""The pipeline over a real pseudo-terminal with pyserial (serial:// driver), as on hardware:
encoded frames written to the master, including a corrupted frame and a gap in seq."""

from __future__ import annotations

import asyncio
import time
from urllib.parse import quote

from pipeline_helpers import (
    SETTLE_FRAMES,
    accounted,
    check_estimates,
    collect,
    contact_path,
    make_frames,
)

from tactiled.frames import encode_frame
from tactiled.pipeline import Daemon
from tactiled.settings import load_settings


def test_pipeline_over_a_pty(pty_device, arun) -> None:
    frames = make_frames(contact_path(60), sensor_id=5, seed=31)
    gap = {SETTLE_FRAMES + 20 + k for k in range(5)}  # never sent: the device "lost" them
    corrupt = SETTLE_FRAMES + 40
    sent = [f for f in frames if f.seq not in gap]
    overrides = {"sensor[0].name": "index", "sensor[0].wire_id": 5,
                 "sensor[0].url": f"serial://{quote(pty_device.path)}"}

    async def main() -> tuple[list, dict]:
        daemon = Daemon(load_settings(None, {}, overrides))
        estimates = collect(daemon)
        await daemon.start()
        source = daemon.sensors["index"].source
        while not source.is_open:  # pyserial flushes the input buffer when it opens the port
            await asyncio.sleep(0.001)
        for frame in sent:
            wire = bytearray(encode_frame(frame))
            if frame.seq == corrupt:
                wire[len(wire) // 2] ^= 0x40  # a bit flipped on the wire
            await pty_device.send(bytes(wire))
            await asyncio.sleep(0.002)  # ~500 Hz, like the device
        t0 = time.monotonic()
        while not estimates or estimates[-1].seq != sent[-1].seq:
            assert time.monotonic() - t0 < 10, "the last frame never got its estimate"
            await asyncio.sleep(0.005)
        st = daemon.stats("index")
        await daemon.stop()
        return estimates, st

    estimates, st = arun(main())
    check_estimates(estimates, "index", 5)
    delivered = {f.seq for f in sent} - {corrupt}
    assert {e.seq for e in estimates} <= delivered
    assert st["decoder"]["crc_errors"] == 1
    assert st["decoder"]["lost"] == len(gap) + 1  # the gap and the corrupted frame
    assert st["frames"] == len(delivered) == accounted(st)
    assert st["connected"] is True and st["sensor_id"] == 5
    assert any(e.gate == "fit" and e.contact for e in estimates)

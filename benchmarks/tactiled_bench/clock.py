"""How well frame stamps hold: :class:`tactiled.clock.FrameClock` against the simulated
device's true send times.

``python -m tactiled_bench.clock --seconds 10 --rate 1000`` stamps a simulated finger's frames
as the daemon does, from the device clock and as a device without a clock, and prints in ms the
bias, jitter, 1st and 99th percentiles and largest error of each stamp (and of the raw arrival
time), and whether the stamps strictly increased.
"""
# The finger is sim://, paced in real time on the event loop, up to 8 frames a read.  Without a
# device clock the stamps are the arrival times spread by sequence number and the rate.  Frame k
# is sent at start + k / rate on the host's monotonic clock and carries device time k / rate, so
# each stamp's error against its true send time is known.

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
from dataclasses import replace
from typing import Any

from tactiled.clock import FrameClock


def _summary(errors_s: list[float]) -> dict[str, float]:
    ms = sorted(e * 1e3 for e in errors_s)
    n = len(ms)
    return {"bias_ms": round(statistics.fmean(ms), 4), "jitter_ms": round(statistics.pstdev(ms), 4),
            "p1_ms": round(ms[n // 100], 4), "p99_ms": round(ms[(99 * n) // 100], 4),
            "max_abs_ms": round(max(abs(ms[0]), abs(ms[-1])), 4)}


async def measure(seconds: float = 10.0, rate: float = 1000.0, settle_s: float = 1.0,
                  seed: int = 0) -> dict[str, Any]:
    """Run the simulated finger for ``seconds`` and return the errors' summaries (the first
    ``settle_s`` seconds, while the filter finds the envelope, are left out)."""
    from tactiled_drivers.sim import SimSource

    source = SimSource(f"sim://?seed={seed}&rate={rate:g}&noise=0")
    clocked = FrameClock(rate, wall_offset=0.0)
    unclocked = FrameClock(rate, wall_offset=0.0)
    errs: dict[str, list[float]] = {"clocked": [], "no_device_clock": [], "arrival": []}
    last = {"clocked": -1.0, "no_device_clock": -1.0}
    increasing = True
    loop = asyncio.get_running_loop()
    async with source:
        end = loop.time() + seconds
        async for batch in source.frame_batches():
            assert source._schedule is not None
            start = source._schedule.start
            copies = [replace(f, clocked=False, time=None) for f in batch]
            clocked.stamp(batch)
            unclocked.stamp(copies)
            for f, c in zip(batch, copies):
                sent = start + f.device_time_us * 1e-6
                for key, t in (("clocked", f.time), ("no_device_clock", c.time)):
                    assert t is not None
                    increasing &= t > last[key]
                    last[key] = t
                    if f.device_time_us * 1e-6 >= settle_s:
                        errs[key].append(t - sent)
                if f.device_time_us * 1e-6 >= settle_s:
                    errs["arrival"].append(f.host_time - sent)
            if loop.time() >= end:
                break
    out: dict[str, Any] = {k: _summary(v) for k, v in errs.items()}
    out.update(frames=len(errs["clocked"]), strictly_increasing=increasing,
               slewed=clocked.slewed, seconds=seconds, rate_hz=rate)
    return out


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m tactiled_bench.clock", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--rate", type=float, default=1000.0, help="frames per second (Hz)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    print(json.dumps(asyncio.run(measure(args.seconds, args.rate, seed=args.seed)), indent=1))


if __name__ == "__main__":
    main()

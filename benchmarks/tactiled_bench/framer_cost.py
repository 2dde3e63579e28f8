"""The framers' cost per frame: ``python -m tactiled_bench.framer_cost``.

The vendor framers and the wire protocol's decoder (``wire``: 8x8 counts below 256, the most
COBS groups per frame).  Each format's stream (2000 frames built by its encoder) is fed in 4 KiB
pieces, as the serial reader hands it over; the best of 5 passes is printed, per frame and in
MB/s, for the compiled core's framer (the one a source runs) and for its Python reference, with
their ratio, in the same invocation (XELA's JSON is framed in Python only).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from tactiled.frames import Frame, FrameDecoder, NativeFrameDecoder, encode_frame
from tactiled_drivers import flexitac, lines, robotiq, xela
from tactiled_drivers.plumbing.framing import FramerBase

FRAMES = 2000
PIECE = 4096
PASSES = 5


def best_time(make: Callable[[], FramerBase | Any], pieces: list[bytes]) -> float:
    """Seconds of the fastest of PASSES passes feeding ``pieces`` to a new framer."""
    best = float("inf")
    for _ in range(PASSES):
        framer = make()
        t = time.perf_counter()
        for piece in pieces:
            framer.feed(piece, 0.0)
        best = min(best, time.perf_counter() - t)
    return best


def main() -> None:
    rng = np.random.default_rng(0)
    Make = Callable[[], FramerBase | Any]
    # each format: its core's framer, its reference, its stream
    streams: dict[str, tuple[Make, Make, list[bytes]]] = {
        "wire 8x8": (NativeFrameDecoder, FrameDecoder,
                     [encode_frame(Frame(seq=k, device_time_us=k,
                                         raw=rng.integers(0, 256, (8, 8)).astype(np.uint16)))
                      for k in range(FRAMES)]),
        "flexitac 12x32": (lambda: flexitac.NativeFlexiTacFramer(12, 32),
                           lambda: flexitac.FlexiTacFramer(12, 32),
                           [flexitac.encode(rng.integers(0, 256, (12, 32)))
                            for _ in range(FRAMES)]),
        "lines 8x8": (lambda: lines.NativeLinesFramer(8, 8), lambda: lines.LinesFramer(8, 8),
                      [lines.encode(rng.integers(0, 65536, (8, 8))) for _ in range(FRAMES)]),
        "robotiq 7x4": (lambda: robotiq.NativeRobotiqFramer(0), lambda: robotiq.RobotiqFramer(0),
                        [robotiq.encode_finger(0, rng.integers(0, 65536, (7, 4)), timestamp_ms=k)
                         for k in range(FRAMES)]),
    }
    print(f"{'':16s} {'core, per frame':>20s}  {'reference':>20s}  reference / core")
    for name, (core, reference, units) in streams.items():
        data = b"".join(units)
        pieces = [data[k:k + PIECE] for k in range(0, len(data), PIECE)]
        t_core, t_ref = best_time(core, pieces), best_time(reference, pieces)
        print(f"{name:16s} {t_core / FRAMES * 1e6:6.1f} us {len(data) / t_core / 1e6:5.0f} MB/s"
              f"  {t_ref / FRAMES * 1e6:6.1f} us {len(data) / t_ref / 1e6:5.0f} MB/s"
              f"  {t_ref / t_core:5.1f}")
    messages = [xela.message(k, {1: ("XR1944", rng.integers(0, 65536, (4, 4, 3)))}, 1.0).encode()
                for k in range(FRAMES)]
    t = best_time(lambda: xela.XelaFramer(1), messages)
    print(f"{'xela 4x4':16s} {'(Python only)':>20s}  {t / FRAMES * 1e6:6.1f} us per message")


if __name__ == "__main__":
    main()

"""The fan-out benchmark's own parts: its minimal client, and one short phase."""

from __future__ import annotations


def test_bench_client_parses_server_frames():
    """The benchmark's minimal client reads what the server sends (split anywhere)."""
    import struct

    from tactiled_bench.websocket_fanout import Client, client_frame

    est = b'{"type":"estimate","v":1,"sensor":"f","seq":1,"host_time":10.5,"latency_ms":0.25}'
    big = b'{"type":"estimate","host_time":10.0,"latency_ms":null,"pad":"' + b"x" * 300 + b'"}'
    wire = (struct.pack("!BB", 0x81, len(est)) + est
            + struct.pack("!BBH", 0x81, 126, len(big)) + big
            + struct.pack("!BB", 0x81, 26) + b'{"type":"unsubscribed"}   ')
    c = Client(sock=None, port=0)  # type: ignore[arg-type]
    for i in range(0, len(wire), 7):
        c.feed(wire[i:i + 7], now=11.0, measuring=True)
    assert c.total == c.received == 2 and c.unsubscribed
    assert c.latencies_ms == [500.0, 1000.0]
    assert c.fanout_ms == [500.0 - 0.25, 1000.0]
    masked = client_frame(b"hi")
    assert masked[:2] == b"\x81\x82" and masked[6:] == b"hi"


def test_bench_phase_smoke(shared_server):
    """One short benchmark phase against a live server: everything delivered and measured."""
    import argparse
    import os
    import time

    from tactiled_bench import websocket_fanout as bench_fanout

    args = argparse.Namespace(clients=4, stalled=1, max_rate=30.0, seconds=1.0,
                              stalled_want="same")
    start = time.monotonic() + bench_fanout.STALL_LEAD
    r = bench_fanout.run_phase("smoke", shared_server.url + "/", shared_server.port, args, 1,
                               start, os.getpid())
    assert r.healthy == 3 and r.received > 0
    assert min(r.delivery) >= 0.99
    assert r.latencies_ms and all(x >= 0 for x in r.latencies_ms)

"""Frame stamps (tactiled/clock.py) against the true send times of a simulated device: a
device clock with an offset and a crystal's drift, frames read in bursts with random transport
delays, host stalls, device restarts, and devices with no clock at all."""

from __future__ import annotations

import numpy as np
import pytest

from tactiled.clock import FrameClock
from tactiled.frames import Frame

RAW = np.zeros((2, 2), dtype=np.uint16)
MIN_DELAY = 0.0002  # s: the fastest a frame crosses the link


def run(clock: FrameClock, send: np.ndarray, device: np.ndarray, arrival: np.ndarray,
        reads: list[int], *, clocked: bool = True) -> np.ndarray:
    """Stamp frames ``k`` read ``reads[i]`` at a time (all of a read arrive at its last frame's
    arrival); returns each stamp minus its true send time, s."""
    stamps, k = [], 0
    for n in reads:
        batch = [Frame(seq=k + j, device_time_us=round(device[k + j] * 1e6), raw=RAW,
                       host_time=float(arrival[k + n - 1]), clocked=clocked) for j in range(n)]
        clock.stamp(batch)
        stamps += [f.time for f in batch]
        k += n
    return np.array(stamps) - send[:k]


def bursts(rng: np.random.Generator, n: int) -> list[int]:
    reads = []
    while sum(reads) < n:
        reads.append(int(min(rng.integers(1, 9), n - sum(reads))))
    return reads


def link(rng: np.random.Generator, send: np.ndarray, reads: list[int]) -> np.ndarray:
    """Arrival times: each read leaves after its last frame, with a delay >= MIN_DELAY."""
    arrival = np.empty_like(send)
    k = 0
    for n in reads:
        arrival[k:k + n] = send[k + n - 1] + MIN_DELAY + rng.exponential(0.0005)
        k += n
    return arrival


@pytest.mark.parametrize("ppm", [-80.0, 0.0, 50.0])
def test_device_clock_maps_onto_the_least_delay_with_its_drift(ppm: float) -> None:
    rng = np.random.default_rng(1)
    n, rate = 20_000, 1000.0
    device = 3.0 + np.arange(n) / rate  # the device's clock, s
    send = 500.0 + device * (1 + ppm * 1e-6)  # ... on the host's clock
    reads = bursts(rng, n)
    err = run(FrameClock(rate, wall_offset=0.0), send, device, link(rng, send, reads), reads)
    assert np.all(np.diff(err + send) > 0)  # strictly increasing
    settled = err[3000:] - MIN_DELAY  # after 3 s; the least delay is all a host can know
    assert abs(settled.mean()) < 1e-4 and settled.std() < 1e-4
    assert np.abs(settled).max() < 5e-4


def test_a_host_stall_neither_lifts_the_mapping_nor_sends_it_back() -> None:
    rng = np.random.default_rng(2)
    n, rate = 8000, 1000.0
    device = np.arange(n) / rate
    send = 10.0 + device
    reads = bursts(rng, n)
    arrival = link(rng, send, reads)
    stall = (device >= 3.0) & (device < 4.5)  # nothing read for 1.5 s, then all at once
    arrival[stall] = np.maximum(arrival[stall], 10.0 + 4.5 + MIN_DELAY)
    clock = FrameClock(rate, wall_offset=0.0)
    err = run(clock, send, device, arrival, reads)
    assert np.all(np.diff(err + send) > 0)
    assert np.abs(err[device >= 2.0] - MIN_DELAY).max() < 1e-3


def test_a_restarted_device_starts_afresh_and_stamps_still_increase() -> None:
    rng = np.random.default_rng(3)
    rate = 1000.0
    device = np.concatenate([np.arange(5000), np.arange(5000)]) / rate  # restarts at 0
    send = 50.0 + np.arange(10_000) / rate + np.where(np.arange(10_000) >= 5000, 0.3, 0.0)
    reads = bursts(rng, 10_000)
    clock = FrameClock(rate, wall_offset=0.0)
    err = run(clock, send, device, link(rng, send, reads), reads)
    assert np.all(np.diff(err + send) > 0)
    assert clock.filter.restarts == 1
    assert np.abs(err[7000:] - MIN_DELAY).max() < 5e-4


@pytest.mark.parametrize("rate_hz", [1000.0, None])
def test_no_device_clock_spreads_a_read_over_its_frames(rate_hz: float | None) -> None:
    rng = np.random.default_rng(4)
    n = 6000
    send = 20.0 + np.arange(n) / 1000.0
    reads = bursts(rng, n)
    arrival = link(rng, send, reads)
    clock = FrameClock(rate_hz, wall_offset=0.0)
    err = run(clock, send, send, arrival, reads, clocked=False)
    stamps = err + send
    assert np.all(np.diff(stamps) > 0)  # none repeated, though 8 frames share an arrival
    # frames of one read a period apart, the last at the arrival (but where the read before
    # came so late that this one, spread back, would overlap it: then it slews)
    last = (np.cumsum(reads) - 1)[100:]
    at_arrival = np.isclose(stamps[last], arrival[last], rtol=0, atol=1e-9)
    assert at_arrival.mean() > 0.9
    assert np.all(stamps[last] >= arrival[last] - 1e-9)
    inside = np.diff(stamps)[2000:]
    assert abs(np.median(inside) - 1e-3) < 2e-5
    # the error is the read's delay, no more: the arrival spread back by the period
    assert np.abs(err[2000:]).max() < arrival.max() - send.max() + 5e-3


def test_framers_say_whether_the_device_sent_a_clock() -> None:
    from tactiled_drivers import flexitac, lines, robotiq

    assert not flexitac.FlexiTacFramer(1, 2).feed(
        flexitac.encode(np.ones((1, 2))) * 3)[0].clocked
    assert not lines.LinesFramer(1, 2).feed(b"1,2\n")[0].clocked
    assert lines.LinesFramer(1, 2, time_col=True).feed(b"5,1,2\n")[0].clocked
    raw = np.zeros((7, 4), dtype=np.uint16)
    static_only = robotiq.encode_finger(0, raw)[4 + 19:]  # the static packet, no timestamp
    got = robotiq.RobotiqFramer(0).feed(static_only + robotiq.encode_finger(0, raw,
                                                                          timestamp_ms=9))
    assert [f.clocked for f in got] == [False, True]


def test_a_read_of_one_frame_is_stamped_as_the_same_frame_in_a_longer_read() -> None:
    # One clocked frame per read (a live port, a replay) takes the short path of stamp(); it
    # must give every frame the stamp that stamping the frames together gives, bit for bit,
    # through bursts, a stall and a device restart.
    rng = np.random.default_rng(4)
    n, rate = 6000, 1000.0
    device = np.concatenate([np.arange(3000), np.arange(3000)]) / rate
    send = 20.0 + np.arange(n) / rate * (1 + 40e-6)
    reads = bursts(rng, n)
    arrival = link(rng, send, reads)
    arrival[1500:1700] = np.maximum(arrival[1500:1700], arrival[1700])  # a stall
    def frames() -> list[Frame]:
        return [Frame(seq=k, device_time_us=round(device[k] * 1e6), raw=RAW,
                      host_time=float(arrival[k])) for k in range(n)]

    alone, together = frames(), frames()
    one_by_one = FrameClock(rate, wall_offset=0.0)
    for f in alone:
        one_by_one.stamp([f])
    clock = FrameClock(rate, wall_offset=0.0)
    clock.stamp(together)
    assert [f.time for f in alone] == [f.time for f in together]
    assert clock.filter.restarts == 1 and clock.slewed > 0  # the paths above were taken

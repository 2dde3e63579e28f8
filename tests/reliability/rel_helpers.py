"""Helpers of the reliability tests (a uniquely named module, importable from every test module
of this directory): physics-true wire frames from the scene simulator, a decoder that keeps what
it delivers, a device writer, and the checks every published estimate must pass."""

from __future__ import annotations

import asyncio
import collections
import json
import math
import os
import time
from collections.abc import Callable, Iterable
from typing import Any
from urllib.parse import quote

import numpy as np

from tactiled.frames import Frame, FrameDecoder, encode_frame
from tactiled.physics.contact import Contact
from tactiled.pipeline import Daemon, Estimate
from tactiled.sim import FingerSimulator


def serial_url(path: str) -> str:
    return f"serial://{quote(path)}"


def scene_frames(count: int, *, scene: str = "demo", rate_hz: float = 500.0, seed: int = 1,
                 sensor_id: int = 0, start: int = 0) -> list[Frame]:
    """``count`` consecutive frames of a looping built-in scene, from tick ``start`` on: what
    the device would send (seq = tick index)."""
    sim = FingerSimulator(scene=scene, seed=seed, rate_hz=rate_hz, sensor_id=sensor_id,
                          loop=True)
    sim.skip(start)
    return sim.frames(count)


class TapDecoder(FrameDecoder):
    """The real decoder, also keeping ``(seq, device_time_us, raw)`` of every frame it
    delivers, so a test can compare them with what was sent intact."""

    def __init__(self) -> None:
        super().__init__()
        self.delivered: list[tuple[int, int, tuple[int, int], bytes]] = []

    def feed(self, data: bytes, host_time: float | None = None) -> list[Frame]:
        frames = super().feed(data, host_time)
        for f in frames:
            self.delivered.append(fingerprint(f))
        return frames


def fingerprint(frame: Frame) -> tuple[int, int, tuple[int, int], bytes]:
    """What the wire carries of a frame (seq, device time, shape, counts)."""
    raw = np.asarray(frame.raw, dtype=np.uint16)
    return (frame.seq, frame.device_time_us, raw.shape, raw.tobytes())


class Streamer:
    """Plays a device: writes ``frames`` (encoded, cycled with increasing seq) to a pty device
    at ``rate_hz`` while it is plugged, as a background task.  While unplugged, the frames due
    are not sent (a device that is away sends nothing).

    Like a device's UART, it never tears a frame: when the pty is full (the reader fell
    behind: the machine is busy, the event loop shared with the daemon stalled), the frames
    due wait in the streamer's own buffer, in order, and go out whole as the reader makes
    room, so a slow reader costs time, not frames.  Only a buffer of ``backlog_s`` seconds of
    frames counts further frames ``dropped`` (a reader that stopped).  ``sent`` counts frames
    written whole; ``unsent`` those due while paused or unplugged (a gap in seq), including
    frames buffered when the device went away."""

    def __init__(self, device: Any, *, rate_hz: float = 500.0, scene: str = "demo",
                 seed: int = 1, sensor_id: int = 0, backlog_s: float = 10.0) -> None:
        self.device = device
        self.rate_hz = rate_hz
        self.sim = FingerSimulator(scene=scene, seed=seed, rate_hz=rate_hz, sensor_id=sensor_id,
                                   loop=True)
        # The first strain prediction in a process loads the compiled kernels (~0.5 s): done
        # here, not in the middle of the stream, where it would stall the shared event loop.
        self.sim.physics(Contact(10.0, math.inf, 90.0, 1.0, 11.0, 13.0))
        self.sent = 0
        self.dropped = 0
        self.unsent = 0
        self.last_seq: int | None = None
        self.backlog_max = max(1, round(backlog_s * rate_hz))
        self._queue: collections.deque[tuple[int, bytes]] = collections.deque()
        self._offset = 0  # bytes of the queue's first frame already written
        self._task: asyncio.Task[None] | None = None
        self.paused = False

    @property
    def backlog(self) -> int:
        """Frames due but not yet written whole."""
        return len(self._queue)

    def _drain(self) -> None:
        """Write what the pty takes, whole frames counted as they complete."""
        if not self.device.plugged:  # gone: what waited is never sent
            self.unsent += len(self._queue)
            self._queue.clear()
            self._offset = 0
            return
        while self._queue:
            seq, data = self._queue[0]
            try:
                n = os.write(self.device.master, memoryview(data)[self._offset:])
            except BlockingIOError:
                return
            except OSError:  # the pty vanished under the write: as unplugged
                return
            self._offset += n
            if self._offset < len(data):
                continue
            self._queue.popleft()
            self._offset = 0
            self.sent += 1
            self.last_seq = seq

    async def _run(self) -> None:
        period = 1.0 / self.rate_hz
        due = time.monotonic()
        while True:
            now = time.monotonic()
            while due <= now:
                frame = self.sim.next_frame()
                due += period
                if self.paused or not self.device.plugged:
                    self.unsent += 1  # the receiver sees a gap in seq here
                    continue
                if len(self._queue) >= self.backlog_max:
                    self.dropped += 1  # the reader stopped reading: lost
                    continue
                self._queue.append((frame.seq, encode_frame(frame)))
            if not self.paused:
                self._drain()
            await asyncio.sleep(max(0.0, min(due - time.monotonic(), 0.01)))

    def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="test-streamer")

    async def stop(self, flush_s: float = 30.0) -> None:
        """Stop making frames; the frames already due are written first (up to ``flush_s``
        s: a reader that stopped leaves them counted neither sent nor unsent)."""
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
            self._task = None
            deadline = time.monotonic() + flush_s
            while self._queue and time.monotonic() < deadline:
                self._drain()
                if self._queue:
                    await asyncio.sleep(0.001)


async def wait_for(condition: Callable[[], bool], timeout: float, what: str,
                   poll: float = 0.001) -> float:
    """Poll ``condition``; return the seconds it took, or raise AssertionError naming ``what``
    after ``timeout`` s."""
    start = time.monotonic()
    while not condition():
        if time.monotonic() - start > timeout:
            raise AssertionError(f"{what}: not within {timeout} s")
        await asyncio.sleep(poll)
    return time.monotonic() - start


async def wait_open(daemon: Daemon, name: str, timeout: float = 5.0) -> None:
    """Wait until sensor ``name``'s source is open (pyserial flushes the input on open, so a
    test must not write before)."""
    source = daemon.sensors[name].source
    await wait_for(lambda: source.is_open and source.connected, timeout, f"{name} open")


def collect(daemon: Daemon, kind: str = "estimate") -> list:
    """Every item of ``kind`` the hub publishes, in order (a listener sees all of them)."""
    items: list = []
    daemon.hub.add_listener(lambda item: items.append(item) if item.kind == kind else None)
    return items


def accounted(st: dict[str, Any]) -> int:
    """docs/concepts/pipeline.md: every frame ends in exactly one of these."""
    return (st["published"] + st["superseded"] + st["stale_dropped"] + st["fit_failed"]
            + st["fit_errors"] + st["wrong_sensor"] + st["bad_shape"] + st["errors"])


def check_estimates(estimates: Iterable[Estimate]) -> dict[str, int]:
    """Every estimate strict JSON with no NaN/inf; per sensor, seq strictly increasing (no
    stale estimate under a newer seq: the arrival order of frames that were never reset) and
    ``fitted_seq`` consistent with the gate.  Returns estimates per sensor."""
    last: dict[str, int] = {}
    count: dict[str, int] = {}
    for e in estimates:
        line = e.to_json_dict()
        text = json.dumps(line, allow_nan=False)  # raises on NaN or inf
        assert "NaN" not in text and "Infinity" not in text
        prev = last.get(e.sensor)
        assert prev is None or e.seq > prev, (
            f"{e.sensor}: estimate of seq {e.seq} published after seq {prev}")
        last[e.sensor] = e.seq
        count[e.sensor] = count.get(e.sensor, 0) + 1
        if e.gate == "fit":
            assert e.fitted_seq == e.seq
        elif e.gate == "unchanged":
            assert e.fitted_seq is not None and e.fitted_seq != e.seq  # (tracked: may be later)
        else:
            assert e.gate == "no_contact" and e.fitted_seq is None and not e.contact
    return count


def open_fds() -> list[str]:
    """What this process's descriptors point at (Linux /proc), sorted."""
    out = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            out.append(os.readlink(f"/proc/self/fd/{fd}"))
        except OSError:
            pass
    return sorted(out)


def fd_kinds(fds: list[str]) -> list[str]:
    """``open_fds()`` without the numbers that change when a descriptor is re-made (pipe and
    socket inodes, the pty's /dev/pts/N)."""
    out = []
    for f in fds:
        if f.startswith("/dev/pts/"):
            f = "/dev/pts/N"
        elif f.startswith(("pipe:", "socket:", "anon_inode:")):
            f = f.split(":", 1)[0]
        out.append(f)
    return sorted(out)


def figures(test: str, **values: Any) -> None:
    """Print the figures a test measured, one line (``pytest -rP`` shows it)."""
    print(f"FIGURES {test}: " + json.dumps(values, sort_keys=True, default=str))

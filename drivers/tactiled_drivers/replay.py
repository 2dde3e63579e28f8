"""Replay a recording: ``replay://session.tact?speed=1.0&loop=0&clock=live``.

The original wire bytes of each frame go to the shared decoder, so a replayed frame is decoded
exactly as it was live (seq, device time and counts bit-identical; a 3-axis array's x, y, z
too).  A recording of a vendor device (its header names it) is read through that device's
nominal counts -> strain table, as it was live.  ``replay://rel/path.tact`` or
``replay:///abs/path.tact``.
"""
# URL parameters:
# - speed: pace multiplier (default 1: the recorded pace, from the recorded host times;
#   2: twice as fast; 0: as fast as possible, yielding to the event loop between frames);
# - loop: 1 to start again at the end (default 0: the stream, and frames(), end);
# - clock: live (default) stamps frames with time.monotonic() at replay; recorded stamps them
#   with the host time stored in the file (for offline analysis).
# Reading the file is ordinary blocking I/O of ~100-byte records from a local disk, short enough
# not to need a thread.

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Iterator
from typing import ClassVar

from tactiled.errors import DriverError, FrameError
from tactiled.frames import FrameDecoder
from tactiled.io.recording import RecordingReader
from tactiled.sensors.devices import KINDS, DeviceArray, device_array
from tactiled.sources import FrameSource, Framer, SourceURL
from tactiled_drivers.plumbing.futures import Pause

log = logging.getLogger(__name__)


class ReplaySource(FrameSource):
    """Wire bytes from a recording file, one recorded frame per :meth:`read`."""

    PARAMS: ClassVar[frozenset[str]] = frozenset({"speed", "loop", "clock"})

    def __init__(self, url: str | SourceURL, *, decoder: Framer | None = None) -> None:
        super().__init__(url, decoder=decoder)
        if not self.url.location:
            raise ValueError(f"{self.url.url!r}: no recording file; write e.g. "
                             "replay://session.tact")
        self.path: str = self.url.location
        self.speed: float = self.url.get_float("speed", 1.0, minimum=0.0)
        self.loop: bool = self.url.get_bool("loop", False)
        self.clock: str = self.url.get_str("clock", "live", choices=("live", "recorded"))
        self.sensor_id: int | None = None  # from the file header, once open
        self.passes = 0  # completed passes through the file
        self._reader: RecordingReader | None = None
        self._records: Iterator[tuple[float, bytes]] = iter(())
        self._pending: tuple[float, bytes] | None = None
        self._t0: float | None = None  # recorded host time of this pass's first frame, s
        self._start = 0.0  # monotonic time that frame was (re)played, s
        self._record_time = 0.0  # recorded host time of the record just returned, s
        self._pause = Pause()

    def device_array(self) -> DeviceArray | None:
        """The recorded vendor device's array (its nominal counts -> strain table), when the
        recording's header names one, in the shape of its first frame; None otherwise, or when
        the file cannot be read yet (opening it says why)."""
        try:
            with RecordingReader(self.path) as reader:
                kind = reader.header.device
                if kind not in KINDS:
                    return None
                frames = next((got for _t, data in reader
                               if (got := FrameDecoder().feed(data))), None)
        except (OSError, FrameError):
            return None
        if not frames:
            return None
        rows, cols = frames[0].shape
        try:
            return device_array(kind, rows, cols)
        except ValueError:  # a shape the device cannot have: the wire format's own counts
            log.warning("%s: recorded %s frames are %dx%d, not the device's array; their "
                        "counts are read as the wire format's", self.path, kind, rows, cols)
            return None

    async def _open_internal(self) -> None:
        try:
            self._reader = RecordingReader(self.path)
        except OSError as err:
            raise DriverError(f"cannot open recording {self.path}: {err}") from err
        self.sensor_id = self._reader.header.sensor_id
        self._rewind()

    async def _close_internal(self) -> None:
        self._pause.wake()  # a paced read may be waiting for a frame due much later
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    def _rewind(self) -> None:
        assert self._reader is not None
        self._records = iter(self._reader)
        self._pending = None
        self._t0 = None

    def _timestamp(self) -> float:
        return self._record_time if self.clock == "recorded" else time.monotonic()

    async def _read_internal(self) -> bytes:
        while self.is_open and self._reader is not None:
            if self._pending is None:
                self._pending = next(self._records, None)
                if self._pending is None:
                    if not self._end_of_pass():
                        return b""
                    continue
            host_time, data = self._pending
            if self.speed > 0:
                if self._t0 is None:
                    self._t0, self._start = host_time, time.monotonic()
                due = self._start + (host_time - self._t0) / self.speed
                delay = due - time.monotonic()
                if delay > 0:
                    await self._pause(delay)
            else:
                # As fast as possible, yet let other tasks run between frames.
                await asyncio.sleep(0)
            if not self.is_open:  # closed while we waited
                break
            # The record is consumed only now, so a read cancelled while sleeping loses none.
            self._pending = None
            self._record_time = host_time
            return data
        return b""


    def _end_of_pass(self) -> bool:
        """Account for one pass; True to go round again."""
        assert self._reader is not None
        self.passes += 1
        if self._reader.truncated:
            self.last_error = (f"recording {self.path} is truncated at byte "
                               f"{self._reader.truncated_offset} (last record incomplete)")
        if not self.loop or self._reader.records == 0:
            log.info("replay of %s finished after %d records", self.path, self._reader.records)
            self.connected = False
            return False
        self._rewind()
        # The recording starts over: its seq numbers repeat, and that is not data loss.
        self.decoder.reset()
        return True

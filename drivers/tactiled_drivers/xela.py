"""XELA uSkin sensors through XELA's server: ``xela://127.0.0.1:5000?sensor=1`` (port 5000
by default).

A WebSocket client of ``xela_server`` (XELA Software).  A frame is the URL's sensor in its
model's layout: x, y, z as ``Frame.taxels`` ``(rows, cols, 3)``, z also as ``raw``; seq is the
message number, device time the sensor's ``time``, ``sensor_id`` the sensor number.  Bad
messages are counted and skipped; a lost connection is retried with backoff.
"""
# The protocol, as XELA's ROS 2 node (mcsix/xela_server_ros2, scripts/xela_service:
# websocket.WebSocketApp("ws://{ip}:{port}"), default port 5000) and Penn's example
# (penn-figueroa-lab/xela_setup, example.py) use it.  Each message is one JSON object:
# {"message": "Welcome", ...} first (ignored), then {"message": n, "type": "routine", "1": {...},
# "2": {...}} where each key made of digits is a sensor: {"time": server time s, "sensor": "1",
# "model": "XR1944", "taxels": 16, "data": "hex,hex,...", "calibrated": [...]}.  data holds x,
# y, z of every taxel (3 * taxels hexadecimal values; the ROS message types them int16/uint16
# counts), taxels "starting from top left and continuing line-by-line" (xela_server_ros2
# readme); calibrated holds forces, optional (passed on as extras["calibrated"]).
# Layouts: 4x4 for XR1944 and uSPa44, 4x6 for XR1946 and uSPa46; rows= and cols= give any other.
# Components map as xela_setup's example.py does: [..., 0] x, [..., 1] y, [..., 2] z.  Gaps in
# the message number count as lost.
# Bad messages: not JSON or not an object, a sensor entry without the keys above or with a value
# that is not a hexadecimal 16-bit count (parse_errors), a data list not 3 * taxels long or a
# taxel count the layout does not hold (length_errors), a message over MAX_MESSAGE bytes
# (oversize; the server closes such a connection and the driver reconnects).  Messages without
# this sensor are not errors.
# Connection refused or lost: retried with backoff (0.1 s doubling to 2 s), counting
# disconnects/reconnects and keeping last_error, as the serial driver does.

from __future__ import annotations

import asyncio
import json
import logging
import math
from typing import Any, ClassVar

import numpy as np

from tactiled.sensors.devices import DeviceArray, device_array
from tactiled.errors import DeviceConnectionError
from tactiled.frames import Frame
from tactiled.sources import FrameSource, SourceURL
from tactiled_drivers.plumbing.framing import FramerBase, now_if_none

log = logging.getLogger(__name__)

DEFAULT_PORT = 5000
MAX_MESSAGE = 1 << 20  # bytes; a 4x6 sensor's message is ~1 KB
#: model -> (rows, cols): the layouts the sources name (xela_setup reshapes 24 taxels to 4x6).
MODELS: dict[str, tuple[int, int]] = {
    "XR1944": (4, 4), "XR1946": (4, 6), "uSPa44": (4, 4), "uSPa46": (4, 6),
}


class XelaFramer(FramerBase):
    """One WebSocket message per :meth:`feed` -> at most one frame of ``sensor``'s z counts."""

    def __init__(self, sensor: int = 1, rows: int | None = None, cols: int | None = None) -> None:
        super().__init__()
        self.sensor = sensor
        self.key = str(sensor)
        self.layout = (rows, cols) if rows and cols else None
        self.messages = 0
        self.model = ""  # the model the latest frame named

    def feed(self, data: bytes, host_time: float | None = None) -> list[Frame]:
        """Parse one whole message (text as UTF-8 bytes); never raises."""
        self.stats.bytes += len(data)
        if len(data) > MAX_MESSAGE:
            self._reject("oversize")
            return []
        try:
            msg = json.loads(data)
        except (ValueError, UnicodeDecodeError):
            self._reject("parse_errors")
            return []
        if not isinstance(msg, dict):
            self._reject("parse_errors")
            return []
        self.messages += 1
        number = msg.get("message")
        entry = msg.get(self.key)
        if not isinstance(number, int) or isinstance(number, bool) or entry is None:
            return []  # the welcome message, or one without this sensor
        frame = self._frame(number, entry, now_if_none(host_time))
        if frame is None or not self._track_seq(frame.seq):
            return []
        return [self._accept(frame)]

    def _frame(self, number: int, entry: Any, host_time: float) -> Frame | None:
        try:
            taxels = entry["taxels"]
            model = str(entry.get("model", ""))
            text = entry["data"]
            stamp = float(entry.get("time", math.nan))
            values = [int(v, 16) for v in text.split(",")]
        except (TypeError, KeyError, AttributeError, ValueError):
            self._reject("parse_errors")
            return None
        if not isinstance(taxels, int) or len(values) != 3 * taxels or taxels < 1:
            self._reject("length_errors")
            return None
        if min(values) < 0 or max(values) > 0xFFFF:
            self._reject("parse_errors")
            return None
        shape = self.layout or MODELS.get(model)
        if shape is None:
            side = math.isqrt(taxels)
            shape = (side, side) if side * side == taxels else None
        if shape is None or shape[0] * shape[1] != taxels:
            self._reject("length_errors")
            return None
        xyz = np.array(values, dtype=np.uint16).reshape(shape[0], shape[1], 3)
        extras: dict[str, Any] = {"model": model}
        calibrated = entry.get("calibrated")
        if isinstance(calibrated, list) and len(calibrated) == 3 * taxels:
            extras["calibrated"] = calibrated
        self.model = model
        t_us = (round(stamp * 1e6) if math.isfinite(stamp) and stamp >= 0
                else self._host_clock_us(host_time))
        return Frame(seq=number % (1 << 32), device_time_us=t_us, raw=xyz[..., 2].copy(),
                     sensor_id=self.sensor & 0xFFFF, host_time=host_time, extras=extras,
                     taxels=xyz)


def message(number: int, sensors: dict[int, tuple[str, np.ndarray]], time_s: float) -> str:
    """A server message as ``xela_server`` sends it: ``sensors`` maps a sensor number to its
    model and its ``(rows, cols, 3)`` x, y, z counts."""
    body: dict[str, Any] = {"message": number, "type": "routine"}
    for n, (model, xyz) in sensors.items():
        flat = np.asarray(xyz).reshape(-1)
        body[str(n)] = {"time": time_s, "sensor": str(n), "model": model,
                        "taxels": flat.size // 3,
                        "data": ",".join(f"{int(v):X}" for v in flat)}
    return json.dumps(body)


WELCOME = json.dumps({"message": "Welcome", "type": "welcome"})


class XelaSource(FrameSource):
    """A WebSocket client of ``xela_server``; see the module docstring."""

    PARAMS: ClassVar[frozenset[str]] = frozenset({"sensor", "rows", "cols"})
    RETRY_MIN: ClassVar[float] = 0.1
    RETRY_MAX: ClassVar[float] = 2.0
    OPEN_TIMEOUT: ClassVar[float] = 2.0

    def __init__(self, url: str | SourceURL, *, decoder: XelaFramer | None = None) -> None:
        super().__init__(url, decoder=decoder)  # type: ignore[arg-type]
        host, sep, port = self.url.location.rstrip("/").rpartition(":")
        if not sep:
            host, port = self.url.location.rstrip("/"), str(DEFAULT_PORT)
        if not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ValueError(f"{self.url.url!r}: write xela://HOST:PORT?sensor=N "
                             "(e.g. xela://127.0.0.1:5000?sensor=1)")
        self.uri = f"ws://{host}:{port}"
        self._ws: Any = None
        self._retry = self.RETRY_MIN
        self._closed = asyncio.Event()

    def _new_decoder(self) -> XelaFramer:
        u = self.url
        self.sensor = u.get_int("sensor", 1, minimum=1, maximum=0xFFFF)
        rows = u.get_int("rows", 0, minimum=1, maximum=64) or None
        cols = u.get_int("cols", 0, minimum=1, maximum=64) or None
        if (rows is None) != (cols is None):
            raise ValueError(f"{u.url!r}: give both rows= and cols=, or neither")
        self.layout = (rows, cols) if rows and cols else None
        return XelaFramer(self.sensor, rows, cols)

    def sent_id(self) -> int:
        return self.sensor & 0xFFFF

    def device_array(self) -> DeviceArray:
        rows, cols = self.layout or (None, None)
        return device_array("xela", rows, cols)

    async def _connect(self) -> Any:
        from websockets.asyncio.client import connect

        try:
            return await asyncio.wait_for(
                connect(self.uri, max_size=MAX_MESSAGE, ping_interval=None, open_timeout=None),
                self.OPEN_TIMEOUT)
        except (OSError, TimeoutError) as err:
            raise DeviceConnectionError(f"cannot connect to xela_server at {self.uri}: "
                                        f"{err or type(err).__name__}") from err
        except Exception as err:  # a handshake refused: not a WebSocket server there
            raise DeviceConnectionError(f"xela_server at {self.uri} refused the connection: "
                                        f"{err}") from err

    async def _open_internal(self) -> None:
        self._closed = asyncio.Event()
        self._ws = await self._connect()
        self._retry = self.RETRY_MIN
        log.info("connected to xela_server at %s (sensor %d)", self.uri, self.sensor)

    async def _close_internal(self) -> None:
        self._closed.set()
        ws, self._ws = self._ws, None
        if ws is not None:
            try:
                await asyncio.wait_for(ws.close(), 1.0)
            except Exception as err:  # closing a dead connection: nothing to free
                log.debug("closing %s: %s", self.uri, err)

    async def _read_internal(self) -> bytes:
        from websockets.exceptions import ConnectionClosed

        while self.is_open:
            ws = self._ws
            if ws is None:
                await self._reconnect()
                continue
            try:
                msg = await ws.recv()
            except ConnectionClosed as err:
                if self._ws is ws and self.is_open:
                    self._lost(err)
                continue
            if isinstance(msg, str):
                msg = msg.encode("utf-8")
            if msg:
                return bytes(msg)
        return b""

    def _lost(self, err: BaseException) -> None:
        rcvd = getattr(err, "rcvd", None)
        if rcvd is not None and rcvd.code == 1009:  # message too big: the framer never saw it
            self.decoder.stats.oversize += 1
        self._ws = None
        self.connected = False
        self.disconnects += 1
        self.last_error = f"xela_server at {self.uri} lost: {err}"
        self._retry = self.RETRY_MIN
        log.warning("%s; retrying every %.1f..%.1f s", self.last_error, self.RETRY_MIN,
                    self.RETRY_MAX)

    async def _reconnect(self) -> None:
        delay = self._retry
        try:
            await asyncio.wait_for(self._closed.wait(), delay)
        except TimeoutError:
            pass
        if not self.is_open:
            return
        try:
            ws = await self._connect()
        except DeviceConnectionError as err:
            self._retry = min(delay * 2.0, self.RETRY_MAX)
            if str(err) != self.last_error:
                log.info("%s", err)
            self.last_error = str(err)
            return
        self._ws = ws
        self._retry = self.RETRY_MIN
        self.connected = True
        self.reconnects += 1
        self.decoder.reset()
        log.warning("xela_server at %s is back (reconnect %d)", self.uri, self.reconnects)

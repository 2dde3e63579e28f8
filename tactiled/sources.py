"""Frame sources: where wire bytes come from, chosen by URL and found by name."""

# A source is named by a URL whose scheme picks the driver::
#
#     serial:///dev/ttyACM0?baud=1000000     the fingertip on a serial port (pyserial)
#     sim://?seed=3&scene=press               the scene simulator, encoded to wire bytes
#     replay://session.tact?speed=0           a recording (speed 0: as fast as possible)
#     flexitac:///dev/ttyUSB0?rows=12&cols=32 a lab's own device: lines://, flexitac://,
#                                             robotiq://, xela:// (docs/howto/drivers.md)
#
# Drivers are registered by name as ``"module:Class"`` strings (the pattern of python-can's
# ``can/interfaces/__init__.py``) plus the ``tactiled.drivers`` entry-point group, so a third
# party can add one; the shipped ones also list their URL query keys, so
# :func:`check_source_url` checks a URL without importing its driver.  Nothing is imported until
# a source is built: the core never imports
# ``tactiled_drivers`` or pyserial at module level, and a missing optional library breaks only
# its own driver (with a :class:`~tactiled.errors.DriverError` naming it).
#
# Every source delivers *bytes*; :meth:`FrameSource.frames` feeds them through one
# :class:`~tactiled.frames.FrameDecoder`, so simulated and replayed frames travel the same
# decoding path as the hardware's.  Following python-can's ``BusABC.recv`` /
# ``_recv_internal``, the base class does the common work (state checks, timeout, counters,
# timestamps) in the public :meth:`FrameSource.read`; a driver implements only
# :meth:`FrameSource._read_internal` (and ``_open_internal`` / ``_close_internal``).

from __future__ import annotations

import abc
import asyncio
import contextlib
import importlib
import logging
import math
import time
from collections.abc import AsyncIterator, Iterable, Mapping
from dataclasses import asdict, dataclass, field, is_dataclass
from importlib import metadata
from types import MappingProxyType, TracebackType
from typing import Any, ClassVar, Protocol, runtime_checkable
from urllib.parse import parse_qsl, unquote, urlsplit

from tactiled.sensors.devices import DeviceArray
from tactiled.errors import DeviceTimeoutError, DriverError
from tactiled.frames import Frame, new_decoder

log = logging.getLogger(__name__)

ENTRY_POINT_GROUP = "tactiled.drivers"

@dataclass(frozen=True)
class DriverSpec:
    """A shipped driver as the registry knows it without importing its module: its class as
    ``"module:Class"`` and the URL query keys it accepts (the class's ``PARAMS``, which
    tests/drivers/test_driver_registry.py holds equal to these)."""

    target: str
    params: frozenset[str]


_SERIAL = frozenset({"baud", "exclusive"})
_FINGER = frozenset({"depth_x", "nu_x", "depth_y", "nu_y", "modulus", "gain_error",
                     "position_error", "offset_counts", "finger_seed"})  # FingerSpec.PARAMS

#: URL scheme -> the driver shipped in ``tactiled_drivers`` (one module per scheme).  Strings,
#: not classes, so that importing this module imports no driver (and no optional library).
BUILTIN_DRIVERS: Mapping[str, DriverSpec] = MappingProxyType({
    "serial": DriverSpec("tactiled_drivers.serial:SerialSource", _SERIAL),
    "sim": DriverSpec("tactiled_drivers.sim:SimSource", _FINGER | {
        "seed", "scene", "rate", "sensor_id", "loop", "speed", "noise", "drift", "hysteresis",
        "sensor"}),
    "replay": DriverSpec("tactiled_drivers.replay:ReplaySource",
                         frozenset({"speed", "loop", "clock"})),
    "lines": DriverSpec("tactiled_drivers.lines:LinesSource", _SERIAL | {
        "rows", "cols", "sep", "time_col", "time_unit"}),
    "flexitac": DriverSpec("tactiled_drivers.flexitac:FlexiTacSource", _SERIAL | {"rows", "cols"}),
    "robotiq": DriverSpec("tactiled_drivers.robotiq:RobotiqSource", _SERIAL | {"finger",
                                                                               "period_ms"}),
    "xela": DriverSpec("tactiled_drivers.xela:XelaSource", frozenset({"sensor", "rows", "cols"})),
    "paxini": DriverSpec("tactiled_drivers.paxini:PaxiniSource", _SERIAL | {"module", "rows",
                                                                            "cols", "checksum"}),
})

# Drivers added at run time with register_driver(); they win over built-ins and entry points.
_registered: dict[str, str | type[FrameSource]] = {}
# Entry points are read once, on first lookup (reading package metadata costs milliseconds).
_entry_points: dict[str, str] | None = None

_TRUE = frozenset({"1", "true", "yes", "on"})
_FALSE = frozenset({"0", "false", "no", "off"})


# --------------------------------------------------------------------------------------------
# URLs


@dataclass(frozen=True)
class SourceURL:
    """A parsed source URL with typed access to its query parameters.

    ``location`` is the percent-decoded authority plus path, so ``serial:///dev/ttyACM0`` gives
    ``/dev/ttyACM0``, ``serial://COM3`` gives ``COM3`` and ``replay://rec/a.tact`` gives the
    relative path ``rec/a.tact``.  The typed getters raise ``ValueError`` naming the URL, the
    parameter and the offending value.
    """

    url: str
    scheme: str
    location: str
    params: Mapping[str, str] = field(default_factory=dict)

    def _fail(self, name: str, value: str, wanted: str) -> ValueError:
        return ValueError(f"{self.url!r}: parameter {name}={value!r} is not {wanted}")

    def get_str(self, name: str, default: str, *,
                choices: Iterable[str] | None = None) -> str:
        """The string value of ``name`` (one of ``choices`` if given), or ``default``."""
        value = self.params.get(name)
        if value is None:
            return default
        if choices is not None:
            allowed = tuple(choices)
            if value not in allowed:
                raise self._fail(name, value, "one of " + ", ".join(allowed))
        return value

    def get_int(self, name: str, default: int, *, minimum: int | None = None,
                maximum: int | None = None) -> int:
        """``name`` as an integer within ``[minimum, maximum]``, or ``default`` when absent."""
        value = self.params.get(name)
        if value is None:
            return default
        try:
            number = int(value, 10)
        except ValueError:
            raise self._fail(name, value, "an integer") from None
        self._check_range(name, value, number, minimum, maximum)
        return number

    def get_float(self, name: str, default: float, *, minimum: float | None = None,
                  maximum: float | None = None) -> float:
        """``name`` as a finite float within ``[minimum, maximum]``, or ``default``."""
        value = self.params.get(name)
        if value is None:
            return default
        try:
            number = float(value)
        except ValueError:
            raise self._fail(name, value, "a number") from None
        if not math.isfinite(number):
            raise self._fail(name, value, "a finite number")
        self._check_range(name, value, number, minimum, maximum)
        return number

    def get_bool(self, name: str, default: bool) -> bool:
        """``name`` as a boolean (1/0, true/false, yes/no, on/off), or ``default``."""
        value = self.params.get(name)
        if value is None:
            return default
        lowered = value.lower()
        if lowered in _TRUE:
            return True
        if lowered in _FALSE:
            return False
        raise self._fail(name, value, "a boolean (1/0, true/false, yes/no, on/off)")

    def _check_range(self, name: str, value: str, number: float,
                     minimum: float | None, maximum: float | None) -> None:
        if minimum is not None and number < minimum:
            raise self._fail(name, value, f">= {minimum}")
        if maximum is not None and number > maximum:
            raise self._fail(name, value, f"<= {maximum}")

    def reject_unknown(self, known: Iterable[str]) -> None:
        """Raise ``ValueError`` if the URL has a parameter outside ``known`` (catches typos)."""
        allowed = set(known)
        unknown = sorted(set(self.params) - allowed)
        if unknown:
            raise ValueError(
                f"{self.url!r}: unknown parameter(s) {', '.join(unknown)}; "
                f"{self.scheme}:// accepts {', '.join(sorted(allowed)) or 'none'}"
            )


def parse_source_url(url: str) -> SourceURL:
    """Split a source URL into scheme, location and query parameters.

    Raises ``ValueError`` for a non-string, a missing scheme, a malformed query or a parameter
    given twice.
    """
    if not isinstance(url, str):
        raise ValueError(f"source URL must be a string, got {url!r}")
    text = url.strip()
    if not text:
        raise ValueError("source URL is empty")
    if "://" not in text:
        raise ValueError(
            f"source URL {url!r} has no scheme; write e.g. serial:///dev/ttyACM0, "
            "sim://?seed=3 or replay://session.tact"
        )
    parts = urlsplit(text)
    if not parts.scheme:
        raise ValueError(f"source URL {url!r} has no scheme")
    if parts.fragment:
        raise ValueError(f"source URL {url!r}: unexpected fragment #{parts.fragment}")
    try:
        pairs = parse_qsl(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError:
        raise ValueError(
            f"source URL {url!r}: malformed query {parts.query!r} (expected name=value&...)"
        ) from None
    params: dict[str, str] = {}
    for name, value in pairs:
        if name in params:
            raise ValueError(f"source URL {url!r}: parameter {name!r} given more than once")
        params[name] = value
    location = unquote(parts.netloc + parts.path)
    return SourceURL(url=text, scheme=parts.scheme.lower(), location=location,
                     params=MappingProxyType(params))


# --------------------------------------------------------------------------------------------
# Framers


@runtime_checkable
class Framer(Protocol):
    """What a source's bytes go through: a pure ``bytes -> frames`` parser, no I/O.

    Every framer implements it: the wire format's :class:`~tactiled.frames.FrameDecoder` and
    its compiled twin, each vendor driver's Python framer and the compiled ones
    (``tactiled_drivers.plumbing.framing.NativeFramer``).  ``feed`` never raises on any
    input, holds a bounded number of bytes between calls and counts what it drops in
    ``stats``, a dataclass of counters that only grow (``frames``, ``bytes``,
    ``crc_errors``...: the same name for the same count in every framer, so health,
    ``/metrics`` and ``tactiled record`` read every driver alike).
    """

    @property
    def stats(self) -> Any:
        """The counters: a dataclass instance (a snapshot, for a compiled framer)."""

    @property
    def buffered(self) -> int:
        """Bytes of an incomplete unit held between calls."""

    def feed(self, data: bytes, host_time: float | None = None) -> list[Frame]:
        """Consume ``data``; return the frames it completes, in order, each stamped with
        ``host_time`` (``time.monotonic()`` seconds; now when ``None``)."""

    def reset(self) -> None:
        """Forget partial data and sequence history (the device was reopened)."""


# --------------------------------------------------------------------------------------------
# The base class


@dataclass(frozen=True)
class SourceStatus:
    """A snapshot of a source's health, for logs and the health endpoint."""

    url: str
    connected: bool
    reconnects: int
    disconnects: int
    last_error: str
    bytes_read: int
    decoder: dict[str, Any]


class FrameSource(abc.ABC):
    """A stream of wire bytes (and, through the shared decoder, of frames).

    Use as ``async with open_source(url) as src: async for frame in src.frames(): ...``.
    A driver subclass declares its URL parameters in ``PARAMS``, reads them in its
    constructor (signature ``(url, *, decoder=None, ...)``, calling this one first) and
    implements ``_open_internal``, ``_close_internal`` and ``_read_internal``.

    Status attributes (read them, drivers update them):

    - ``connected``: the device is open and delivering (False while a serial port is away);
    - ``reconnects`` / ``disconnects``: how many times it came back / was lost;
    - ``last_error``: the latest problem as one line ("" if none);
    - ``bytes_read``: wire bytes delivered by :meth:`read`;
    - ``decoder.stats``: the frame decoder's counters.
    """

    #: Query parameters the driver understands; anything else in the URL is a ValueError.
    PARAMS: ClassVar[frozenset[str]] = frozenset()

    def __init__(self, url: str | SourceURL, *, decoder: Framer | None = None) -> None:
        self.url: SourceURL = url if isinstance(url, SourceURL) else parse_source_url(url)
        self.url.reject_unknown(self.PARAMS)
        self.decoder: Framer = decoder if decoder is not None else self._new_decoder()
        self.connected = False
        self.reconnects = 0
        self.disconnects = 0
        self.last_error = ""
        self.bytes_read = 0
        #: ``time.monotonic()`` seconds (or a driver's own clock) of the latest read.
        self.last_read_time: float | None = None
        self._is_open = False

    # -- lifecycle ------------------------------------------------------------------------

    @property
    def is_open(self) -> bool:
        """True between a successful :meth:`open` and :meth:`close`."""
        return self._is_open

    async def open(self) -> None:
        """Open the device or file; raises a :class:`DriverError` subclass if it cannot."""
        if self._is_open:
            raise DriverError(f"{self.url.url}: already open")
        await self._open_internal()
        self._is_open = True
        self.connected = True

    async def close(self) -> None:
        """Release the device or file.  Idempotent; a pending :meth:`read` returns ``b""``."""
        if not self._is_open:
            return
        self._is_open = False
        self.connected = False
        await self._close_internal()

    async def __aenter__(self) -> FrameSource:
        await self.open()
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None,
                        exc: BaseException | None, tb: TracebackType | None) -> None:
        await self.close()

    # -- reading --------------------------------------------------------------------------

    async def read(self, timeout: float | None = None) -> bytes:
        """The next chunk of wire bytes; ``b""`` at the end of the stream.

        ``timeout`` in seconds (``None``: wait for ever).  Raises
        :class:`~tactiled.errors.DeviceTimeoutError` when nothing arrives in time.
        """
        if not self._is_open:
            raise DriverError(f"{self.url.url}: read from a source that is not open")
        if timeout is None:
            data = await self._read_internal()
        else:
            try:
                data = await asyncio.wait_for(self._read_internal(), timeout)
            except DeviceTimeoutError:
                raise
            except TimeoutError as err:  # asyncio.TimeoutError is TimeoutError on 3.11
                raise DeviceTimeoutError(
                    f"{self.url.url}: no data within {timeout:g} s"
                ) from err
        self.bytes_read += len(data)
        self.last_read_time = self._timestamp()
        return data

    async def frames(self, timeout: float | None = None) -> AsyncIterator[Frame]:
        """Decoded frames until the end of the stream (or until the source is closed).

        ``timeout`` applies to each :meth:`read`, in seconds.  Corrupt wire data never
        raises here: the decoder drops it and counts it in ``decoder.stats``.
        """
        async with contextlib.aclosing(self._decoded(timeout)) as batches:
            async for batch in batches:
                for frame in batch:
                    yield frame

    def frame_batches(self, timeout: float | None = None) -> AsyncIterator[list[Frame]]:
        """As :meth:`frames`, a read at a time: the frames decoded from each read's bytes (a
        list per read that completed any), so a consumer is resumed once per read, not once
        per frame.  A driver that overrides :meth:`frames` gets its frames one per list."""
        if type(self).frames is FrameSource.frames:
            return self._decoded(timeout)
        return _one_per_list(self.frames(timeout))

    async def _decoded(self, timeout: float | None) -> AsyncIterator[list[Frame]]:
        while True:
            data = await self.read(timeout)
            if not data:
                return
            batch = self.decoder.feed(data, host_time=self.last_read_time)
            if batch:
                yield batch

    @property
    def read_backlog_now(self) -> int:
        """Bytes read from the device but not yet handed to the decoder, now (0 for a source
        that reads only when asked; the serial driver's reader thread can run ahead)."""
        return 0

    @property
    def read_backlog(self) -> int:
        """The most bytes :attr:`read_backlog_now` has been at once (0 as above)."""
        return 0

    def status(self) -> SourceStatus:
        """A snapshot of the counters above."""
        stats = getattr(self.decoder, "stats", None)
        if is_dataclass(stats) and not isinstance(stats, type):
            decoder_stats = asdict(stats)
        else:
            decoder_stats = dict(vars(stats)) if stats is not None else {}
        return SourceStatus(
            url=self.url.url,
            connected=self.connected,
            reconnects=self.reconnects,
            disconnects=self.disconnects,
            last_error=self.last_error,
            bytes_read=self.bytes_read,
            decoder=decoder_stats,
        )

    async def retry_pause(self, delay: float) -> None:
        """Wait before the next attempt to open a source that failed to open: ``delay``
        seconds (the caller's backoff).  A driver that can tell its device has come back
        (the serial driver watches the device path) returns early so the retry is immediate.
        """
        await asyncio.sleep(delay)

    def sent_id(self) -> int | None:
        """The sensor id every frame of this source carries when the driver fixes it (a vendor
        device's finger or sensor number, 0 for a device that sends none), so a calibration of
        another sensor is refused at start; ``None`` (the default): only the frames say."""
        return None

    def device_array(self) -> DeviceArray | None:
        """The array this driver's device has (its built-in description's model and its
        nominal counts -> strain scaling), when the driver knows it; ``None`` (the default):
        counts on the simulator's 16-bit scale (:meth:`LookupTable.linear`)."""
        return None

    # -- for drivers ----------------------------------------------------------------------

    def _new_decoder(self) -> Framer:
        """The :class:`Framer` this source's bytes go through (called once, from the
        constructor, after ``self.url`` is set).  The default is the tactiled wire format's
        :class:`~tactiled.frames.FrameDecoder` (the compiled core's,
        :func:`~tactiled.frames.new_decoder`); a vendor driver names its own framer here."""
        return new_decoder()

    def _timestamp(self) -> float:
        """Host time stamped on bytes just read, in seconds; ``time.monotonic()`` here."""
        return time.monotonic()

    @abc.abstractmethod
    async def _open_internal(self) -> None:
        """Acquire the device or file (raise DriverError subclasses, ``from`` the cause)."""

    @abc.abstractmethod
    async def _close_internal(self) -> None:
        """Release everything ``_open_internal`` acquired; must not raise."""

    @abc.abstractmethod
    async def _read_internal(self) -> bytes:
        """Wait for and return the next bytes (non-empty), or ``b""`` at the end of the stream.

        Must be cancellation-safe: a cancelled call (e.g. by the read timeout) loses no data.
        """

    def __repr__(self) -> str:
        state = "connected" if self.connected else ("open" if self._is_open else "closed")
        return f"<{type(self).__name__} {self.url.url!r} {state}>"


async def _one_per_list(frames: AsyncIterator[Frame]) -> AsyncIterator[list[Frame]]:
    async with contextlib.aclosing(frames):  # type: ignore[type-var]
        async for frame in frames:
            yield [frame]


# --------------------------------------------------------------------------------------------
# The registry


def _load_entry_points() -> dict[str, str]:
    global _entry_points
    if _entry_points is None:
        found: dict[str, str] = {}
        points: Iterable[metadata.EntryPoint]
        try:
            points = metadata.entry_points(group=ENTRY_POINT_GROUP)
        except Exception as err:  # broken metadata must not stop the built-in drivers
            log.warning("cannot read entry points %s: %s", ENTRY_POINT_GROUP, err)
            points = ()
        for point in points:
            scheme = point.name.lower()
            if scheme in BUILTIN_DRIVERS and BUILTIN_DRIVERS[scheme].target != point.value:
                # A plug-in must not silently replace a built-in (say, the serial driver).
                log.warning("ignoring entry point %s=%s: scheme %r is built in",
                            point.name, point.value, scheme)
                continue
            found[scheme] = point.value
        _entry_points = found
    return _entry_points


def register_driver(scheme: str, target: str | type[FrameSource]) -> None:
    """Register a driver for ``scheme``: a ``"module:Class"`` string (imported on use) or a
    :class:`FrameSource` subclass.  Replaces any earlier driver for the scheme."""
    if not scheme or not scheme.replace("+", "").replace("-", "").replace(".", "").isalnum():
        raise ValueError(f"invalid URL scheme {scheme!r}")
    if isinstance(target, str):
        _split_target(target)
    elif not (isinstance(target, type) and issubclass(target, FrameSource)):
        raise ValueError(f"driver for {scheme!r} must be 'module:Class' or a FrameSource "
                         f"subclass, got {target!r}")
    _registered[scheme.lower()] = target


def unregister_driver(scheme: str) -> None:
    """Forget a driver added with :func:`register_driver` (built-ins stay)."""
    _registered.pop(scheme.lower(), None)


def known_schemes() -> list[str]:
    """All URL schemes with a driver, sorted (the driver may still fail to import)."""
    return sorted({*BUILTIN_DRIVERS, *_load_entry_points(), *_registered})


def _split_target(target: str) -> tuple[str, str]:
    module, sep, attr = target.partition(":")
    if not sep or not module or not attr:
        raise ValueError(f"driver target must look like 'module:Class', got {target!r}")
    return module, attr


def driver_class(scheme: str) -> type[FrameSource]:
    """The driver class for ``scheme``, importing its module now.

    ``ValueError`` for an unknown scheme (listing the known ones); :class:`DriverError` if
    the driver or a library it needs cannot be imported.
    """
    key = scheme.lower()
    builtin = BUILTIN_DRIVERS.get(key)
    target = (_registered.get(key) or (builtin.target if builtin else None)
              or _load_entry_points().get(key))
    if target is None:
        raise ValueError(
            f"unknown frame source scheme {scheme!r}; known: {', '.join(known_schemes())}"
        )
    if isinstance(target, type):
        return target
    module_name, attr = _split_target(target)
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise DriverError(
            f"driver {scheme!r} ({target}) is unavailable: {err}"
        ) from err
    try:
        cls = getattr(module, attr)
    except AttributeError as err:
        raise DriverError(f"driver {scheme!r}: {module_name} has no {attr}") from err
    if not (isinstance(cls, type) and issubclass(cls, FrameSource)):
        raise DriverError(f"driver {scheme!r}: {target} is not a FrameSource subclass")
    return cls


def check_source_url(url: str) -> SourceURL:
    """``url`` parsed, its scheme known and its query keys ones its driver accepts, checked
    without importing a shipped driver's module (a plug-in's is imported to read its
    ``PARAMS``).  ``ValueError`` naming what is wrong (:class:`DriverError` for a plug-in that
    cannot be imported); the values are checked when the source is built (:func:`open_source`).
    """
    parsed = parse_source_url(url)
    spec = BUILTIN_DRIVERS.get(parsed.scheme)
    if spec is None or parsed.scheme in _registered:
        params = driver_class(parsed.scheme).PARAMS
    else:
        params = spec.params
    parsed.reject_unknown(params)
    return parsed


def open_source(url: str, **kwargs: Any) -> FrameSource:
    """Build (not yet open) the frame source for ``url``, chosen by its scheme.

    ``kwargs`` go to the driver's constructor (e.g. ``decoder=``).  Bad URLs raise
    ``ValueError`` here, before any I/O, so a config can be checked at start-up.  Open the
    result with ``await src.open()`` or ``async with``.
    """
    parsed = parse_source_url(url)
    return driver_class(parsed.scheme)(parsed, **kwargs)

"""What the pipeline publishes: contact estimates and zeroed frames.

Both are read-only records with a ``kind`` (the hub's routing key) and a ``to_json_dict()``
that is strict JSON (no NaN or inf: ``json.dumps(..., allow_nan=False)`` never fails), in the
style of gpsd's reports: a ``type`` field says what the object is (the same key as the
WebSocket stream's and Zenoh's messages: one name for one thing on every interface).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

import numpy as np

_R = TypeVar("_R")

#: Keys of :meth:`Estimate.to_json_dict` that depend on timing, not on the data; dropping them
#: makes a replay's output reproducible byte for byte (``tactiled replay --no-timing``).
TIMING_KEYS = ("host_time", "time", "latency_ms", "worker_ms", "fit_ms")


def without_timing(line: dict[str, Any], blank: bool = False) -> dict[str, Any]:
    """An estimate's JSON dict with its ``TIMING_KEYS`` dropped (``blank``: set to None), at
    the top and in each of its ``contacts``."""
    def strip(d: dict[str, Any]) -> dict[str, Any]:
        out = dict(d)
        for key in TIMING_KEYS:
            if key in out:
                if blank:
                    out[key] = None
                else:
                    del out[key]
        return out

    out = strip(line)
    if out.get("contacts"):
        out["contacts"] = [strip(c) for c in out["contacts"]]
    return out

#: Why an estimate was published without a fit of its own frame (the gate's decisions).
GATE_FIT = "fit"
GATE_NO_CONTACT = "no_contact"
GATE_UNCHANGED = "unchanged"


def plain(value: Any) -> Any:
    """``value`` as plain JSON data: numpy scalars to Python, non-finite floats to None."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return v if math.isfinite(v) else None
    if value is None or isinstance(value, str):
        return value
    return str(value)


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


_new = object.__new__
#: held while an estimate's encoded bytes are built (:meth:`Estimate.encoded`): consumers on
#: different threads (the ROS 2 node's sender, the MCAP recorder's writer) build each once
_encoding = threading.Lock()


def _envelope(kind: str, item: Estimate | ZeroedFrame) -> dict[str, Any]:
    """The keys every published item's JSON starts with, in order: what it is, whose, which
    frame and when."""
    return {"type": kind, "sensor": item.sensor, "sensor_id": item.sensor_id, "seq": item.seq,
            "device_time_us": item.device_time_us, "host_time": _finite(item.host_time),
            "time": _finite(item.stamp)}


def _record(cls: type[_R], fields: dict[str, Any]) -> _R:
    """An instance of the frozen dataclass ``cls`` holding ``fields`` (every one of its
    fields, by name), built without its generated ``__init__``: that one sets each field
    through ``object.__setattr__`` (frozen), ~3x the time this takes, and a frame's path
    builds a :class:`ZeroedFrame` for each of up to 6000 frames a second.  The result is the
    same object: frozen, equal, hashable alike."""
    obj = _new(cls)
    obj.__dict__.update(fields)
    return obj


@dataclass(slots=True)
class Estimate:
    """One contact estimate of one sensor, for one frame: a typed record (slots), read-only.

    ``seq`` / ``device_time_us`` / ``host_time`` / ``stamp`` are those of the frame this
    estimate answers (host time: ``time.monotonic()`` seconds when its bytes arrived; stamp:
    when the device measured it, Unix seconds, from :mod:`tactiled.clock`; the JSON's
    ``time``).  ``fitted_seq`` is the
    frame the values were fitted on: ``seq`` itself when ``gate == "fit"``, an earlier frame
    when the gate found this one unchanged, None for no contact.  ``worker_ms`` is the fit
    request's round trip to the worker process (0 when not fitted), ``latency_ms`` the time from
    host receive to publication.  ``fit`` is the ``tactiled fit`` JSON line of the result
    (``FitResult.to_json_dict()``: mm, N, degrees) and must be treated as read-only.

    Nothing changes an estimate once published (no setter is guarded: a frozen dataclass's
    guarded fields cost 3x the construction on a path that builds up to 6000 a second).  Its
    JSON form is built once, on first use, and shared by every consumer (:attr:`json_dict`);
    so are its other encodings, such as its ROS 2 messages' CDR (:meth:`encoded`).
    """

    sensor: str
    sensor_id: int
    seq: int
    device_time_us: int
    host_time: float  # s, monotonic
    published_time: float  # s, monotonic
    stamp: float  # s since the Unix epoch: the frame's time (tactiled.clock)
    gate: str
    fitted_seq: int | None
    worker_ms: float
    fit: dict[str, Any]
    #: the JSON form, once built (:attr:`json_dict`)
    _json: dict[str, Any] | None = field(default=None, init=False, repr=False, compare=False)
    #: encoded forms by key, once built (:meth:`encoded`)
    _encoded: dict[Hashable, bytes] | None = field(default=None, init=False, repr=False,
                                                   compare=False)

    kind: ClassVar[str] = "estimate"

    @property
    def latency_ms(self) -> float:
        """Host receive -> published, in milliseconds."""
        return (self.published_time - self.host_time) * 1e3

    @property
    def contact(self) -> bool:
        return bool(self.fit.get("contact"))

    @property
    def json_dict(self) -> dict[str, Any]:
        """The JSON form (:meth:`to_json_dict`), built on first use and kept: every consumer
        (WebSocket, REST, Zenoh, MCAP, ROS 2, the CLI) reads this one dict, so it must not be
        changed (take :meth:`to_json_dict` for a dict of your own)."""
        out = self._json
        if out is None:
            out = _envelope("estimate", self)
            out["latency_ms"] = _finite(round(self.latency_ms, 4))
            out["worker_ms"] = _finite(round(self.worker_ms, 4))
            out["gate"] = self.gate
            out["fitted_seq"] = self.fitted_seq
            out.update(self.fit)
            self._json = out
        return out

    def to_json_dict(self) -> dict[str, Any]:
        """The envelope keys, then the fit line's keys (contact, model, x_mm, ... message): a
        new dict (its values, the fit's, are shared: treat them as read-only)."""
        return dict(self.json_dict)

    def encoded(self, key: Hashable, build: Callable[[Estimate], bytes]) -> bytes:
        """This estimate's bytes in the encoding ``key`` names (e.g. a ROS 2 message's CDR
        for one topic kind, frame id and stamp), built by ``build(self)`` on first use and
        kept: every consumer of that encoding, on any thread, gets the same bytes object, built
        once per estimate.  ``key`` must name everything the bytes depend on besides the
        estimate."""
        with _encoding:
            cache = self._encoded
            if cache is None:
                cache = self._encoded = {}
            out = cache.get(key)
            if out is None:
                out = cache[key] = build(self)
            return out


@dataclass(frozen=True)
class ZeroedFrame:
    """A linearised, zeroed strain frame (dimensionless, positive under compression).

    ``strain`` is a read-only ``(rows, cols)`` float64 array with no NaN (the zeroer outputs 0
    for a non-finite tactel); ``contact`` is the detector's decision and ``statistic`` its
    matched-filter statistic (strain).  ``taxels``: a 3-axis array's zeroed readings
    ``(rows, cols, 3)`` (x, y, z, in the description's readings; None for a 1-axis array or
    before the 3-axis zero is known: :mod:`tactiled.pipeline.shear_track`).
    """

    sensor: str
    sensor_id: int
    seq: int
    device_time_us: int
    host_time: float  # s, monotonic
    contact: bool
    statistic: float
    strain: np.ndarray
    stamp: float = math.nan  # s since the Unix epoch: the frame's time (tactiled.clock)
    taxels: np.ndarray | None = None

    kind = "frame"

    def to_json_dict(self, digits: int = 6) -> dict[str, Any]:
        """The frame with strain rounded to ``digits`` decimals, rows first."""
        strain = np.round(np.nan_to_num(self.strain, nan=0.0, posinf=0.0, neginf=0.0), digits)
        out = _envelope("frame", self)
        out["contact"] = self.contact
        out["statistic"] = _finite(round(self.statistic, 9))
        out["strain"] = strain.tolist()
        if self.taxels is not None:
            out["taxels"] = np.round(self.taxels, 3).tolist()
        return out


def make_estimate(*, sensor: str, sensor_id: int, seq: int, device_time_us: int,
                  host_time: float, gate: str, fitted_seq: int | None, worker_ms: float,
                  fit: dict[str, Any], stamp: float | None = None) -> Estimate:
    """An :class:`Estimate` stamped as published now; ``stamp``: the frame's time (Unix s;
    None or NaN: now, for a frame no clock stamped)."""
    return Estimate(sensor, sensor_id, seq, device_time_us, host_time, time.monotonic(),
                    published_stamp(stamp), gate, fitted_seq, worker_ms, fit)


def published_stamp(stamp: float | None) -> float:
    """An estimate's stamp (Unix s): its frame's time, or now for a frame no clock stamped
    (None or NaN)."""
    return stamp if stamp is not None and math.isfinite(stamp) else time.time()


def zeroed_frame(sensor: str, sensor_id: int, seq: int, device_time_us: int, host_time: float,
                 contact: bool, statistic: float, strain: np.ndarray, stamp: float = math.nan,
                 taxels: np.ndarray | None = None) -> ZeroedFrame:
    """A :class:`ZeroedFrame` of these fields, in its order (the same as its constructor's,
    built faster: ``_record``)."""
    return _record(ZeroedFrame, {
        "sensor": sensor, "sensor_id": sensor_id, "seq": seq, "device_time_us": device_time_us,
        "host_time": host_time, "contact": contact, "statistic": statistic, "strain": strain,
        "stamp": stamp, "taxels": taxels,
    })

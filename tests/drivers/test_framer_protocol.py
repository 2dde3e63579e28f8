"""Every framer a driver can hand out is a :class:`tactiled.sources.Framer`: the wire format's
decoder and its compiled twin, each vendor framer in Python and in the compiled core, and the
framer each built-in driver builds from its URL."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
from collections.abc import Callable
from importlib import metadata
from typing import Any

import pytest

import tactiled_drivers
from tactiled import frames
from tactiled.sources import BUILTIN_DRIVERS, ENTRY_POINT_GROUP, Framer, open_source
from tactiled_drivers import flexitac, lines, paxini, robotiq, xela
from tactiled_drivers.plumbing import framing

#: each framer class, and how to build a small one
FRAMERS: dict[type, Callable[[], Any]] = {
    frames.FrameDecoder: frames.FrameDecoder,
    frames.NativeFrameDecoder: frames.NativeFrameDecoder,
    lines.LinesFramer: lambda: lines.LinesFramer(2, 3),
    lines.NativeLinesFramer: lambda: lines.NativeLinesFramer(2, 3),
    flexitac.FlexiTacFramer: lambda: flexitac.FlexiTacFramer(2, 3),
    flexitac.NativeFlexiTacFramer: lambda: flexitac.NativeFlexiTacFramer(2, 3),
    robotiq.RobotiqFramer: lambda: robotiq.RobotiqFramer(0),
    robotiq.NativeRobotiqFramer: lambda: robotiq.NativeRobotiqFramer(0),
    xela.XelaFramer: lambda: xela.XelaFramer(1, 2, 3),
    paxini.PaxiniFramer: lambda: paxini.PaxiniFramer(0, 2, 3),
}

#: a URL for each driver shipped with tactiled (building a source does no I/O)
URLS = {
    "serial": "serial:///dev/ttyACM0",
    "sim": "sim://?seed=1",
    "replay": "replay://session.tact",
    "lines": "lines:///dev/ttyACM0?rows=2&cols=3",
    "flexitac": "flexitac:///dev/ttyUSB0?rows=2&cols=3",
    "robotiq": "robotiq:///dev/ttyACM0?finger=0",
    "xela": "xela://127.0.0.1:5000?sensor=1",
    "paxini": "paxini:///dev/ttyACM0?module=0",
}


def _framer_classes() -> set[type]:
    """Every class of tactiled.frames and the drivers' modules that parses bytes into frames
    (it has ``feed`` and ``reset``), the bases that leave ``feed`` to subclasses aside."""
    modules = [frames] + [importlib.import_module(info.name) for info in pkgutil.walk_packages(
        tactiled_drivers.__path__, "tactiled_drivers.")]
    found = set()
    for module in modules:
        for _, cls in inspect.getmembers(module, inspect.isclass):
            if (cls.__module__ == module.__name__ and callable(getattr(cls, "feed", None))
                    and callable(getattr(cls, "reset", None))
                    and not getattr(cls, "_is_protocol", False)):
                found.add(cls)
    return found - {frames.NativeFraming, framing.NativeFramer}


def test_every_framer_class_is_checked_here() -> None:
    """A framer added to the drivers without joining :data:`FRAMERS` fails here."""
    assert _framer_classes() == set(FRAMERS)


@pytest.mark.parametrize("cls", list(FRAMERS), ids=lambda c: c.__name__)
def test_each_framer_is_a_framer(cls: type) -> None:
    framer = FRAMERS[cls]()
    assert isinstance(framer, Framer)
    params = inspect.signature(framer.feed).parameters
    assert list(params) == ["data", "host_time"] and params["host_time"].default is None
    assert framer.feed(b"", host_time=1.0) == []
    out = framer.feed(b"\xff\x00 not a frame \n" * 8, host_time=1.0)  # never raises
    assert out == [] and framer.buffered >= 0
    stats = framer.stats
    assert dataclasses.is_dataclass(stats) and stats.frames == 0
    assert framer.reset() is None and framer.buffered == 0


def test_an_object_without_reset_is_not_a_framer() -> None:
    class NoReset:
        stats = None
        buffered = 0

        def feed(self, data: bytes, host_time: float | None = None) -> list:
            return []

    assert not isinstance(NoReset(), Framer)


def test_every_shipped_driver_has_a_url_here() -> None:
    shipped = {point.name for point in metadata.entry_points(group=ENTRY_POINT_GROUP)
               if point.value.startswith("tactiled_drivers.")}
    assert shipped == set(URLS) and set(BUILTIN_DRIVERS) <= shipped


@pytest.mark.parametrize("scheme", sorted(URLS))
def test_each_shipped_driver_builds_a_framer(scheme: str) -> None:
    source = open_source(URLS[scheme])
    assert isinstance(source.decoder, Framer)
    assert type(source.decoder) in FRAMERS

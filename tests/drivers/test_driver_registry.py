"""The registry of drivers by URL scheme: a URL is checked by its scheme and query keys without
importing a shipped driver's module, and the table says what the drivers and pyproject say."""

from __future__ import annotations

import subprocess
import sys
from importlib import metadata

import pytest

from tactiled.errors import DriverError
from tactiled.sources import (
    BUILTIN_DRIVERS,
    ENTRY_POINT_GROUP,
    FrameSource,
    check_source_url,
    driver_class,
    register_driver,
    unregister_driver,
)


def test_the_table_is_the_entry_point_group() -> None:
    """Every driver shipped in tactiled_drivers is in the table, at the class pyproject names."""
    shipped = {point.name: point.value for point in metadata.entry_points(group=ENTRY_POINT_GROUP)
               if point.value.startswith("tactiled_drivers.")}
    assert shipped == {scheme: spec.target for scheme, spec in BUILTIN_DRIVERS.items()}


@pytest.mark.parametrize("scheme", sorted(BUILTIN_DRIVERS))
def test_the_table_lists_the_keys_each_driver_accepts(scheme: str) -> None:
    cls = driver_class(scheme)
    assert f"{cls.__module__}:{cls.__name__}" == BUILTIN_DRIVERS[scheme].target
    assert cls.PARAMS == BUILTIN_DRIVERS[scheme].params


def test_a_url_is_checked_without_importing_its_driver() -> None:
    code = """
import sys
from tactiled.sources import check_source_url
good = ["serial:///dev/ttyACM0?baud=115200", "robotiq:///dev/ttyACM0?finger=1&period_ms=5",
        "xela://127.0.0.1:5000?sensor=2", "lines:///dev/ttyACM0?rows=4&cols=4&sep=tab",
        "paxini:///dev/ttyACM0?module=0", "sim://?seed=3&depth_x=1.5", "replay://a.tact?speed=0"]
for url in good:
    assert check_source_url(url).url == url
for url in ["xela://127.0.0.1?sensr=1", "flexitac:///dev/ttyUSB0?row=12", "bogus://x"]:
    try:
        check_source_url(url)
    except ValueError as err:
        print("REFUSED:", err)
loaded = [m for m in sys.modules if m == "serial" or m.startswith("serial.")
          or m.startswith("tactiled_drivers") or m.startswith("websockets")]
print("LOADED:", loaded)
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert "LOADED: []" in lines
    refused = [line for line in lines if line.startswith("REFUSED:")]
    assert len(refused) == 3
    assert "unknown parameter(s) sensr; xela:// accepts cols, rows, sensor" in refused[0]
    assert "unknown parameter(s) row;" in refused[1]
    assert "unknown frame source scheme 'bogus'" in refused[2]


class Plugin(FrameSource):
    """A driver registered at run time (its keys come from its class)."""

    PARAMS = frozenset({"depth"})

    async def _open_internal(self) -> None:
        pass

    async def _close_internal(self) -> None:
        pass

    async def _read_internal(self) -> bytes:
        return b""


def test_a_registered_driver_is_checked_by_its_class() -> None:
    register_driver("plug", Plugin)
    register_driver("ghost", "no_such_module_for_tactiled:Ghost")
    try:
        assert check_source_url("plug://x?depth=2").params == {"depth": "2"}
        with pytest.raises(ValueError, match=r"unknown parameter\(s\) width; plug:// accepts"):
            check_source_url("plug://x?width=2")
        with pytest.raises(DriverError, match="'ghost'.*unavailable"):
            check_source_url("ghost://x")
        # A driver registered for a shipped scheme replaces it, keys and all.
        register_driver("xela", Plugin)
        assert check_source_url("xela://h?depth=1").params == {"depth": "1"}
        with pytest.raises(ValueError, match="sensor"):
            check_source_url("xela://h?sensor=1")
    finally:
        for scheme in ("plug", "ghost", "xela"):
            unregister_driver(scheme)
    assert check_source_url("xela://h?sensor=1").params == {"sensor": "1"}

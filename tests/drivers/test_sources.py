"""The core side of frame sources: URL parsing, the driver registry, the base class."""

from __future__ import annotations

import asyncio
import subprocess
import sys
from importlib import metadata
from typing import ClassVar

import pytest

from tactiled import sources
from tactiled.errors import DeviceTimeoutError, DriverError
from tactiled.frames import FrameDecoder, encode_frame
from tactiled.sources import (
    BUILTIN_DRIVERS,
    FrameSource,
    SourceURL,
    driver_class,
    known_schemes,
    open_source,
    parse_source_url,
    register_driver,
    unregister_driver,
)


class MemorySource(FrameSource):
    """Serves given byte chunks, then ends; a test double for the base-class behaviour."""

    PARAMS: ClassVar[frozenset[str]] = frozenset({"n"})
    chunks: ClassVar[list[bytes]] = []

    async def _open_internal(self) -> None:
        self._queue = list(self.chunks)
        self.closed_calls = 0

    async def _close_internal(self) -> None:
        self.closed_calls += 1

    async def _read_internal(self) -> bytes:
        if not self._queue:
            return b""
        chunk = self._queue.pop(0)
        if chunk == b"STALL":
            await asyncio.Event().wait()
        return chunk


@pytest.fixture
def memory_scheme():
    register_driver("mem", MemorySource)
    yield "mem"
    unregister_driver("mem")
    MemorySource.chunks = []


# -- URLs -------------------------------------------------------------------------------------


def test_parse_url_forms() -> None:
    u = parse_source_url("serial:///dev/ttyACM0?baud=115200")
    assert (u.scheme, u.location, dict(u.params)) == ("serial", "/dev/ttyACM0",
                                                      {"baud": "115200"})
    assert parse_source_url("SIM://?seed=3&scene=press").scheme == "sim"
    assert parse_source_url("sim://?seed=3").location == ""
    assert parse_source_url("replay://rec/a.tact").location == "rec/a.tact"
    assert parse_source_url("replay:///abs/a%20b.tact").location == "/abs/a b.tact"
    assert parse_source_url("serial://COM3").location == "COM3"


def test_typed_params() -> None:
    u = parse_source_url("x://?i=42&f=0.5&b=yes&s=live&neg=-3&e=")
    assert u.get_int("i", 0) == 42 and u.get_int("missing", 7) == 7
    assert u.get_float("f", 1.0) == 0.5 and u.get_float("i", 0.0) == 42.0
    assert u.get_bool("b", False) is True and u.get_bool("missing", True) is True
    assert u.get_str("s", "", choices=("live", "recorded")) == "live"
    assert u.get_str("e", "x") == ""
    with pytest.raises(ValueError, match=r"neg='-3' is not >= 0"):
        u.get_int("neg", 0, minimum=0)
    with pytest.raises(ValueError, match=r"i='42' is not <= 10"):
        u.get_int("i", 0, maximum=10)
    with pytest.raises(ValueError, match=r"f='0.5' is not an integer"):
        u.get_int("f", 0)
    with pytest.raises(ValueError, match=r"s='live' is not a number"):
        u.get_float("s", 0.0)
    with pytest.raises(ValueError, match=r"s='live' is not a boolean"):
        u.get_bool("s", False)
    with pytest.raises(ValueError, match=r"s='live' is not one of a, b"):
        u.get_str("s", "", choices=("a", "b"))
    for bad in ("nan", "inf", "-inf"):
        with pytest.raises(ValueError, match="finite"):
            parse_source_url(f"x://?f={bad}").get_float("f", 0.0)


@pytest.mark.parametrize(
    ("url", "message"),
    [
        ("", "empty"),
        ("/dev/ttyACM0", "no scheme"),
        ("://x", "no scheme"),
        ("sim://?seed=1&seed=2", "'seed' given more than once"),
        ("sim://?seed", "malformed query"),
        ("replay://a.tact#frag", "fragment"),
        (None, "must be a string"),
    ],
)
def test_bad_urls(url, message) -> None:
    with pytest.raises(ValueError, match=message):
        parse_source_url(url)


def test_unknown_parameter_named(memory_scheme) -> None:
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) bogus, zz.*accepts n"):
        open_source("mem://?n=1&bogus=2&zz=3")


# -- registry ---------------------------------------------------------------------------------


def test_unknown_scheme_names_it_and_lists_known() -> None:
    with pytest.raises(ValueError) as info:
        open_source("tcp://localhost:9000")
    text = str(info.value)
    assert "'tcp'" in text
    for scheme in ("replay", "serial", "sim"):
        assert scheme in text


def test_builtins_registered_by_name() -> None:
    assert BUILTIN_DRIVERS["serial"].target == "tactiled_drivers.serial:SerialSource"
    assert BUILTIN_DRIVERS["sim"].target == "tactiled_drivers.sim:SimSource"
    assert BUILTIN_DRIVERS["replay"].target == "tactiled_drivers.replay:ReplaySource"
    assert {"serial", "sim", "replay"} <= set(known_schemes())
    assert driver_class("serial").__name__ == "SerialSource"
    assert driver_class("REPLAY").__name__ == "ReplaySource"


def test_core_imports_no_driver_and_no_pyserial() -> None:
    code = ("import sys, tactiled.sources, tactiled.io.recording\n"
            "bad = [m for m in sys.modules if m == 'serial' or m.startswith('serial.')"
            " or m.startswith('tactiled_drivers')]\n"
            "print(bad); sys.exit(1 if bad else 0)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stdout + done.stderr


def test_missing_library_breaks_only_its_driver(tmp_path) -> None:
    # pyserial made unimportable: serial:// fails with a DriverError naming the driver,
    # replay:// still works.
    code = f"""
import asyncio, sys
sys.modules["serial"] = None
from tactiled.errors import DriverError
from tactiled.io.recording import RecordingWriter
from tactiled.sources import open_source
try:
    open_source("serial:///dev/ttyACM0")
except DriverError as err:
    print("SERIAL:", err)
with RecordingWriter({str(tmp_path / 'r.tact')!r}) as w:
    pass
async def main():
    async with open_source("replay://{tmp_path / 'r.tact'}?speed=0") as src:
        print("REPLAY:", [f async for f in src.frames()])
asyncio.run(main())
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    assert "SERIAL: driver 'serial' (tactiled_drivers.serial:SerialSource) is " \
           "unavailable" in done.stdout
    assert "REPLAY: []" in done.stdout


def test_registered_string_target_loaded_lazily(memory_scheme) -> None:
    register_driver("ghost", "no_such_module_for_tactiled:Ghost")
    try:
        assert "ghost" in known_schemes()
        with pytest.raises(DriverError, match=r"'ghost'.*unavailable.*no_such_module"):
            open_source("ghost://x")
        register_driver("ghost", "tactiled.errors:DriverError")
        with pytest.raises(DriverError, match="not a FrameSource subclass"):
            open_source("ghost://x")
        register_driver("ghost", "tactiled.errors:Nope")
        with pytest.raises(DriverError, match="has no Nope"):
            open_source("ghost://x")
    finally:
        unregister_driver("ghost")
    with pytest.raises(ValueError, match="module:Class"):
        register_driver("ghost", "no_colon")
    with pytest.raises(ValueError, match="invalid URL scheme"):
        register_driver("bad scheme", MemorySource)


def test_entry_point_group(monkeypatch, caplog) -> None:
    points = metadata.EntryPoints([
        metadata.EntryPoint("mem2", f"{__name__}:MemorySource", sources.ENTRY_POINT_GROUP),
        metadata.EntryPoint("serial", "evil.module:Hijack", sources.ENTRY_POINT_GROUP),
    ])
    calls = []

    def fake_entry_points(*, group: str):
        calls.append(group)
        return points.select(group=group)

    monkeypatch.setattr(metadata, "entry_points", fake_entry_points)
    monkeypatch.setattr(sources, "_entry_points", None)
    with caplog.at_level("WARNING", logger="tactiled.sources"):
        assert driver_class("mem2") is MemorySource
    assert "ignoring entry point serial=evil.module:Hijack" in caplog.text
    assert "mem2" in known_schemes()
    # A plug-in cannot take over a built-in scheme.
    assert driver_class("serial").__module__ == "tactiled_drivers.serial"
    assert calls == [sources.ENTRY_POINT_GROUP]  # read once, then cached


def test_pyproject_entry_point_table_is_loadable() -> None:
    # Whatever the installed distribution declares in the group must load.
    for point in metadata.entry_points(group=sources.ENTRY_POINT_GROUP):
        assert issubclass(driver_class(point.name), FrameSource)


# -- the base class ---------------------------------------------------------------------------


def test_frames_decode_through_the_shared_decoder(memory_scheme, frame_factory,
                                                  same_frame) -> None:
    sent = frame_factory(3)
    wire = b"".join(map(encode_frame, sent))
    MemorySource.chunks = [wire[:10], wire[10:200], wire[200:]]
    decoder = FrameDecoder()

    async def main() -> None:
        src = open_source("mem://?n=1", decoder=decoder)
        assert isinstance(src, MemorySource) and src.url.get_int("n", 0) == 1
        assert not src.is_open and not src.connected
        async with src:
            assert src.is_open and src.connected
            got = [f async for f in src.frames()]
        assert src.closed_calls == 1 and not src.connected
        assert all(same_frame(a, b) for a, b in zip(got, sent, strict=True))
        assert src.bytes_read == len(wire)
        assert src.decoder is decoder and decoder.stats.frames == 3
        status = src.status()
        assert status.bytes_read == len(wire) and status.decoder["frames"] == 3
        assert status.url == "mem://?n=1" and status.connected is False

    asyncio.run(main())


def test_frame_batches_hand_each_reads_frames_together(memory_scheme, frame_factory,
                                                       same_frame) -> None:
    sent = frame_factory(5)
    wire = [encode_frame(f) for f in sent]
    # a read of three whole frames, a read of half a frame, a read of the rest and one more
    half = len(wire[3]) // 2
    MemorySource.chunks = [b"".join(wire[:3]), wire[3][:half], wire[3][half:] + wire[4]]

    async def main() -> list[list]:
        async with open_source("mem://") as src:
            return [batch async for batch in src.frame_batches()]

    batches = asyncio.run(main())
    assert [len(b) for b in batches] == [3, 2]
    assert all(same_frame(a, b) for a, b in zip(sum(batches, []), sent, strict=True))

    class OwnFrames(MemorySource):  # a driver that makes its frames itself: one per list
        async def frames(self, timeout=None):  # type: ignore[override]
            for f in sent[:2]:
                yield f

    async def own() -> list[list]:
        async with OwnFrames("mem://") as src:
            return [batch async for batch in src.frame_batches()]

    assert asyncio.run(own()) == [[sent[0]], [sent[1]]]


def test_read_requires_open_and_open_twice_fails(memory_scheme) -> None:
    async def main() -> None:
        src = open_source("mem://")
        with pytest.raises(DriverError, match="not open"):
            await src.read()
        await src.open()
        with pytest.raises(DriverError, match="already open"):
            await src.open()
        await src.close()
        await src.close()
        assert src.closed_calls == 1

    asyncio.run(main())


def test_read_timeout_raises_device_timeout(memory_scheme) -> None:
    MemorySource.chunks = [b"STALL"]

    async def main() -> None:
        async with open_source("mem://") as src:
            with pytest.raises(DeviceTimeoutError, match=r"mem://: no data within 0.02 s"):
                await src.read(timeout=0.02)
        assert isinstance(DeviceTimeoutError("x"), TimeoutError)

    asyncio.run(main())


def test_source_url_object_accepted(memory_scheme) -> None:
    src = MemorySource(SourceURL("mem://", "mem", ""))
    assert "MemorySource 'mem://' closed" in repr(src)

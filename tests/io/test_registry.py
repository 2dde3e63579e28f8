"""The file-format registry: a reader and a writer by what a file holds and its suffix."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tactiled import io
from tactiled.calibration.lut import LookupTable
from tactiled.calibration.presses import PressSet
from tactiled.frames import Frame, encode_frame


def test_a_recording_written_and_read_through_the_registry_keeps_its_bytes(tmp_path: Path) -> None:
    path = tmp_path / "session.tact"
    frames = [Frame(seq=k, device_time_us=1000 * k, raw=np.full((8, 8), 100 + k, np.uint16))
              for k in range(5)]
    with io.writer("recording", path)(path, sensor_id=3) as out:
        for k, f in enumerate(frames):
            out.write(0.5 * k, encode_frame(f))
    with io.reader("recording", path)(path) as rec:
        assert rec.header.sensor_id == 3
        assert list(rec) == [(0.5 * k, encode_frame(f)) for k, f in enumerate(frames)]


def test_two_kinds_share_npz_and_each_gets_its_own_format(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    strain = rng.normal(0, 1e-3, (3, 8, 8))
    frames_path = tmp_path / "frames.npz"
    io.writer("frames", frames_path)(frames_path, strain, 3.3, 3.9)
    loaded = io.reader("frames", frames_path)(frames_path)
    np.testing.assert_array_equal(loaded.strain, strain)
    assert (loaded.dx, loaded.dy) == (3.3, 3.9)

    presses = PressSet(rng.integers(9000, 12000, (4, 8, 8)).astype(np.uint16),
                       rng.uniform(0, 0.05, (4, 8, 8)), sensor_id=7)
    presses_path = tmp_path / "presses.npz"
    io.writer("presses", presses_path)(presses, presses_path)
    back = io.reader("presses", presses_path)(presses_path)
    np.testing.assert_array_equal(back.counts, presses.counts)
    np.testing.assert_array_equal(back.strain_ref, presses.strain_ref)
    assert back.sensor_id == 7


def test_a_calibration_file_round_trips_through_the_registry(tmp_path: Path) -> None:
    path = tmp_path / "cal.json"
    table = LookupTable.linear(8, 8, 20000.0, 10000.0, sensor_id=2)
    io.writer("calibration", path)(table, path)
    cal = io.reader("calibration", path)(path)
    counts = np.full((8, 8), 10400, np.uint16)
    np.testing.assert_allclose(cal.table.to_strain(counts), (10400 - 10000) / 20000.0, rtol=1e-12)
    assert cal.table.sensor_id == 2


def test_an_unknown_suffix_is_refused_naming_the_known_ones(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"no recording writer for '\.bag' \(known: \.tact\)"):
        io.writer("recording", tmp_path / "x.bag")
    with pytest.raises(ValueError, match=r"no frames reader for 'a name without a suffix'"):
        io.reader("frames", tmp_path / "x")


def test_a_format_registered_at_run_time_is_found_and_can_be_a_string(tmp_path: Path) -> None:
    try:
        io.register("frames", ".TXT", reader=np.loadtxt, writer="numpy:savetxt")
        assert io.reader("frames", tmp_path / "a.txt") is np.loadtxt
        assert io.writer("frames", tmp_path / "a.Txt") is np.savetxt
        assert ".txt" in io.suffixes("frames")
    finally:
        io._registered.clear()
    with pytest.raises(ValueError):
        io.reader("frames", tmp_path / "a.txt")


def test_the_services_mcap_writer_comes_through_its_entry_point() -> None:
    """``messages.mcap`` is registered by the service's packaging, not imported by the core:
    importing the registry imports no format module and no service module."""
    code = (
        "import sys\n"
        "from tactiled import io\n"
        "before = sorted(m for m in sys.modules if m.startswith(('tactiled.io.', 'tactiled_service')))\n"
        "w = io.writer('messages', 'out.mcap')\n"
        "print(before)\n"
        "print(w.__module__ + ':' + w.__name__)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         check=True).stdout.splitlines()
    assert out == ["[]", "tactiled_service.ros2.mcap_file:McapWriter"]

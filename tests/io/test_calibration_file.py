"""Calibration files: round trip, and every refusal of the loader with its message."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tactiled.calibration import LookupTable
from tactiled.io.calibration import load_calibration, save_calibration, table_to_dict
from tactiled.errors import CalibrationError


@pytest.fixture
def table(random_knots) -> LookupTable:
    rng = np.random.default_rng(7)
    counts, strain = random_knots(rng, 64)
    flags = [()] * 64
    flags[10] = ("dead",)
    rms = rng.uniform(1e-4, 1e-3, (8, 8))
    return LookupTable(8, 8, counts, strain, sensor_id=42, created="2024-05-01T12:00:00Z",
                       flags=flags, rms_residual=rms)


@pytest.fixture
def doc(table) -> dict:
    return json.loads(json.dumps(table_to_dict(table)))


def _write(tmp_path: Path, content) -> Path:
    path = tmp_path / "cal.json"
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    return path


def test_round_trip_is_exact(table, tmp_path):
    path = save_calibration(table, tmp_path / "cal.json", build={"note": "test"})
    loaded = load_calibration(path, shape=(8, 8), sensor_id=42)
    assert (loaded.sensor_id, loaded.shape, loaded.created) == (42, (8, 8), "2024-05-01T12:00:00Z")
    assert loaded.flags == table.flags
    np.testing.assert_array_equal(loaded.rms_residual, table.rms_residual)
    np.testing.assert_array_equal(loaded.dead_mask, table.dead_mask)
    for m in range(8):
        for n in range(8):
            for a, b in zip(loaded.knots(m, n), table.knots(m, n)):
                np.testing.assert_array_equal(a, b)  # floats survive JSON bit for bit
    raw = np.random.default_rng(0).integers(0, 1 << 16, (50, 8, 8), dtype=np.uint16)
    np.testing.assert_array_equal(loaded.to_strain(raw), table.to_strain(raw))
    assert json.loads(path.read_text())["build"] == {"note": "test"}
    assert not list(tmp_path.glob("*.tmp"))  # the atomic write cleaned up


def test_the_file_is_human_readable_one_line_per_tactel(table, tmp_path):
    text = save_calibration(table, tmp_path / "cal.json").read_text()
    assert text.startswith('{\n "format": "tactiled-calibration",\n "version": 1,')
    assert sum(line.startswith('  {"index"') for line in text.splitlines()) == 64


def test_refuses_truncated_json(table, tmp_path):
    text = save_calibration(table, tmp_path / "full.json").read_text()
    path = _write(tmp_path, text[: len(text) // 2])
    with pytest.raises(CalibrationError, match=r"cal\.json: not valid JSON \(truncated\?\)"):
        load_calibration(path)


def test_refuses_missing_and_unreadable_files(tmp_path):
    with pytest.raises(CalibrationError, match=r"nope\.json: no such file"):
        load_calibration(tmp_path / "nope.json")
    (tmp_path / "bin.json").write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(CalibrationError, match="bin.json"):
        load_calibration(tmp_path / "bin.json")


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.update(format="something-else"),
         r"key 'format' is 'something-else', expected 'tactiled-calibration'"),
        (lambda d: d.update(version=3), r"key 'version' is 3; this tactiled reads versions 1, 2"),
        (lambda d: d.update(version=2), r"missing key 'model' \(version 2\)"),
        (lambda d: d.update(version="1"), r"key 'version' is '1'"),
        (lambda d: d.pop("sensor_id"), r"missing key 'sensor_id'"),
        (lambda d: d.pop("created"), r"missing key 'created'"),
        (lambda d: d.update(sensor_id=70000), r"key 'sensor_id' must be an integer 0\.\.65535"),
        (lambda d: d.update(rows=0), r"key 'rows' must be a positive integer"),
        (lambda d: d.update(rows=7),
         r"key 'tactels' has 64 entries, expected rows\*cols = 7\*8 = 56"),
        (lambda d: d["tactels"].pop(), r"key 'tactels' has 63 entries, expected .* = 64"),
        (lambda d: d["tactels"][9].pop("strain"),
         r"tactel \[1, 1\] \(index 9\): missing key 'strain'"),
        (lambda d: d["tactels"][9].update(index=[0, 9]),
         r"tactel \[1, 1\] \(index 9\): key 'index' is \[0, 9\], expected \[1, 1\]"),
        (lambda d: d["tactels"][3]["strain"].pop(),
         r"tactel \[0, 3\] \(index 3\): 'counts' has \d+ knots but 'strain' has \d+"),
        (lambda d: d["tactels"][5].update(counts=[100.0, 200.0, 150.0], strain=[0.0, 0.1, 0.2]),
         r"tactel \[0, 5\] \(index 5\): 'counts' knots must be strictly increasing, but knot 2 "
         r"\(150\.0\) <= knot 1 \(200\.0\)"),
        (lambda d: d["tactels"][63].update(counts=[100.0, 200.0, 300.0], strain=[0.0, 0.1, 0.05]),
         r"tactel \[7, 7\] \(index 63\): 'strain' knots must be non-decreasing .* knot 2 "
         r"\(0\.05\) < knot 1 \(0\.1\)"),
        (lambda d: d["tactels"][8].update(counts=[100.0], strain=[0.0]),
         r"tactel \[1, 0\] \(index 8\): 'counts' needs at least 2 knots"),
        (lambda d: d["tactels"][8].update(counts=[100.0, "x"]),
         r"tactel \[1, 0\] \(index 8\): 'counts' is not a list of numbers"),
        (lambda d: d["tactels"][8].update(flags=["sticky"]),
         r"tactel \[1, 0\] \(index 8\): unknown flag 'sticky'"),
    ],
)
def test_refuses_bad_documents_naming_the_key(doc, tmp_path, edit, message):
    edit(doc)
    with pytest.raises(CalibrationError, match=r"cal\.json: " + message):
        load_calibration(_write(tmp_path, doc))


def test_refuses_nan_knots(doc, tmp_path):
    # Python's json writes NaN as a bare token; other writers might too.  Refuse it by name.
    doc["tactels"][12]["strain"][1] = float("nan")
    path = _write(tmp_path, json.dumps(doc))
    assert "NaN" in path.read_text()
    expected = r"tactel \[1, 4\] \(index 12\): 'strain' knot 1 is not finite \(nan\)"
    with pytest.raises(CalibrationError, match=expected):
        load_calibration(path)
    doc["tactels"][12]["strain"][1] = 0.0
    doc["tactels"][0]["counts"][0] = float("-inf")
    with pytest.raises(CalibrationError, match=r"tactel \[0, 0\] .*'counts' knot 0 is not finite"):
        load_calibration(_write(tmp_path, json.dumps(doc)))


def test_refuses_non_object_top_level(tmp_path):
    with pytest.raises(CalibrationError, match="top level must be a JSON object, got list"):
        load_calibration(_write(tmp_path, "[1, 2]"))


def test_refuses_a_table_for_another_sensor_or_shape(table, tmp_path):
    path = save_calibration(table, tmp_path / "cal.json")
    with pytest.raises(CalibrationError, match=r"key 'sensor_id' is 42, but the sensor reports 7"):
        load_calibration(path, sensor_id=7)
    with pytest.raises(CalibrationError,
                       match=r"table shape \(8, 8\) .* does not match the sensor's \(4, 4\)"):
        load_calibration(path, shape=(4, 4))


def test_save_reports_unwritable_paths(table, tmp_path):
    with pytest.raises(CalibrationError, match="cal.json: cannot write it: no directory"):
        save_calibration(table, tmp_path / "missing-dir" / "cal.json")

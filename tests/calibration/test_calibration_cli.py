"""``tactiled calibrate`` as a user runs it: a subprocess of the installed console script."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tactiled.io.calibration import load_calibration
from tactiled.io.presses import save_presses

TACTILED = Path(sys.executable).with_name("tactiled")


def _run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(TACTILED), "calibrate", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=60)


@pytest.fixture(scope="module")
def press_file(tmp_path_factory, synthetic_faulty) -> Path:
    return save_presses(synthetic_faulty[0], tmp_path_factory.mktemp("presses") / "presses.npz")


def test_good_file_prints_the_grid_and_writes_the_table(press_file, tmp_path):
    result = _run(str(press_file), "-o", "cal.json", "--knots", "6", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[2].split() == [f"n={n}" for n in range(8)]
    grid = lines[3:11]
    assert [row.split()[0] for row in grid] == [f"m={m}" for m in range(8)]
    assert grid[2].split()[6].endswith("D") and grid[6].split()[7].endswith("N")
    assert "dead: 1 ([2, 5]); non-monotone: 1 ([6, 6])" in result.stdout
    assert "wrote cal.json" in result.stdout
    assert "2 tactel(s) flagged" in result.stderr
    table = load_calibration(tmp_path / "cal.json", shape=(8, 8), sensor_id=1)
    assert max(len(table.knots(m, n)[0]) for m in range(8) for n in range(8)) == 6
    strict = _run(str(press_file), "-o", "cal2.json", "--strict", cwd=tmp_path)
    assert strict.returncode == 1 and (tmp_path / "cal2.json").exists()


@pytest.mark.parametrize(
    ("make", "extra", "message"),
    [
        (lambda p: p.write_bytes(b"PK\x03\x04 truncated"), (), "not a complete .npz press file"),
        (lambda p: np.savez(p, counts=np.zeros((3, 2, 2), np.uint16)), (),
         "missing array 'strain_ref'"),
        (lambda p: None, (), "bad.npz: no such file"),
        (lambda p: np.savez(p, counts=np.zeros((3, 2, 2), np.uint16),
                            strain_ref=np.zeros((3, 2, 2)), sensor_id=np.array(4)),
         ("--sensor-id", "5"), "recorded from sensor 4, not 5"),
        (lambda p: p.write_bytes(b""), ("--knots", "1"), "--knots must be >= 2"),
    ],
)
def test_bad_input_exits_2_with_one_clear_line(tmp_path, make, extra, message):
    path = tmp_path / "bad.npz"
    make(path)
    result = _run(str(path), "-o", "cal.json", *extra, cwd=tmp_path)
    assert result.returncode == 2
    err = result.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tactiled calibrate: error: "), result.stderr
    assert message in err[0]
    assert result.stdout == "" and not (tmp_path / "cal.json").exists()


def test_missing_arguments_exit_2(tmp_path):
    result = _run(cwd=tmp_path)
    assert result.returncode == 2 and "need PRESSES.npz and -o CAL.json" in result.stderr

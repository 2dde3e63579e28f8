"""What a newcomer meets first, run as the newcomer runs it (the installed console script):
a mistyped flag answered with that command's usage, a flag named in the error it caused, frames
of an array no description names refused with one line instead of fitted with the paper's
pitch, a calibration of another sensor id refused at start, and the program described as what
it is (any taxel array, not only the paper's cylindrical finger)."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np

from tactiled.calibration import LookupTable
from tactiled.io.calibration import save_calibration

ROOT = Path(__file__).resolve().parents[2]
TACTILED = Path(sys.executable).with_name("tactiled")


def tactiled(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([str(TACTILED), *args], cwd=cwd, capture_output=True, text=True,
                          timeout=120)


def test_a_bad_flag_prints_the_commands_own_usage() -> None:
    done = tactiled("simulate", "--bogus")
    assert done.returncode == 2
    assert done.stderr.startswith("usage: tactiled simulate ")
    assert done.stderr.rstrip().endswith("tactiled simulate: error: unrecognized arguments: --bogus")
    top = tactiled("--bogus")
    assert top.returncode == 2 and top.stderr.startswith("usage: tactiled [-h]")


def test_a_flags_bad_value_names_the_flag() -> None:
    done = tactiled("run", "--port", "99999")
    assert done.returncode == 2
    assert done.stderr.splitlines() == [
        "tactiled run: error: server.port: must be a TCP port in 0..65535, got 99999 (from --port)"]


def test_frames_of_an_unnamed_array_are_refused_with_one_line(tmp_path: Path) -> None:
    np.savez(tmp_path / "f57.npz", strain=np.zeros((2, 5, 7)))
    np.savez(tmp_path / "f16.npz", strain=np.zeros((2, 16, 16)))
    done = tactiled("fit", "f57.npz", cwd=tmp_path)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.splitlines() == [
        "tactiled fit: error: 5x7 frames, but no sensor says what array they come from and the "
        "file gives no pitch (dx, dy): name it with --sensor NAME|FILE.toml; `tactiled sensors` "
        "lists the built-in arrays"]
    sixteen = tactiled("fit", "f16.npz", cwd=tmp_path)
    assert sixteen.returncode == 2 and "(flat16 is 16x16)" in sixteen.stderr
    # named, or with its pitch in the file, it is fitted
    assert tactiled("fit", "f16.npz", "--sensor", "flat16", cwd=tmp_path).returncode == 0
    np.savez(tmp_path / "f57dx.npz", strain=np.zeros((2, 5, 7)), dx=2.0, dy=2.0)
    fitted = tactiled("fit", "f57dx.npz", cwd=tmp_path)
    assert fitted.returncode == 0, fitted.stderr
    assert len(fitted.stdout.splitlines()) == 2


def test_a_calibration_of_another_sensor_id_stops_the_daemon_with_one_line(tmp_path: Path) -> None:
    """A text-lines pad sends no id (0); a calibration made with --sensor-id 3 would drop every
    frame: refused before anything opens."""
    save_calibration(LookupTable.linear(8, 8, sensor_id=3), tmp_path / "cal3.json")
    (tmp_path / "pad.toml").write_text(
        '[server]\nport = 0\n[[sensor]]\nname = "pad"\n'
        f'url = "lines://{tmp_path}/ttyPAD?rows=8&cols=8"\ncalibration = "cal3.json"\n')
    done = tactiled("run", "--config", "pad.toml", cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.splitlines() == [
        f"tactiled run: error: sensor pad: lines://{tmp_path}/ttyPAD?rows=8&cols=8 sends sensor "
        "id 0, but its calibration cal3.json is of sensor id 3: every frame would be dropped "
        "(calibrate with --sensor-id 0)"]
    # a Robotiq finger sends its finger number; the wire_id key is checked the same way
    (tmp_path / "tsf.toml").write_text(
        '[server]\nport = 0\n[[sensor]]\nname = "left"\ndescription = "robotiq_tsf85"\n'
        f'url = "robotiq://{tmp_path}/ttyTSF?finger=1"\nwire_id = 0\n')
    tsf = tactiled("run", "--config", "tsf.toml", cwd=tmp_path)
    assert tsf.returncode == 2
    assert tsf.stderr.splitlines()[-1].endswith(
        "sends sensor id 1, but its wire_id is 0: every frame would be dropped (set wire_id = 1)")


def test_the_program_says_it_reads_any_array() -> None:
    described = tactiled("--help").stdout
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["description"]
    for text in (described, meta):
        assert "cylindrical fingertip" not in text and "cylindrical robot fingertips" not in text
        assert "taxel array" in " ".join(text.split())

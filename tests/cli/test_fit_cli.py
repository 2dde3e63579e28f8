"""`tactiled fit` and `tactiled simulate` as a user (and outside tools) run them: subprocesses."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

TACTILED = [sys.executable, "-m", "tactiled.cli"]
KEYS = {"frame", "contact", "model", "x_mm", "y_mm", "force_n", "r1_mm", "r2_mm", "angle_deg", "rms", "std", "fit_ms"}
STD_KEYS = {"x_mm", "y_mm", "force_n", "r1_mm", "r2_mm", "angle_deg"}


def run(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    proc = subprocess.run([*TACTILED, *args], capture_output=True, text=True, timeout=120)
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


def test_simulate_then_fit_json_contract(tmp_path: Path):
    out = tmp_path / "cyl.npz"
    run("simulate", str(out), "--r1", "10", "--angle", "45", "--force", "1.2", "--x", "11", "--y", "13",
        "--frames", "6", "--empty", "0.3", "--seed", "4")
    data = np.load(out)
    assert data["strain"].shape == (6, 8, 8)
    assert float(data["dx"]) == 3.3 and float(data["dy"]) == 3.9
    proc = run("fit", str(out))
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 6
    for i, line in enumerate(lines):
        obj = json.loads(line)  # strict JSON: no NaN
        assert KEYS <= obj.keys()
        assert obj["frame"] == i
        empty = math.isnan(float(data["true_r1"][i]))
        assert obj["contact"] is (not empty)
        if obj["contact"]:
            assert obj["model"] == "cylinder"
            assert set(obj["std"]) == STD_KEYS
            assert obj["r2_mm"] is None and obj["std"]["r2_mm"] is None
            assert 0 <= obj["angle_deg"] < 180
            # within 4 reported sigma of the truth
            assert abs(obj["x_mm"] - 11) < 4 * obj["std"]["x_mm"]
            assert abs(obj["force_n"] - 1.2) < 4 * obj["std"]["force_n"]
            assert abs(obj["angle_deg"] - 45) < 4 * obj["std"]["angle_deg"]
            assert abs(obj["r1_mm"] - 10) < 4 * obj["std"]["r1_mm"]
            assert obj["fit_ms"] > 0
        else:
            assert obj["model"] is None


@pytest.mark.parametrize("model", ["auto", "sphere", "general"])
def test_models_and_window_options(tmp_path: Path, model: str):
    out = tmp_path / "sph.npz"
    run("simulate", str(out), "--r1", "4", "--sphere", "--force", "1.5", "--frames", "2")
    obj = json.loads(run("fit", str(out), "--model", model, "--window", "6").stdout.splitlines()[0])
    assert obj["model"] in ("sphere", "general", "cylinder")
    if model == "sphere":
        assert obj["angle_deg"] is None and obj["r2_mm"] == obj["r1_mm"]
    if model == "auto":
        assert obj["model"] == "sphere"


def test_plain_strain_file_without_pitch(tmp_path: Path):
    from tactiled.physics.contact import Contact
    from tactiled.physics.strain import StrainModel

    f = tmp_path / "plain.npz"
    np.savez(f, strain=StrainModel().predict(Contact(6, math.inf, 100, 1.0, 10, 12))[None])
    obj = json.loads(run("fit", str(f)).stdout)
    assert obj["r1_mm"] == pytest.approx(6, rel=1e-3)


def bad_files(tmp_path: Path):
    good = np.zeros((2, 8, 8))
    np.savez(tmp_path / "missing.npz", frames=good)
    yield "missing.npz", "missing array 'strain'"
    np.savez(tmp_path / "shape.npz", strain=np.zeros((2, 64)))
    yield "shape.npz", "shape (N, rows, cols)"
    nan = good.copy()
    nan[1, 2, 3] = np.nan
    np.savez(tmp_path / "nan.npz", strain=nan)
    yield "nan.npz", "non-finite value(s), first at frame 1 tactel [2, 3]"
    (tmp_path / "junk.npz").write_bytes(b"not a zip file at all")
    yield "junk.npz", "not a readable .npz"
    np.savez(tmp_path / "pitch.npz", strain=good, dx=-1.0)
    yield "pitch.npz", "'dx' must be a positive pitch"
    np.savez(tmp_path / "text.npz", strain=np.array([["a"]]))
    yield "text.npz", "real numeric array"
    yield "absent.npz", "no such file"


def test_bad_files_get_one_clear_line_and_exit_2(tmp_path: Path):
    for name, message in bad_files(tmp_path):
        proc = run("fit", str(tmp_path / name), check=False)
        assert proc.returncode == 2, name
        err = proc.stderr.strip().splitlines()
        assert len(err) == 1 and message in err[0], (name, proc.stderr)
        assert proc.stdout == ""


def test_bad_options_exit_2(tmp_path: Path):
    out = tmp_path / "c.npz"
    run("simulate", str(out), "--frames", "1")
    assert run("fit", str(out), "--model", "banana", check=False).returncode == 2
    assert run("fit", str(out), "--window", "1", check=False).returncode == 2
    assert run("simulate", str(tmp_path / "x.npz"), "--r1", "5:1", check=False).returncode == 2
    assert run("simulate", str(tmp_path / "x.npz"), "--force", "-1", check=False).returncode == 2


def test_help_explains():
    proc = run("--help")
    for name in ("run", "fit", "simulate", "bench"):
        assert name in proc.stdout
    fit_help = run("fit", "--help").stdout
    assert "FRAMES.npz" in fit_help and "--model" in fit_help and "--window" in fit_help

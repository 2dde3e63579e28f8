"""`tactiled simulate` and `tactiled fit` on a 3-axis array, as a user runs them: subprocesses."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

TACTILED = [sys.executable, "-m", "tactiled.cli"]


def run(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    proc = subprocess.run([*TACTILED, *args], capture_output=True, text=True, timeout=300)
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


def test_random_frames_round_trip(tmp_path: Path):
    out = tmp_path / "xela.npz"
    run("simulate", str(out), "--sensor", "xela_uskin_4x4", "--frames", "4", "--seed", "2")
    data = np.load(out)
    assert data["taxels"].shape == (4, 4, 4, 3) and str(data["sensor"]) == "xela_uskin_4x4"
    lines = [json.loads(line) for line in run("fit", str(out)).stdout.splitlines()]
    assert [obj["frame"] for obj in lines] == [0, 1, 2, 3]
    for i, obj in enumerate(lines):
        assert obj["contact"] is True and obj["model"] == "sphere"
        sh = obj["shear"]
        assert {"fx_n", "fy_n", "torque_nmm", "q_over_p", "mu", "slip_margin", "std"} <= sh.keys()
        assert obj["slip"]["state"] in ("stick", "partial", "slip")
        assert abs(sh["fx_n"] - data["true_fx"][i]) < 5 * sh["std"]["fx_n"]
        assert abs(sh["fy_n"] - data["true_fy"][i]) < 5 * sh["std"]["fy_n"]
        if sh["mu"] is None:
            assert obj["reasons"]["mu"]


def test_pull_until_slip_declares_the_onset(tmp_path: Path):
    out = tmp_path / "pull.npz"
    run("simulate", str(out), "--sensor", "xela_uskin_4x4", "--load", "pull", "--seed", "7")
    onset = int(np.load(out)["true_onset"][0])
    lines = [json.loads(line) for line in run("fit", str(out)).stdout.splitlines()]
    events = [(o["frame"], o["slip"]["event"]) for o in lines if o.get("contact") and o["slip"]["event"]]
    assert events and events[0][1] == "onset"
    assert onset <= events[0][0] <= onset + 5
    assert all(o["slip"]["state"] == "slip" for o in lines[events[0][0]:])


def test_three_axis_file_with_a_one_axis_sensor_is_refused(tmp_path: Path):
    out = tmp_path / "xela.npz"
    run("simulate", str(out), "--sensor", "xela_uskin_4x4", "--frames", "1")
    proc = run("fit", str(out), "--sensor", "flat16", check=False)
    assert proc.returncode == 2 and "1-axis" in proc.stderr and proc.stdout == ""
    proc = run("fit", str(out), "--sensor", "xela_uskin_4x6", check=False)
    assert proc.returncode == 2 and "(N, 4, 6, 3)" in proc.stderr

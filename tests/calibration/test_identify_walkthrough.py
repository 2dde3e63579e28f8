"""docs/howto/calibration.md's identification walkthrough, run as a user pastes it: simulated presses
of a finger whose rubber is not the paper's, ``calibrate --identify``, then ``fit
--calibration`` on frames of that finger.  The identified constants must hold the truth within
their bounds, and the fits' force errors must be what their sigmas say (and far from it
without the calibration)."""

from __future__ import annotations

import json
import math
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
#: The simulated finger of the walkthrough (its flags), the truth the report must hold.
TRUTH = {"depth_x": 5.0, "nu_x": 0.4, "depth_y": 6.0, "nu_y": 0.7, "modulus": 0.32}


def walkthrough() -> list[str]:
    text = (ROOT / "docs" / "howto" / "calibration.md").read_text()
    section = text.split("**Try it on a simulated finger first.**", 1)[1]
    return re.search(r"```sh\n(.*?)```", section, re.S).group(1).strip().splitlines()


def _run(line: str, cwd: Path) -> str:
    """One documented command line (``tactiled ...`` [``> FILE``]); its stdout."""
    words = shlex.split(line)
    target = None
    if ">" in words:
        words, target = words[: words.index(">")], words[words.index(">") + 1]
    assert words[0] == "tactiled", line
    proc = subprocess.run([sys.executable, "-m", "tactiled.cli", *words[1:]], cwd=cwd,
                          capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, (line, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr
    if target:
        (cwd / target).write_text(proc.stdout)
    return proc.stdout


def _force_z(fits: str, frames: Path) -> np.ndarray:
    truth = np.load(frames)["true_force"]
    z = []
    for line in fits.splitlines():
        fit = json.loads(line)
        assert fit["contact"] and fit["std"]["force_n"], fit
        z.append((fit["force_n"] - truth[fit["frame"]]) / fit["std"]["force_n"])
    return np.asarray(z)


def test_the_documented_walkthrough_identifies_the_finger(tmp_path: Path) -> None:
    lines = walkthrough()
    assert [shlex.split(l)[1] for l in lines] == ["simulate", "calibrate", "simulate", "fit"]
    assert "--presses" in lines[0] and "--identify" in lines[1] and "--calibration" in lines[3]
    for flag, value in (("--depth-x", TRUTH["depth_x"]), ("--nu-x", TRUTH["nu_x"]),
                        ("--modulus", TRUTH["modulus"])):
        for line in (lines[0], lines[2]):  # the presses and the frames: one finger
            assert f"{flag} {value:g}" in line, (flag, line)

    for line in lines:
        _run(line, tmp_path)

    model = json.loads((tmp_path / "cal.json").read_text())["model"]
    got = {**model["impulse"], "modulus": model["modulus"]}
    for name, true in TRUTH.items():
        sigma = model["sigma"][name]
        assert sigma is not None and 0 < sigma < 0.02 * true, (name, sigma)
        assert abs(got[name] - true) < 4 * sigma, (name, got[name], sigma)

    z = _force_z((tmp_path / "fits.jsonl").read_text(), tmp_path / "frames.npz")
    assert len(z) == 100
    rms = math.sqrt(float(np.mean(z**2)))
    assert 0.5 < rms < 1.6, rms  # the sigmas say what the errors are

    # Without the calibration the same frames are biased by many of their sigmas.
    plain = _run("tactiled fit frames.npz", tmp_path)
    assert math.sqrt(float(np.mean(_force_z(plain, tmp_path / "frames.npz") ** 2))) > 4.0

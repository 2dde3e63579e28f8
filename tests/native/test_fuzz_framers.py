"""The atheris fuzz target of the core's framers (tests/native/fuzz_framers.py) runs clean: a
short run by default, a long one with ``-m slow``.  A failing input makes libFuzzer exit with
an error and write the input (``crash-*``) into the test's directory."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

TARGET = Path(__file__).with_name("fuzz_framers.py")


def _fuzz(runs: int, tmp_path: Path) -> str:
    run = subprocess.run(
        [sys.executable, str(TARGET), f"-runs={runs}", "-max_len=20000", "-len_control=0",
         f"-artifact_prefix={tmp_path}/", "-seed=1"],
        capture_output=True, text=True, timeout=1200, cwd=tmp_path)
    out = run.stdout + run.stderr
    assert run.returncode == 0, out[-4000:]
    assert f"Done {runs} runs" in out, out[-2000:]
    return out


def test_the_framers_fuzz_target_runs_clean(tmp_path: Path) -> None:
    _fuzz(2000, tmp_path)


@pytest.mark.slow
def test_the_framers_fuzz_target_runs_clean_for_long(tmp_path: Path) -> None:
    _fuzz(200_000, tmp_path)


def test_the_fuzz_target_would_fail_on_a_disagreement(tmp_path: Path) -> None:
    """(The target can fail: a reference made to count one byte too many is caught.)"""
    patched = tmp_path / "fuzz_broken.py"
    patched.write_text(TARGET.read_text().replace(
        "    ref, got = FrameDecoder(), NativeFrameDecoder()\n",
        "    ref, got = FrameDecoder(), NativeFrameDecoder()\n    ref.stats.bytes += 1\n"))
    run = subprocess.run([sys.executable, str(patched), "-runs=50", "-max_len=2000",
                          f"-artifact_prefix={tmp_path}/"],
                         capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert run.returncode != 0 and "AssertionError" in run.stdout + run.stderr

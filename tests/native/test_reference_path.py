"""The Python reference runs the daemon's key paths as the core does: a short set of tests,
run in a child process with ``TACTILED_CORE=python`` (the core cannot be unloaded from this
one), in every default run.

The whole suite runs against the reference with ``TACTILED_CORE=python .venv/bin/python -m
pytest`` (docs/contributing.md); this keeps the golden replays (the published estimates of
recorded sessions, frame path and fits alike) and the tracker's kernels honest under it on
every run.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tactiled import native

ROOT = Path(__file__).resolve().parents[2]
#: what the child runs: the golden replays, the tracker's kernels against numpy, and the
#: check that the child really runs the reference
REFERENCE_SET = [
    "tests/reliability/test_golden_replay.py::test_replay_matches_the_golden_estimates",
    "tests/pipeline/test_kernels.py",
    "tests/native/test_core_build.py::test_the_install_built_the_core",
]


@pytest.mark.skipif(native.core is None, reason="this process already runs the reference")
def test_the_key_tests_pass_against_the_python_reference() -> None:
    env = {**os.environ, "TACTILED_CORE": "python"}
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          *REFERENCE_SET], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=900)
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    assert " passed" in run.stdout and "failed" not in run.stdout and "skipped" not in run.stdout

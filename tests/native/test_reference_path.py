"""The Python reference runs the daemon's key paths as the core does: a short set of tests,
run in a child process with ``TACTILED_CORE=python`` (the core cannot be unloaded from this
one), in every default run; the whole suite so with ``-m slow``.

The short set keeps the published estimates of recorded sessions (the golden replays: frame
path and fits alike), a damaged stream through the daemon over a real pty, a read's frames in
one call, the tracker's kernels, the Hertz ellipse against MODEL.md, a fit's choice of model and
a vendor source's framer honest under the reference on every run: the directories where the
reference's own code runs (pipeline, reliability, physics, fit, drivers).
tests/native/test_published_reference.py holds the core's published estimates equal to the
reference's on hypothesis-drawn streams.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from tactiled import native

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT / "tests" / "reliability") not in sys.path:
    sys.path.insert(0, str(ROOT / "tests" / "reliability"))
import regen_golden as g  # noqa: E402
#: what the child runs: the golden replays, a stream damaged every way at once through the
#: daemon over a pty (as read, and lossless), a read's frames in one call, the tracker's
#: kernels against numpy, and the check that the child really runs the reference (about 40 s
#: with the machine loaded 17 deep: the goldens' replays are most of it)
REFERENCE_SET = [
    "tests/reliability/test_golden_replay.py::test_replay_matches_the_golden_estimates",
    "tests/reliability/test_serial_faults.py::test_damaged_stream[mixed]",
    "tests/reliability/test_serial_faults.py::test_damaged_stream[mixed-lossless]",
    "tests/pipeline/test_sensor_batch.py",
    "tests/pipeline/test_kernels.py",
    "tests/native/test_core_build.py::test_the_install_built_the_core",
    # where the reference's own bodies run and are held to MODEL.md or the truth: the Hertz
    # ellipse's reference example and limits, a fit choosing the model of drawn contacts, and
    # a vendor source built on the reference's framer (3.6 s of CPU more together, measured)
    "tests/physics/test_hertz.py",
    "tests/fit/test_recovery.py::test_auto_picks_the_right_model",
    "tests/drivers/test_lines_core.py::test_a_lines_source_frames_through_the_core_unless_told_otherwise",
]
#: why a test may skip under the reference, the whole suite run (-rs lists the reasons):
#: the slow ones (not asked for), those that compare the core with the reference, and this
#: file's own tests
REFERENCE_SKIPS = (
    "slow: opt in with -m slow",
    "TACTILED_CORE=python: no core to compare",
    "this process already runs the reference",
)


def _under_reference(args: list[str], timeout: float) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "TACTILED_CORE": "python"}
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider",
                           *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.skipif(native.core is None, reason="this process already runs the reference")
def test_the_key_tests_pass_against_the_python_reference() -> None:
    run = _under_reference(REFERENCE_SET, timeout=900)
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    assert " passed" in run.stdout and "failed" not in run.stdout and "skipped" not in run.stdout


def _replay(core: str, session: str) -> tuple[str, str]:
    """``tactiled replay`` of a golden session in a child process run with
    ``TACTILED_CORE=core``, numerics pinned as the goldens' are: (stdout, stderr)."""
    env = {**os.environ, **g.PINNED_ENV, "TACTILED_CORE": core}
    done = subprocess.run(g.replay_command(g.recording(session)), cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout, done.stderr


def test_a_replay_on_the_reference_publishes_the_cores_estimates() -> None:
    """The selection end to end: the daemon of ``tactiled replay`` (replay source, decoder,
    calibration, gate, tracker, a real fit worker, the hub) in two child processes, one per
    ``TACTILED_CORE``; each says which frame path it ran, and they publish the same estimates:
    every string, integer, boolean and null equal, floats within the reference's stated
    relative 1e-8 (``regen_golden.REL_TOL``: its sums run in NumPy's order, not the core's)."""
    with ThreadPoolExecutor(2) as ex:
        (core_out, core_err), (ref_out, ref_err) = ex.map(
            lambda core: _replay(core, "press"), ["native", "python"])
    assert core_err.rstrip().endswith("core native"), core_err[-500:]
    assert ref_err.rstrip().endswith("core python"), ref_err[-500:]
    cores = [json.loads(line) for line in core_out.splitlines()]
    refs = [json.loads(line) for line in ref_out.splitlines()]
    assert len(cores) == 90 and sum(e["contact"] for e in cores) > 30  # the press's frames
    assert [e["seq"] for e in refs] == [e["seq"] for e in cores]
    diffs = [d for c, r in zip(cores, refs) for d in g.compare(c, r, f"seq {c['seq']}", 1e-8)]
    assert not diffs, diffs[:8]


@pytest.mark.slow
@pytest.mark.timeout(7200)
@pytest.mark.skipif(native.core is None, reason="this process already runs the reference")
def test_the_whole_suite_passes_against_the_python_reference() -> None:
    """Every test of the default run, on the reference (docs/contributing.md gives its last
    result); a skip only for a reason of :data:`REFERENCE_SKIPS`."""
    t0 = time.monotonic()
    # the reference's fits cost 15-30 times the core's CPU: a test's own time bound (the
    # pytest-timeout of pyproject.toml, 300 s) is set for the core
    run = _under_reference(["--timeout", "1800", "tests"], timeout=7000)
    tail = run.stdout.strip().splitlines()[-1] if run.stdout.strip() else ""
    print(f"FIGURES whole suite under TACTILED_CORE=python: {tail} "
          f"({time.monotonic() - t0:.0f} s)")
    assert run.returncode == 0, run.stdout[-6000:] + run.stderr[-2000:]
    reasons = set(re.findall(r"^SKIPPED \[\d+\] [^:]+:\d+: (.*)$", run.stdout, re.M))
    assert reasons <= set(REFERENCE_SKIPS), reasons - set(REFERENCE_SKIPS)

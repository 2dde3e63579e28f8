"""Golden estimate files for the recorded-session regression test (test_golden_replay.py).

Three short sessions were recorded with ``tactiled record`` from the scene simulator (press,
sphere, edge; 3 s each at 30 frames/s) and are checked in under ``tests/data/golden/`` with
what ``tactiled replay --mode lossless --no-timing`` printed for them.  The test replays each
recording through the whole daemon again and fails on any difference, as gpsd's regression
tests compare ``gpsfake`` output with checked-in ``.chk`` files.

Regenerate the golden estimates (after a deliberate change of the estimates; review the diff)::

    .venv/bin/python -m tests.reliability.regen_golden

and, to re-record the sessions from the simulator as well (new recordings; rarely needed)::

    .venv/bin/python -m tests.reliability.regen_golden --record
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from tactiled import native

GOLDEN = Path(__file__).resolve().parent.parent / "data" / "golden"

#: session name -> the simulator URL it was recorded from.
SESSIONS = {
    name: f"sim://?scene={name}&seed=1&rate=30&speed=0&loop=0"
    for name in ("press", "sphere", "edge")
}

#: floats: relative tolerance of the comparison (see compare()).  On the Python reference
#: (``TACTILED_CORE=python``) 1e-8: its sums run in another order (NumPy, BLAS), and the tracker
#: carries those last-digit differences from frame to frame (a held ellipse's axis 1.6e-9 of
#: itself apart from the core's after 80 frames).
REL_TOL = 1e-8 if native.core is None else 1e-9
ABS_TOL = 1e-12


def recording(name: str) -> Path:
    return GOLDEN / f"{name}.tact"


def golden(name: str) -> Path:
    return GOLDEN / f"{name}.jsonl"


def replay_command(path: Path) -> list[str]:
    """The command whose output is the golden file (run as ``python -m tactiled.cli``)."""
    return [sys.executable, "-m", "tactiled.cli", "replay", str(path), "--mode", "lossless",
            "--speed", "0", "--no-timing"]


#: The replay's numerics pinned to baseline x86-64, so that the golden files do not depend on
#: the CPU that runs the test.  Unpinned, the fits follow the host: OpenBLAS's kernels, numpy's
#: SIMD loops and glibc's libm (FMA variants of exp, log, sin, ...) all follow the CPU's features, and a fit
#: near the edge of what the data supports (force too low for curvature) then takes another
#: path from a last-bit difference: other iteration counts, even another convergence verdict.
#: The goldens made on an AVX2 machine differed from an AVX-512 machine in ~40 % of the lines.
PINNED_ENV = {
    "OPENBLAS_CORETYPE": "Prescott",
    "NPY_DISABLE_CPU_FEATURES": "X86_V3 X86_V4 AVX512_ICL AVX512_SPR",
    "GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX2,-FMA,-FMA4,-AVX512F,-AVX",
}


def replay(path: Path, pinned: bool = True) -> str:
    """What the replay command prints for ``path``, with the numerics pinned to baseline
    x86-64 (``PINNED_ENV``), or, ``pinned=False``, as the host CPU runs them."""
    env = {**os.environ, **PINNED_ENV} if pinned else {
        k: v for k, v in os.environ.items() if k not in PINNED_ENV}
    done = subprocess.run(replay_command(path), capture_output=True, text=True, timeout=600,
                          check=False, env=env)
    if done.returncode != 0:
        raise RuntimeError(f"replay of {path} failed ({done.returncode}): {done.stderr}")
    return done.stdout


def compare(expected: Any, actual: Any, where: str = "", rel_tol: float = REL_TOL,
            abs_tol: float | None = None) -> list[str]:
    """Differences between two parsed JSON values: exact for everything but floats, which
    must agree within ``rel_tol`` (relative; ``REL_TOL`` by default) or ``ABS_TOL``.  An
    estimate's value that has a 1-sigma in its ``std`` may also differ by ``rel_tol`` of that
    sigma: a rate is a difference of nearly equal numbers, and its relative last digits are
    not the measure of a change (a force rate of 67.83 N/s with a sigma of 2017 N/s moved
    2e-6 of itself, 7e-8 of its sigma, between two CPUs)."""
    if isinstance(expected, dict) and isinstance(actual, dict):
        std = expected.get("std") if isinstance(expected.get("std"), dict) else {}
        out = []
        for key in sorted(expected.keys() | actual.keys()):
            if key not in actual:
                out.append(f"{where}.{key}: missing")
            elif key not in expected:
                out.append(f"{where}.{key}: unexpected ({actual[key]!r})")
            else:
                sd = std.get(key)
                tol = rel_tol * sd if isinstance(sd, float) and math.isfinite(sd) else None
                if key == "condition" and isinstance(expected[key], float):
                    # a condition number kappa moves kappa times its matrix's last digits:
                    # relatively, kappa * rel_tol (1669.58291760 against ...91495 between the
                    # core and the Python reference, 1.6e-9 of itself)
                    tol = rel_tol * expected[key] * expected[key]
                out += compare(expected[key], actual[key], f"{where}.{key}", rel_tol, tol)
        return out
    if isinstance(expected, list) and isinstance(actual, list):
        if len(expected) != len(actual):
            return [f"{where}: {len(actual)} items, expected {len(expected)}"]
        return [d for i, (e, a) in enumerate(zip(expected, actual))
                for d in compare(e, a, f"{where}[{i}]", rel_tol, abs_tol)]
    if (isinstance(expected, float) and isinstance(actual, (int, float))
            and not isinstance(actual, bool)):
        if math.isclose(expected, actual, rel_tol=rel_tol, abs_tol=max(ABS_TOL, abs_tol or 0.0)):
            return []
        return [f"{where}: {actual!r}, expected {expected!r}"]
    if type(expected) is not type(actual) or expected != actual:
        return [f"{where}: {actual!r}, expected {expected!r}"]
    return []


def record(name: str) -> None:
    path = recording(name)
    path.unlink(missing_ok=True)
    subprocess.run([sys.executable, "-m", "tactiled.cli", "record", SESSIONS[name], "-o",
                    str(path)], check=True, timeout=300)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--record", action="store_true",
                        help="re-record the sessions from the simulator first")
    args = parser.parse_args(argv)
    GOLDEN.mkdir(parents=True, exist_ok=True)
    for name in SESSIONS:
        if args.record or not recording(name).exists():
            record(name)
        text = replay(recording(name))
        golden(name).write_text(text)
        print(f"{golden(name)}: {len(text.splitlines())} estimates from {recording(name)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

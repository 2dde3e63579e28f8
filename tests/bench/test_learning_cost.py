"""The learning-cost probe (python -m tactiled_bench.learning_cost), short: it runs, measures
both fitters on both fingers, and finds the flat field off on the paper's finger and on on the
mismatched one.  Its figures are in docs/performance/benchmarks.md, not asserted here (rule 4)."""

import subprocess
import sys


def test_the_probe_runs_and_reports_both_fingers() -> None:
    out = subprocess.run([sys.executable, "-m", "tactiled_bench.learning_cost", "--fits", "40",
                          "--rounds", "2", "--warmup", "400"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    rows = [line.split("|")[1:-1] for line in out.stdout.splitlines()[2:]]
    assert [(r[0].strip(), r[1].strip()) for r in rows] == [("the paper's", "off"), ("5 % gains, 0.1 mm", "on")]
    for r in rows:
        assert float(r[2]) > 0.0 and float(r[3]) > 0.0
        assert len(r[5].split("/")[0].split()) == 2

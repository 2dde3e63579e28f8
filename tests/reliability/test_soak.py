"""Acquisition soak: three fingers at 1 kHz over ptys (``tactiled simulate --pty`` processes)
into the real daemon, run by ``python -m tactiled.bench.reliability`` in a process of its own
so that its resident memory is the daemon's (see that module).

Bars: the daemon's RSS grows by less than 5 MB after the warm-up, no frame is lost or rejected
in acquisition, every frame is accounted for, no fit worker is restarted.  The short version
(20 s) always runs; the 10-minute one with ``-m slow``; one hour with
``TACTILED_SOAK_SECONDS=3600 pytest -m slow tests/reliability/test_soak.py``.  Subscribers
(REST/WebSocket) are not part of this soak: the service has its own.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from rel_helpers import figures

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux ptys and /proc")

LONG = float(os.environ.get("TACTILED_SOAK_SECONDS", "600"))


def _soak(seconds: float) -> dict:
    done = subprocess.run([sys.executable, "-m", "tactiled.bench.reliability", "--seconds",
                           repr(seconds), "--json"], capture_output=True, text=True,
                          timeout=seconds + 240, check=False)
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    assert lines, f"no result (exit {done.returncode}): {done.stderr[-2000:]}"
    return json.loads(lines[-1])


#: Other jobs on the machine using more CPU than this (cores, averaged over the run) make the
#: acquisition figures a measure of the machine, not of the daemon: on the shared 2-core
#: development machine a concurrent test suite starves the simulators themselves (they skip
#: frames) and the daemon.  The frame-loss bar is then not judged; memory always is.
QUIET_CORES = 0.25


def _check(r: dict) -> None:
    figures(f"soak[{r['seconds']:g} s]", rss_mb=r["rss_mb"], sensors=r["sensors"],
            worker_restarts=r["worker_restarts_by_reason"],
            workers_rss_growth_mb=r["workers_rss_growth_mb"],
            simulators=r["simulators"], cpu_cores=r["cpu_cores"], passed=r["passed"])
    assert r["rss_mb"]["growth"] < 5.0, r["rss_mb"]
    for name, s in r["sensors"].items():
        assert s["connected"] and s["disconnects"] == 0, (name, s)
        assert s["unaccounted"] == 0, (name, s)  # every frame decoded is accounted for
        assert s["rejected"] == 0 and s["duplicated"] == 0, (name, s)
    busy = r["cpu_cores"]["other_jobs"]
    if busy > QUIET_CORES:
        pytest.skip(f"other jobs used {busy} CPU cores during the soak: frame loss not judged "
                    f"(lost: {[s['lost'] for s in r['sensors'].values()]}; RSS growth "
                    f"{r['rss_mb']['growth']} MB, checked)")
    for name, s in r["sensors"].items():
        assert s["frame_rate_hz"] > 0.98 * 1000, (name, s)
        assert s["lost"] == 0, (name, s)


def test_soak_short() -> None:
    _check(_soak(20.0))


@pytest.mark.slow
@pytest.mark.timeout(LONG + 600)
def test_soak_long() -> None:
    _check(_soak(LONG))

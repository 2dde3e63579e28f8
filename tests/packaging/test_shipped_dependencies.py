"""What ships runs with what the package installs: every module of the four packages imports,
and every command and bench answers ``--help``, without the test-only packages (httpx, pytest,
playwright, hypothesis, mpmath, matplotlib, schemathesis) or an optional extra's; what needs
an extra says so in one line naming it.

Fast: this environment, with ``tests/packaging/blocked`` on PYTHONPATH (a ``sitecustomize``
whose import hook refuses those packages, in every process started, children included).
Slow (``-m slow``): a fresh venv holding only ``pip install .`` (no extras), where the reliability
soak also runs its quickest mode end to end."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from tactiled.cli import COMMANDS
from tactiled.frames import Frame
from tactiled.io.recording import Recorder

ROOT = Path(__file__).resolve().parents[2]
BLOCKER = Path(__file__).resolve().parent / "blocked"
#: The optional extras' import names (pyproject's optional-dependencies).
EXTRAS = {"zenoh": ("zenoh",), "ros2": ("rosbags", "mcap", "mcap_ros2", "xxhash", "cyclonedds"),
          "plot": ("matplotlib",), "docs": ("mkdocs", "material", "mkdocstrings")}
#: Test-only packages (pyproject's test extra; zenoh-ros2-sdk installs two top-level names)
#: and the extras'.
NOT_SHIPPED = ("httpx", "pytest", "_pytest", "playwright", "hypothesis", "mpmath", "PIL",
               "schemathesis", "zenoh_ros2_sdk", "messages",
               *(name for names in EXTRAS.values() for name in names))
#: Modules of an optional extra (imported only where it is enabled; their users say which).
EXTRA_MODULES = ("tactiled_service.bus", "tactiled_service.ros2.")

WALK = textwrap.dedent("""
    import importlib, json, pkgutil, sys
    bad = {}
    for top in ("tactiled", "tactiled_drivers", "tactiled_service", "tactiled_bench"):
        pkg = importlib.import_module(top)
        for info in pkgutil.walk_packages(pkg.__path__, top + "."):
            try:
                importlib.import_module(info.name)
            except BaseException as err:
                bad[info.name] = f"{type(err).__name__}: {err}"
    json.dump(bad, sys.stdout)
""")

PROBE = textwrap.dedent(f"""
    import importlib, json, sys
    found = []
    for name in {NOT_SHIPPED!r}:
        try:
            importlib.import_module(name)
            found.append(name)
        except ImportError:
            pass
    json.dump(found, sys.stdout)
""")

#: argv after the interpreter -> what its output must hold.
HELP = {
    ("-m", "tactiled.cli", "--help"): "simulate",
    **{("-m", "tactiled.cli", name, "--help"): "usage: tactiled " + name
       for name in COMMANDS},
    ("-m", "tactiled_bench.reliability", "--help"): "--quick",
    ("-m", "tactiled_bench.learning_cost", "--help"): "--fits",
    ("-m", "tactiled_bench.worker_memory", "--help"): "--fits",
    ("-m", "tactiled_bench.clock", "--help"): "--seconds",
    ("-m", "tactiled_bench.websocket_fanout", "--help"): "--clients",
    ("-m", "tactiled_bench.zenoh_fanout", "--help"): "--subscribers",
    ("-m", "tactiled_bench.ros2_fanout", "--help"): "--sensors",
    ("-m", "tactiled_bench.calibration_cost"): "linearise",  # no options: its whole run (~1 s)
}

#: What needs an extra, run without it: one line naming the extra, exit 2.
NEEDS_EXTRA = {
    ("-m", "tactiled.cli", "run", "--zenoh", "--port", "0"): "tactiled[zenoh]",
    ("-m", "tactiled.cli", "watch", "--zenoh"): "tactiled[zenoh]",
    ("-m", "tactiled_bench.zenoh_fanout", "--quick"): "tactiled[zenoh]",
    ("-m", "tactiled.cli", "bench", "--quick", "--plot", "pareto.png"): "tactiled[plot]",
    ("-m", "tactiled.cli", "run", "--ros2", "--port", "0"): "tactiled[zenoh",
    ("-m", "tactiled.cli", "watch", "--ros2"): "tactiled[ros2]",  # DDS: no [zenoh] here
    ("-m", "tactiled.cli", "watch", "--ros2", "--connect", "tcp/127.0.0.1:7447"):
        "tactiled[zenoh,ros2]",
    ("-m", "tactiled_bench.ros2_fanout", "--quick"): "tactiled[zenoh,ros2]",
    ("-m", "tactiled.cli", "export", "r.tact", "-o", "r.mcap"): "tactiled[ros2]",
}


def _blocked_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(BLOCKER), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["TACTILED_BLOCKED"] = ",".join(NOT_SHIPPED)
    return env


def _run_all(python: str, commands: list[tuple[str, ...]], env: dict[str, str], cwd: Path,
             parallel: int = 4) -> dict[tuple[str, ...], subprocess.CompletedProcess]:
    out = {}
    for start in range(0, len(commands), parallel):
        procs = {c: subprocess.Popen([python, *c], env=env, cwd=cwd, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
                 for c in commands[start:start + parallel]}
        for c, p in procs.items():
            stdout, stderr = p.communicate(timeout=120)
            out[c] = subprocess.CompletedProcess(c, p.returncode, stdout, stderr)
    return out


def check_environment(python: str, env: dict[str, str], cwd: Path) -> None:
    """Every shipped module imports and every command and bench answers in ``python``'s
    environment, where the not-shipped packages cannot be imported."""
    probe = subprocess.run([python, "-c", PROBE], env=env, cwd=cwd, capture_output=True,
                           text=True, timeout=60)
    assert probe.returncode == 0 and probe.stdout == "[]", ("importable here", probe.stdout,
                                                            probe.stderr)

    walk = subprocess.run([python, "-c", WALK], env=env, cwd=cwd, capture_output=True,
                          text=True, timeout=120)
    assert walk.returncode == 0, walk.stderr
    failed = json.loads(walk.stdout)
    assert "tactiled_service.bus" in failed, failed
    extras = {name for names in EXTRAS.values() for name in names}
    for module, error in failed.items():
        assert module.startswith(EXTRA_MODULES), (module, error)
        assert any(f"No module named '{name}" in error for name in extras), (module, error)

    with Recorder(cwd / "r.tact", sensor_id=0) as rec:  # for export
        rec.record(Frame(seq=0, device_time_us=0, raw=np.zeros((8, 8), np.uint16)), 1.0)
    results = _run_all(python, [*HELP, *NEEDS_EXTRA], env, cwd)
    for args, words in HELP.items():
        r = results[args]
        assert r.returncode == 0 and words in r.stdout, (args, r.stdout[-500:], r.stderr[-2000:])
        assert "Traceback" not in r.stderr, (args, r.stderr)
    for args, extra in NEEDS_EXTRA.items():
        r = results[args]
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and extra in lines[0], (args, r.stderr)
    assert not (cwd / "pareto.png").exists() and not (cwd / "r.mcap").exists()


def test_shipped_modules_run_without_the_test_packages(tmp_path: Path) -> None:
    check_environment(sys.executable, _blocked_env(), tmp_path)


def test_the_blocker_blocks(tmp_path: Path) -> None:
    """The fast test means something only if the hook really hides what is installed here."""
    r = subprocess.run([sys.executable, "-c", "import httpx"], env=_blocked_env(), cwd=tmp_path,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and "No module named 'httpx'" in r.stderr, r.stderr
    r = subprocess.run([sys.executable, "-c", "import httpx"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, "httpx (test extra) is not installed in the test environment"


@pytest.mark.slow
def test_a_venv_with_only_the_package(tmp_path: Path) -> None:
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    python = str(venv / "bin" / "python")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    install = subprocess.run([python, "-m", "pip", "install", "-q", str(ROOT)], env=env,
                             capture_output=True, text=True, timeout=900)
    assert install.returncode == 0, install.stderr[-3000:]
    check_environment(python, env, tmp_path)
    # The soak docs/performance/reliability.md quotes, in its quickest form: subscribers, stalled clients
    # and the daemon, every process of it in this environment.
    soak = subprocess.run([python, "-m", "tactiled_bench.reliability", "--quick", "--seconds",
                           "3", "--warmup", "1", "--subscribers", "5", "--stalled", "1"],
                          env=env, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert "Traceback" not in soak.stderr, soak.stderr[-3000:]
    assert "Subscribers: delivery min" in soak.stdout, (soak.stdout[-2000:], soak.stderr[-2000:])
    assert "'healthy_delivery_99pct': True" in soak.stdout, soak.stdout[-2000:]

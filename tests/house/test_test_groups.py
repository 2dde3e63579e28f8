"""The xdist grouping of tests/conftest.py (``pytest -n 2``): a module listed as compute-only
exists, and uses nothing that runs in real time (such a test belongs to the group ``live``)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]


def _frozenset_of(name: str) -> frozenset[str]:
    """The literal frozenset ``name`` of tests/conftest.py (read, not imported: under a whole
    run ``import conftest`` may name another directory's conftest.py)."""
    tree = ast.parse((TESTS / "conftest.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == name
                                                for t in node.targets):
            return frozenset(ast.literal_eval(node.value.args[0]))
    raise AssertionError(f"tests/conftest.py defines no {name}")


COMPUTE_ONLY_MODULES = _frozenset_of("COMPUTE_ONLY_MODULES")
COMPUTE_ONLY = _frozenset_of("COMPUTE_ONLY")
#: What a test that runs in real time uses: devices, servers, daemons, threads, the loop.  A
#: command run to its end in a process of its own computes (its timeout is no deadline).
LIVE = re.compile(r"pty_device|live_server|shared_server|daemon_process|SimulatedDevice|"
                  r"browser_page|threading|asyncio|Daemon\(|WorkerPool\(|open_source|"
                  r"serial://|time\.sleep")


def test_every_compute_only_module_exists_and_runs_nothing_live() -> None:
    for rel in sorted(COMPUTE_ONLY_MODULES):
        path = TESTS / rel
        assert path.is_file(), f"{rel}: listed in COMPUTE_ONLY_MODULES, not a test module"
        found = LIVE.search(path.read_text(encoding="utf-8"))
        assert found is None, f"{rel} uses {found.group()!r}: it belongs to the group live"
    assert all((TESTS / d).is_dir() for d in COMPUTE_ONLY)

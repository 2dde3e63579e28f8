"""The xdist grouping of tests/conftest.py (``pytest -n 2``): a module listed as compute-only
exists, and uses nothing that runs in real time (such a test belongs to the group ``live``)."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]
# tests/conftest.py itself: ``import conftest`` finds whichever conftest comes first on the path
_spec = importlib.util.spec_from_file_location("tests_root_conftest", TESTS / "conftest.py")
conftest = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(conftest)
#: What a test that runs in real time uses: devices, servers, daemons, threads, the loop.  A
#: command run to its end in a process of its own computes (its timeout is no deadline).
LIVE = re.compile(r"pty_device|live_server|shared_server|daemon_process|SimulatedDevice|"
                  r"browser_page|threading|asyncio|Daemon\(|WorkerPool\(|open_source|"
                  r"serial://|time\.sleep")


def test_every_compute_only_module_exists_and_runs_nothing_live() -> None:
    for rel in sorted(conftest.COMPUTE_ONLY_MODULES):
        path = TESTS / rel
        assert path.is_file(), f"{rel}: listed in COMPUTE_ONLY_MODULES, not a test module"
        found = LIVE.search(path.read_text(encoding="utf-8"))
        assert found is None, f"{rel} uses {found.group()!r}: it belongs to the group live"
    assert all((TESTS / d).is_dir() for d in conftest.COMPUTE_ONLY)


def test_a_worker_puts_its_tests_in_groups(monkeypatch) -> None:
    """In a pytest-xdist worker (``PYTEST_XDIST_WORKER`` set; xdist resets ``numprocesses``
    there) the collected tests get their groups: ``live`` first, then a group per
    compute-only module; without xdist, none."""
    from types import SimpleNamespace

    import pytest

    class Item:
        def __init__(self, rel: str) -> None:
            self.path = TESTS / rel
            self.marks: list[pytest.Mark] = []
            self.keywords: dict[str, object] = {}

        def add_marker(self, mark: pytest.MarkDecorator) -> None:
            self.marks.append(mark.mark)

    rels = ["fit/test_recovery.py", "service/test_rest.py", "pipeline/test_kernels.py",
            "reliability/test_soak.py"]
    config = SimpleNamespace(option=SimpleNamespace(numprocesses=None),
                             getoption=lambda name: "")
    items = [Item(r) for r in rels]
    monkeypatch.delenv("PYTEST_XDIST_WORKER", raising=False)
    conftest.pytest_collection_modifyitems(config, items)
    assert [i.marks for i in items] == [[]] * 4
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw0")
    conftest.pytest_collection_modifyitems(config, items)
    groups = [(i.path.relative_to(TESTS).as_posix(), i.marks[0].args[0]) for i in items]
    assert groups == [("service/test_rest.py", "live"), ("reliability/test_soak.py", "live"),
                      ("fit/test_recovery.py", "fit/test_recovery.py"),
                      ("pipeline/test_kernels.py", "pipeline/test_kernels.py")]


def test_the_scheduler_makes_a_unit_of_each_group(pytestconfig) -> None:
    """Under ``--dist loadgroup`` the work units are the groups, read from the test ids; under
    another ``--dist``, xdist's own scheduler."""
    from types import SimpleNamespace

    assert conftest.group_of_id("tests/service/test_rest.py::test_x[a]") == "live"
    assert conftest.group_of_id("tests/test_readme_commands.py::test_x") == "live"
    assert conftest.group_of_id("tests/fit/test_recovery.py::T::test_y") == "fit/test_recovery.py"
    assert (conftest.group_of_id("tests/pipeline/test_kernels.py::test_z[1-2]")
            == "pipeline/test_kernels.py")
    other = SimpleNamespace(getoption=lambda name, default=None: "load")
    assert conftest.pytest_xdist_make_scheduler(other, None) is None

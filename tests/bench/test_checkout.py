"""A baseline revision's code is what a benchmark's ``--baseline`` runs: its own packages, not
this tree's (which an editable install would otherwise answer from, whatever PYTHONPATH says)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tactiled_bench.checkout import ROOT, build, checkout_env

PACKAGES = {"tactiled": "", "tactiled_drivers": "drivers", "tactiled_service": "service",
            "tactiled_bench": "benchmarks"}


def _fake_tree(root: Path) -> Path:
    """A checkout of four empty packages (no CMakeLists.txt: a pure Python revision)."""
    for name, folder in PACKAGES.items():
        pkg = root / folder / name
        pkg.mkdir(parents=True)
        (pkg / "__init__.py").write_text("")
    return root


def _imported(env: dict[str, str], cwd: Path) -> dict[str, str]:
    code = ("import importlib\n"
            f"for name in {sorted(PACKAGES)!r}:\n"
            "    print(name, importlib.import_module(name).__file__)\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=cwd, capture_output=True,
                         text=True, check=True).stdout
    return dict(line.split(" ", 1) for line in out.splitlines())


def test_a_checkout_is_imported_from_the_checkout(tmp_path: Path) -> None:
    tree = _fake_tree(tmp_path / "tree")
    assert build(str(tree)) == str(tree)  # nothing to compile
    got = _imported(checkout_env(str(tree)), tmp_path)
    for name, folder in PACKAGES.items():
        assert Path(got[name]) == tree / folder / name / "__init__.py", (name, got[name])


def test_this_tree_is_run_in_this_environment(tmp_path: Path) -> None:
    assert build(str(ROOT)) == str(ROOT)  # its own install: nothing built
    env = checkout_env(str(ROOT))
    got = _imported(env, tmp_path)
    import tactiled

    assert Path(got["tactiled"]) == Path(tactiled.__file__)


def _where_tactiled() -> str:
    import tactiled

    return tactiled.__file__


def test_a_built_revision_runs_from_its_built_folder(tmp_path: Path, monkeypatch) -> None:
    """A revision with a compiled core runs from the folder pip built it into, not from its
    source tree, whose packages lack the core: ``python -c`` puts its working folder first on
    sys.path.  (pip's build of the core takes minutes: a folder laid out as its answer, the
    four packages, stands in for it.)"""
    from tactiled_bench import checkout

    tree = _fake_tree(tmp_path / "tree")
    built = tmp_path / "built"
    for name in PACKAGES:
        (built / name).mkdir(parents=True)
        (built / name / "__init__.py").write_text("")
    monkeypatch.setattr(checkout, "build", lambda t: str(built) if Path(t) == tree else t)
    got = checkout.run_at(str(tree), _where_tactiled, "_where_tactiled()")
    assert Path(got) == built / "tactiled" / "__init__.py", got

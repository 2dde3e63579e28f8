"""A git revision's code, for a benchmark's ``--baseline``: extracted, built where it has a
compiled core, and the environment in which a Python process imports it and nothing else."""

# Why the environment takes more than PYTHONPATH: an editable install by scikit-build-core (this
# project's, `pip install -e .`) answers imports of its packages from a finder on sys.meta_path,
# ahead of every sys.path entry, so a process given a checkout on PYTHONPATH alone imports this
# tree's tactiled, tactiled_drivers, tactiled_service and tactiled_bench all the same (only a
# module this tree lacks comes from the checkout).  The finder stands aside for the build folders
# listed in SKBUILD_EDITABLE_SKIP (scikit-build-core's own switch, which its rebuilds use), so
# checkout_env lists every such finder's there.  A revision with a compiled core (a top-level
# CMakeLists.txt) is built into a folder of its own by pip (the C++ compiler, minutes) and
# imported from there; one without runs its Python code from the extracted tree.

from __future__ import annotations

import os
import subprocess
import sys
import tarfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
#: The checkout's folders that hold its import packages (the tree itself holds tactiled).
PACKAGE_DIRS = ("", "benchmarks", "drivers", "service")
#: The folder under a checkout that its built packages go to (revisions with a compiled core).
BUILT = "_built"
#: scikit-build-core's variable: build folders whose editable finder must not answer imports.
SKIP_VARIABLE = "SKBUILD_EDITABLE_SKIP"


def checkout(rev: str, into: str) -> str:
    """``git archive REV`` of this repository extracted under ``into``; returns its path."""
    out = Path(into) / f"tactiled-{rev}"
    out.mkdir()
    blob = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True,
                          capture_output=True).stdout
    tar_path = Path(into) / "rev.tar"
    tar_path.write_bytes(blob)
    with tarfile.open(tar_path) as tar:
        tar.extractall(out, filter="data")
    tar_path.unlink()
    return str(out)


def editable_finders() -> list[str]:
    """The build folders of the editable installs (scikit-build-core's finders on
    ``sys.meta_path``) in this interpreter."""
    return [str(f.path) for f in sys.meta_path
            if type(f).__module__.startswith("_editable_skbc_") and getattr(f, "path", None)]


def build(tree: str) -> str:
    """Where checkout ``tree``'s packages are imported from: the tree itself (pure Python), or,
    for a revision with a compiled core, the folder pip installs its wheel into (built once,
    kept in the checkout; ``subprocess.CalledProcessError`` if the build fails)."""
    if Path(tree).resolve() == ROOT or not (Path(tree) / "CMakeLists.txt").exists():
        return tree  # this tree (its own install), or nothing to compile
    target = Path(tree) / BUILT
    if not target.exists():
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps",
                        "--target", str(target), tree], check=True, cwd=tree)
    return str(target)


def checkout_env(tree: str, built: str | None = None) -> dict[str, str]:
    """This process's environment with the code of checkout ``tree`` (imported from ``built``,
    :func:`build`'s answer, when given) in place of this tree's: its package folders on
    PYTHONPATH and this interpreter's editable finders told to stand aside (the module's
    comment).  Every process started with it, and its children, import that code.  For this
    tree itself: this environment, unchanged."""
    if Path(tree).resolve() == ROOT:
        return dict(os.environ)
    where = built if built is not None and built != tree else None
    path = [where] if where else [os.path.join(tree, d) if d else tree for d in PACKAGE_DIRS]
    skip = [p for p in os.environ.get(SKIP_VARIABLE, "").split(os.pathsep) if p]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(path),
            SKIP_VARIABLE: os.pathsep.join([*skip, *editable_finders()])}


def run_at(tree: str, func: Any, call: str, preamble: tuple[str, ...] = ()) -> Any:
    """``call`` (an expression calling ``func``, a self-contained function of its module)
    evaluated on the code of checkout ``tree``, in a subprocess: this module's own ``func``
    runs there, so a revision from before it existed is measured the same way.  Its result
    must be JSON."""
    import inspect
    import json
    import subprocess
    import sys

    source = "\n".join(["from typing import Any", *preamble, inspect.getsource(func),
                        "if __name__ == '__main__':",
                        "    import json",
                        f"    print(json.dumps({call}))"])
    built = build(tree)
    # run from where the code is imported: `python -c` puts its working folder first on
    # sys.path, and a built revision's source tree there has no compiled core
    out = subprocess.run([sys.executable, "-c", source], cwd=built, capture_output=True,
                         text=True, env=checkout_env(tree, built))
    if out.returncode != 0:
        raise RuntimeError(f"{func.__name__} on {tree} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])

"""The house's bars, read from the sources: the import graph of the four packages and the
modules' length.

The graph is built from each module's syntax tree (``ast``), every ``import`` and ``from ...
import`` counted, those inside functions included (a lazy import still ties two modules) and
those under ``if TYPE_CHECKING:`` left out (they never run), plus ``importlib.import_module``
of a literal name.  Its bars (docs/contributing.md, "Layers"):

* the runtime (``tactiled``, ``tactiled_drivers``, ``tactiled_service``) never imports the
  benchmarks (``tactiled_bench``), but for the two commands that run them, inside ``run``;
* no import runs up :data:`LAYERS`;
* no import cycle between modules;
* no module of the runtime or the benchmarks is over :data:`MAX_LINES` lines, unless its first
  lines say it is a compiled-kernel file and why.

Every bar holds with no exception listed: a change that breaks one mends it (a split, a module
of its own for what two modules share) rather than adding an exception here.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: Import package -> its folder.
PACKAGES = {
    "tactiled": ROOT / "tactiled",
    "tactiled_drivers": ROOT / "drivers" / "tactiled_drivers",
    "tactiled_service": ROOT / "service" / "tactiled_service",
    "tactiled_bench": ROOT / "benchmarks" / "tactiled_bench",
}
RUNTIME = ("tactiled", "tactiled_drivers", "tactiled_service")
#: Compiled modules (no source to read): they count as modules of the layer that holds them.
COMPILED = ("tactiled._core",)

#: The layers, lowest first: a module may import its own layer's modules and those below it.
#: A module's layer is the one naming the longest prefix of its dotted name.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("base", ("tactiled", "tactiled._core", "tactiled.errors", "tactiled.io.files", "tactiled.native",
              "tactiled.progress", "tactiled.heap", "tactiled.heapstats", "tactiled.systemd")),
    # a sensor: its model, description and vendor arrays, and the counts-to-strain table type
    # (calibration.lut, .segments: a vendor array's nominal table is one)
    ("sensor", ("tactiled.sensors", "tactiled.calibration.lut", "tactiled.calibration.segments")),
    ("frames", ("tactiled.frames", "tactiled.clock", "tactiled.io.recording")),
    ("physics", ("tactiled.physics",)),
    ("calibration", ("tactiled.calibration",)),
    ("fit", ("tactiled.fit", "tactiled.sensors.window")),
    # sources holds the driver table (a URL checked by scheme, no driver imported); the file
    # formats above the calibration (a calibration or press file holds its types)
    ("sources", ("tactiled.sources", "tactiled.io", "tactiled.sim")),
    ("settings", ("tactiled.settings",)),
    ("pipeline", ("tactiled.pipeline",)),
    ("drivers", ("tactiled_drivers",)),
    ("service", ("tactiled_service",)),
    ("commands", ("tactiled.commands", "tactiled.cli")),
    ("benchmarks", ("tactiled_bench",)),
)
#: The commands that run the benchmarks: they import ``tactiled_bench`` inside a function, the
#: one way the runtime reaches it (``tactiled bench``, ``tactiled calibrate --bench``).
BENCH_ENTRY = ("tactiled.commands.bench", "tactiled.commands.calibrate")

MAX_LINES = 700
#: Words a long module's first lines use to say it holds compiled kernels (and why it is long).
KERNEL_FILE = "compiled-kernel file"


@dataclass(frozen=True)
class Import:
    importer: str
    imported: str
    line: int
    in_function: bool

    def __str__(self) -> str:
        where = "inside a function" if self.in_function else "at module level"
        return f"{self.importer}:{self.line} imports {self.imported} ({where})"


@cache
def modules() -> dict[str, Path | None]:
    """Every module of the four packages (dotted name -> source file; None if compiled)."""
    found: dict[str, Path | None] = {}
    for top, folder in PACKAGES.items():
        for path in sorted(folder.rglob("*.py")):
            parts = [top, *path.relative_to(folder).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    found.update(dict.fromkeys(COMPILED))
    return found


def _owner(name: str) -> str | None:
    """The module of ours that importing ``name`` runs (a name inside a module: that
    module), or None for another distribution's."""
    known = modules()
    while name and name not in known:
        name = name.rpartition(".")[0]
    return name or None


def _is_type_checking(node: ast.If) -> bool:
    return "TYPE_CHECKING" in ast.unparse(node.test)


def _imports_of(name: str, path: Path) -> list[Import]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: list[Import] = []

    def add(target: str, node: ast.AST, in_function: bool) -> None:
        owner = _owner(target)
        if owner is not None and owner != name:
            out.append(Import(name, owner, node.lineno, in_function))

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for other in child.orelse:
                    visit(other, in_function)
                continue
            inner = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef,
                                                      ast.Lambda))
            if isinstance(child, ast.Import):
                for alias in child.names:
                    add(alias.name, child, in_function)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    anchor = package
                    for _ in range(child.level - 1):
                        anchor = anchor.rpartition(".")[0]
                    base = f"{anchor}.{base}" if base else anchor
                for alias in child.names:
                    # ``from pkg import module`` imports the module; ``from module import name``
                    # the module holding the name
                    add(f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules() else base,
                        child, in_function)
            elif (isinstance(child, ast.Call) and ast.unparse(child.func).endswith("import_module")
                  and child.args):
                arg = child.args[0]
                if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                    add(arg.value, child, in_function)
                elif (isinstance(arg, ast.JoinedStr) and arg.values
                      and isinstance(arg.values[0], ast.Constant)):
                    add(str(arg.values[0].value).rstrip("."), child, in_function)
            visit(child, inner)

    visit(tree, False)
    return out


@cache
def imports() -> tuple[Import, ...]:
    """Every import between two of our modules."""
    return tuple(i for name, path in modules().items() if path is not None
                 for i in _imports_of(name, path))


def layer(name: str) -> int:
    """The rank of ``name``'s layer in :data:`LAYERS`."""
    best, rank = -1, -1
    for r, (_, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (name == p or name.startswith(p + ".")) and len(p) > best:
                best, rank = len(p), r
    return rank


def _package(name: str) -> str:
    return name.partition(".")[0]


def cycles() -> list[tuple[str, ...]]:
    """The strongly connected sets of modules (two or more) of the import graph, sorted."""
    graph: dict[str, set[str]] = defaultdict(set)
    for i in imports():
        graph[i.importer].add(i.imported)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[tuple[str, ...]] = []

    def connect(v: str) -> None:  # Tarjan's algorithm, recursive (the graph is ~300 nodes deep at most)
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            members = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                members.append(w)
                if w == v:
                    break
            if len(members) > 1:
                found.append(tuple(sorted(members)))

    for v in sorted(modules()):
        if v not in index:
            connect(v)
    return sorted(found)


def upward() -> list[Import]:
    """Imports that run up the layers, but for the bench commands' (their own bar)."""
    return [i for i in imports() if layer(i.imported) > layer(i.importer)
            and not (i.importer in BENCH_ENTRY and _package(i.imported) == "tactiled_bench")]


def length(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def says_compiled_kernels(path: Path) -> bool:
    """Whether the module's first lines say it is a compiled-kernel file."""
    head = " ".join(path.read_text(encoding="utf-8").splitlines()[:5])
    return KERNEL_FILE in head


def long_modules() -> list[str]:
    return sorted(name for name, path in modules().items()
                  if path is not None and length(path) > MAX_LINES
                  and not says_compiled_kernels(path))


# --------------------------------------------------------------------------------------------
# The graph reads what it should


def test_the_graph_sees_module_level_lazy_and_relative_imports() -> None:
    """Known edges of each kind are found, so an empty answer below means something."""
    edges = {(i.importer, i.imported): i.in_function for i in imports()}
    assert edges[("tactiled.pipeline.daemon", "tactiled.settings")] is False
    assert edges[("tactiled.commands.run", "tactiled_service.server")] is True  # lazy
    assert edges[("tactiled.commands.bench", "tactiled_bench.suite")] is True
    # importlib.import_module(f"tactiled_bench.{suite}") counts as an import of the package
    assert ("tactiled.commands.bench", "tactiled_bench") in edges
    assert len(modules()) > 150 and len(imports()) > 800


def test_relative_imports_resolve_against_the_package(tmp_path: Path) -> None:
    source = tmp_path / "app.py"
    source.write_text("from .auth import check\nfrom . import stream\nfrom ..pipeline import hub\n")
    got = {i.imported for i in _imports_of("tactiled_service.app", source)}
    assert got == {"tactiled_service.auth", "tactiled_service.stream"}  # ..pipeline: not ours


def test_every_module_has_a_layer() -> None:
    missing = [m for m in modules() if layer(m) < 0]
    assert not missing, f"add these to LAYERS (tests/house/test_layers.py): {missing}"


# --------------------------------------------------------------------------------------------
# The bars


def test_the_runtime_never_imports_the_benchmarks() -> None:
    """Only ``tactiled bench`` and ``tactiled calibrate --bench`` reach ``tactiled_bench``, and
    only inside a function (importing the command never loads a benchmark)."""
    bad = [str(i) for i in imports() if _package(i.importer) in RUNTIME
           and _package(i.imported) == "tactiled_bench"
           and not (i.importer in BENCH_ENTRY and i.in_function)]
    assert not bad, "\n".join(bad)


def test_the_core_loads_drivers_and_service_only_from_a_command() -> None:
    """The core finds drivers by name (the driver table in ``tactiled.sources``) and imports
    the service or a driver only inside a command's function."""
    bad = [str(i) for i in imports() if _package(i.importer) == "tactiled"
           and _package(i.imported) in ("tactiled_drivers", "tactiled_service")
           and not (layer(i.importer) == layer("tactiled.commands") and i.in_function)]
    assert not bad, "\n".join(bad)


def test_no_import_runs_up_the_layers() -> None:
    bad = [f"{i}: layer {LAYERS[layer(i.importer)][0]} -> {LAYERS[layer(i.imported)][0]}"
           for i in upward()]
    assert not bad, "\n".join(bad)




def test_no_import_cycle_between_modules() -> None:
    bad = [" <-> ".join(c) for c in cycles()]
    assert not bad, "\n".join(bad)



def test_no_module_over_the_limit() -> None:
    bad = [f"{m}: {length(modules()[m])} lines" for m in long_modules()]  # type: ignore[arg-type]
    assert not bad, "\n".join(bad)



def test_a_long_kernel_file_says_so_in_its_first_lines(tmp_path: Path) -> None:
    """The exemption reads the file's first lines, not anywhere in it."""
    body = ["x = 1"] * (MAX_LINES + 10)
    said = tmp_path / "said.py"
    said.write_text("\n".join([f'"""Kernels: a {KERNEL_FILE} (one loop per stage)."""', *body]))
    late = tmp_path / "late.py"
    late.write_text("\n".join(['"""Kernels."""', *body, f"# a {KERNEL_FILE}"]))
    assert says_compiled_kernels(said) and not says_compiled_kernels(late)

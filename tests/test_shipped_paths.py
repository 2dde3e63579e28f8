"""Nothing a user reads may send them outside the repository: the README, the docs, the
package sources (tactiled/, drivers/, service/ with its static files, benchmarks/), deploy/ and
pyproject.toml name only files that ship with them.

"A path outside the repository" here is a reference to a project file that is not shipped:

* a ``../``-relative path that climbs out of the repository from the file naming it, or that
  names a document or source file (a known extension) that is not there (``../shared/MODEL.md``
  is both, from the README and from ``tactiled/``);
* a Markdown file named anywhere (``MODEL.md``, ``docs/concepts/model.md``) that exists neither
  beside the file naming it, nor at the repository root, nor in ``docs/``;
* an absolute path into a workspace (``/work/...``, ``/home/...``, ``/root/...``,
  ``/Users/...``, ``/mnt/...``): somebody's checkout, not the user's.

System paths a deployment legitimately names (``/dev/ttyACM0``, ``/etc/tactiled/...``,
``/var/lib/tactiled``, ``/usr/bin/...``, ``/proc``) and URL paths (``/v1/health``) are none of
these; nor is a symlink target such as ``ls -l``'s ``finger0 -> ../ttyACM0`` (no extension of
a document, and it stays inside the tree from where it is quoted).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SHIPPED_DIRS = ("docs", "tactiled", "drivers", "service", "benchmarks", "deploy")
SHIPPED_FILES = ("README.md", "pyproject.toml")
TEXT_SUFFIXES = {".py", ".md", ".toml", ".txt", ".html", ".js", ".css", ".service", ".rules",
                 ".json", ".cfg", ".ini", ".sh", ""}
#: Extensions of files a reference would point a reader to.
DOCUMENT_SUFFIXES = {".md", ".txt", ".rst", ".py", ".toml", ".json", ".jsonl", ".yaml", ".yml",
                     ".html", ".js", ".css", ".sh", ".tact", ".npz", ".service", ".rules",
                     ".pdf"}

PARENT_REF = re.compile(r"(?<![\w./-])((?:\.\./)+[\w.-]+(?:/[\w.-]+)*)")
MARKDOWN_REF = re.compile(r"(?<![\w./-])((?:[\w.-]+/)*[\w-][\w.-]*\.md)\b")
WORKSPACE_REF = re.compile(r"(?<![\w.~-])(/(?:work|home|root|Users|mnt)/[\w./-]*)")


def shipped_files() -> list[Path]:
    files = [ROOT / name for name in SHIPPED_FILES]
    for top in SHIPPED_DIRS:
        for path in sorted((ROOT / top).rglob("*")):
            if (path.is_file() and path.suffix in TEXT_SUFFIXES
                    and "__pycache__" not in path.parts
                    and not any(part.endswith(".egg-info") for part in path.parts)):
                files.append(path)
    return files


def _inside(path: Path) -> bool:
    try:
        path.resolve().relative_to(ROOT)
    except ValueError:
        return False
    return True


def outside_references(path: Path, text: str) -> list[str]:
    """The references of ``text`` (the content of ``path``) to paths outside the repository."""
    found = []
    for m in PARENT_REF.finditer(text):
        ref = m.group(1).rstrip(".")
        target = path.parent / ref
        if not _inside(target):
            found.append(f"{ref} (climbs out of the repository)")
        elif Path(ref).suffix in DOCUMENT_SUFFIXES and not target.exists():
            found.append(f"{ref} (no such file in the repository)")
    for m in MARKDOWN_REF.finditer(text):
        ref = m.group(1)
        if ref.startswith("../"):
            continue  # judged above
        if not any((base / ref).exists() for base in (path.parent, ROOT, ROOT / "docs")):
            found.append(f"{ref} (no such Markdown file in the repository)")
    for m in WORKSPACE_REF.finditer(text):
        found.append(f"{m.group(1)} (a workspace path)")
    return found


@pytest.mark.parametrize("path", shipped_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_shipped_file_names_a_path_outside_the_repository(path: Path) -> None:
    text = path.read_text(encoding="utf-8", errors="replace")
    assert outside_references(path, text) == []


def test_the_check_catches_what_it_is_for() -> None:
    """The checks flag the references this test exists for, and not what deployments and the
    API legitimately name."""
    readme, module = ROOT / "README.md", ROOT / "tactiled" / "__init__.py"
    assert outside_references(readme, "see `../shared/MODEL.md` for the equations")
    assert outside_references(module, "``../shared/MODEL.md`` pins the equations")
    assert outside_references(module, "Units follow ``MODEL.md``")
    assert outside_references(readme, "the paper text is in /work/shared/paper.txt")
    assert outside_references(readme, "cd ../other-project && make")
    assert outside_references(readme, "/home/dev/tactiled/docs/reference/api.md")
    legit = ("docs/concepts/model.md and `docs/reference/api.md`; README.md; serial:///dev/ttyACM0; "
             "/etc/tactiled/tactiled.toml; /var/lib/tactiled/{sensor}.tact; /usr/bin/chromium; "
             "curl http://127.0.0.1:8765/v1/health; /proc/PID/statm; finger0 -> ../ttyACM0; "
             "tactiled/physics/strain.py; /tmp/ttyTACT")
    assert outside_references(ROOT / "docs" / "howto" / "deploy.md", legit) == []


def test_the_model_is_documented_in_the_repository() -> None:
    text = (ROOT / "docs" / "concepts" / "model.md").read_text()
    for needle in ("h_x(u) = 2 d_x (d_x^2 - nu_x u^2)", "A'/C' = ( E(m) / (1 - m) - K(m) )",
                   "a^3 = 3 F k (K(m) - E(m)) / (2 pi m C')", "3 F / (2 pi a b)",
                   "strain[m, n] = (1/E)", "12.7 mm", "0.25 N/mm^2", "0.0005", "11.38", "0.037",
                   "positive under compression"):
        assert needle in text, needle
    assert "docs/concepts/model.md" in (ROOT / "README.md").read_text()

"""Every ``docs/...`` path a user can meet (an error message, a ``--help`` text, a docstring, a
comment, the README, a test or another page) names a file that exists: a reader following it
lands on a page.  Pages are also linked to each other; those links the site build checks."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCANNED = ("tactiled", "drivers", "service", "benchmarks", "deploy", "tests", "docs", "ros2", ".ci")
TOP_FILES = ("README.md", "CHANGELOG.md", "pyproject.toml", "mkdocs.yml")
SUFFIXES = {".py", ".md", ".toml", ".yml", ".yaml", ".txt", ".html", ".js", ".css", ".json",
            ".service", ".rules", ".msg", ".sh", ""}
DOCS_PATH = re.compile(r"(?<![\w.-])docs/[\w./-]*\w\.(?:md|png|json)\b")
#: Paths that name another project's docs tree (a URL), not ours.
FOREIGN = re.compile(r"https?://\S*$")


def scanned_files() -> list[Path]:
    files = [ROOT / name for name in TOP_FILES if (ROOT / name).exists()]
    for top in SCANNED:
        for path in sorted((ROOT / top).rglob("*")):
            if (path.is_file() and path.suffix in SUFFIXES and "__pycache__" not in path.parts
                    and path != Path(__file__).resolve()
                    and not any(p.endswith(".egg-info") for p in path.parts)):
                files.append(path)
    return files


def docs_paths(text: str) -> list[str]:
    found = []
    for m in DOCS_PATH.finditer(text):
        line_start = text.rfind("\n", 0, m.start()) + 1
        if FOREIGN.search(text[line_start:m.start()]):
            continue
        found.append(m.group(0))
    return found


def test_every_docs_path_named_anywhere_exists() -> None:
    missing, count = [], 0
    for path in scanned_files():
        for ref in docs_paths(path.read_text(encoding="utf-8", errors="replace")):
            count += 1
            if not (ROOT / ref).is_file():
                missing.append(f"{path.relative_to(ROOT)}: {ref}")
    print("FIGURES docs_paths:", {"references": count})
    assert count >= 100
    assert missing == []


def test_the_check_sees_a_wrong_path_and_leaves_urls_alone() -> None:
    assert docs_paths('raise ConfigError("see docs/sensors.md")') == ["docs/sensors.md"]
    assert docs_paths("(docs/howto/sensors.md, \"Flat arrays\")") == ["docs/howto/sensors.md"]
    assert docs_paths("https://github.com/ros2/rmw_zenoh/blob/rolling/docs/design.md") == []
    assert not (ROOT / "docs" / "sensors.md").exists()

"""The documentation site builds with MkDocs in strict mode: a broken link, a missing page or
anchor, a page left out of the nav or a command the CLI reference cannot generate fails it."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_the_site_builds_strictly_without_a_warning(tmp_path: Path) -> None:
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
         str(ROOT / "mkdocs.yml"), "--site-dir", str(tmp_path / "site")],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    output = done.stdout + done.stderr
    assert done.returncode == 0, output[-4000:]
    warnings = [line for line in output.splitlines() if line.startswith(("WARNING", "ERROR"))]
    assert warnings == []
    cli = (tmp_path / "site" / "reference" / "cli" / "index.html").read_text()
    from tactiled.cli import COMMANDS

    assert cli.count("usage: tactiled") == len(COMMANDS) + 1, "a command's help is missing"


def test_every_page_is_in_the_nav_and_every_nav_entry_exists() -> None:
    """``mkdocs build`` only reports pages left out of the nav (as INFO unless configured); the
    site's own config asks for a warning, which strict mode turns into a failure.  This checks
    the setting stays."""
    config = (ROOT / "mkdocs.yml").read_text()
    assert "strict: true" in config and "omitted_files: warn" in config and "anchors: warn" in config


def test_the_command_line_reference_has_every_command() -> None:
    from tactiled.cli import COMMANDS

    marks = re.findall(r"<!-- tactiled-help(?: ([a-z0-9_-]+))? -->",
                       (ROOT / "docs" / "reference" / "cli.md").read_text())
    assert "" in marks, "the top-level help is missing"
    assert sorted(m for m in marks if m) == sorted(COMMANDS)


def test_the_readme_stays_short_and_points_into_the_docs() -> None:
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) < 120
    assert "docs/index.md" in readme and "docs/img/dashboard-hand.png" in readme


def test_the_committed_command_line_reference_is_the_parsers_text() -> None:
    """docs/reference/cli.md holds each command's --help as the parser prints it, so the page
    reads whole where no hook runs (GitHub); `python docs/hooks.py` rewrites it."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    page = (ROOT / "docs" / "reference" / "cli.md").read_text()
    assert page == hooks.render(page), "docs/reference/cli.md is stale: run python docs/hooks.py"
    from tactiled.cli import COMMANDS

    assert page.count("usage: tactiled") == len(COMMANDS) + 1
    assert hooks.render(page.replace("usage: tactiled presses", "usage: old")) == page

"""MkDocs hook: the command-line reference shows each command's own ``--help``.

In a page, ``<!-- tactiled-help COMMAND -->`` is followed by a text block holding what
``tactiled COMMAND --help`` prints (``<!-- tactiled-help -->``: ``tactiled --help``), formatted
at 100 columns.  The build replaces the block with the parser's text, so the site cannot fall
behind the parser; the committed page holds the same text, so it reads whole on GitHub too
(``python docs/hooks.py`` rewrites it; ``tests/docs/test_site.py`` fails when it is stale).
An unknown command stops the build.
"""

from __future__ import annotations

import argparse
import os
import re
from typing import Any

MARK = re.compile(r"<!-- tactiled-help(?: ([a-z0-9_-]+))? -->(?:\n\n```text\n.*?\n```)?", re.S)
PAGE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "reference/cli.md")
COLUMNS = "100"


def help_text(command: str | None = None) -> str:
    """What ``tactiled [COMMAND] --help`` prints, at ``COLUMNS`` columns."""
    from tactiled.cli import build_parser

    saved = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = COLUMNS
    try:
        parser = build_parser()
        if command is None:
            return parser.format_help()
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        if command not in sub.choices:
            raise ValueError(f"docs: no tactiled command {command!r} (known: {', '.join(sub.choices)})")
        return sub.choices[command].format_help()
    finally:
        if saved is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = saved


def render(markdown: str) -> str:
    """``markdown`` with each mark followed by the parser's current text block."""
    def block(m: re.Match[str]) -> str:
        mark = f"<!-- tactiled-help{' ' + m.group(1) if m.group(1) else ''} -->"
        return f"{mark}\n\n```text\n{help_text(m.group(1)).rstrip()}\n```"

    return MARK.sub(block, markdown)


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    return render(markdown)


if __name__ == "__main__":  # rewrite the committed reference page
    import sys

    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    with open(PAGE, encoding="utf-8") as fh:
        text = fh.read()
    with open(PAGE, "w", encoding="utf-8") as fh:
        fh.write(render(text))

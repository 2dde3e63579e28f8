"""MkDocs hook: the command-line reference shows each command's own ``--help``.

In a page, ``<!-- tactiled-help COMMAND -->`` becomes a text block holding what ``tactiled
COMMAND --help`` prints (``<!-- tactiled-help -->``: ``tactiled --help``), formatted at 100
columns, so the reference is the parser itself and cannot fall behind it.  An unknown command
stops the build.
"""

from __future__ import annotations

import argparse
import os
import re
from typing import Any

MARK = re.compile(r"<!-- tactiled-help(?: ([a-z0-9_-]+))? -->")
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


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    return MARK.sub(lambda m: "```text\n" + help_text(m.group(1)).rstrip() + "\n```", markdown)

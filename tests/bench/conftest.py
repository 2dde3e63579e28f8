"""Shared helpers of the benchmark tests."""

from __future__ import annotations

from collections.abc import Callable

import pytest


def markdown_rows(out: str, header: str) -> list[list[str]]:
    """The cells of the rows of the Markdown table in ``out`` whose header line starts with
    ``header``."""
    lines = out.splitlines()
    i = next(k for k, line in enumerate(lines) if line.startswith(header))
    got = []
    for line in lines[i + 2:]:
        if not line.startswith("|"):
            break
        got.append([c.strip() for c in line.strip("|").split("|")])
    return got


@pytest.fixture
def table_rows() -> Callable[[str, str], list[list[str]]]:
    """:func:`markdown_rows`."""
    return markdown_rows

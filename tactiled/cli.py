"""Command line entry point (filled in by the foundation work)."""

import sys


def main(argv: list[str] | None = None) -> int:
    print("tactiled: not yet implemented", file=sys.stderr)
    return 2

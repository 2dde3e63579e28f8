"""Put this folder on PYTHONPATH and every Python process started with it (and its children,
which inherit the variable) behaves as if the test-only packages were not installed: importing
one raises ModuleNotFoundError.  ``TACTILED_BLOCKED`` (comma-separated top-level names)
replaces the default list."""

import os
import sys

BLOCKED = frozenset(os.environ.get("TACTILED_BLOCKED", "").split(",")) - {""} or frozenset({
    "httpx", "pytest", "_pytest", "playwright", "hypothesis", "mpmath", "matplotlib",
    "schemathesis", "PIL"})


class _Refuse:
    """A meta path finder that refuses the blocked packages before any other finder looks."""

    def find_spec(self, name, path=None, target=None):  # noqa: ANN001, ANN201
        if name.partition(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r} (not installed here)", name=name)
        return None


sys.meta_path.insert(0, _Refuse())

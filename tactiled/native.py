"""Which implementation of the frame path runs: the compiled core or the Python reference.

``tactiled._core`` is the C++ extension built by ``pip install`` (CMakeLists.txt, core/).  The
Python code it mirrors stays the reference; ``TACTILED_CORE=python`` selects it for a whole
process (its children inherit the variable), so every test can run against both.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Mapping
from types import ModuleType
from typing import Any

#: the bindings' version this Python expects (core/module.cpp's ``ABI``)
ABI = 1


def _load() -> ModuleType | None:
    choice = os.environ.get("TACTILED_CORE", "native").strip().lower()
    if choice not in ("native", "python"):
        raise ValueError(f"TACTILED_CORE={choice!r}: expected 'native' or 'python'")
    if choice == "python":
        return None
    try:
        from tactiled import _core
    except ImportError as err:  # an install that skipped the build: say how to mend it
        raise ImportError(
            "tactiled's compiled core (tactiled._core) is missing: reinstall with "
            "`pip install -e .` (it needs a C++ compiler), or set TACTILED_CORE=python "
            "to run the slower Python reference"
        ) from err
    if getattr(_core, "ABI", None) != ABI:
        raise ImportError(
            f"tactiled._core has ABI {getattr(_core, 'ABI', None)}, this Python expects {ABI}: "
            "rebuild it with `pip install -e .`"
        )
    return _core


#: the compiled core, or None where the Python reference was asked for
core: ModuleType | None = _load()


def name() -> str:
    """``"native"`` or ``"python"``: what this process runs (``tactiled replay``'s summary
    ends with it: ``core native``)."""
    return "python" if core is None else "native"


def bind(namespace: dict[str, Any], names: Mapping[str, str] | Iterable[str]) -> dict[str, Callable[..., Any]]:
    """Point a module's functions at the core's, when the core is loaded.

    ``names``: the module's names (each bound to the core's function of the same name), or a
    mapping of the module's names to the core's.  Returns the module's own Python bodies by
    name, whichever runs: the reference the core is held to (tests/native).  A Python body that
    calls another bound name calls the core's when the core is loaded.
    """
    pairs = dict(names) if isinstance(names, Mapping) else {n: n for n in names}
    reference = {name: namespace[name] for name in pairs}
    if core is not None:
        for name, core_name in pairs.items():
            namespace[name] = getattr(core, core_name)
    return reference

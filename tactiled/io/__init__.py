"""tactiled's file formats, one module each, and the registry that picks a reader or a writer
by what a file holds and its suffix.
"""

# * :mod:`~tactiled.io.recording`: ``.tact`` recordings (raw wire frames with host times);
# * :mod:`~tactiled.io.framefile`: ``.npz`` frame files (strain, or counts with a table);
# * :mod:`~tactiled.io.calibration`: ``.json`` calibration files;
# * :mod:`~tactiled.io.presses`: ``.npz`` press files;
# * :mod:`~tactiled.io.files`: what every format shares (checked paths, atomic writes, errors
#   naming the file).
#
# The registry follows python-can's ``can.io`` (hardbyte/python-can, ``can/io/logger.py``'s
# ``MESSAGE_WRITERS`` and ``can/io/player.py``'s ``MESSAGE_READERS``: a table from suffix to
# class, extended through entry points).  Two formats share ``.npz``, so a format is keyed by
# what it holds (``kind``) and its suffix.  Entries are ``"module:attribute"`` strings, imported
# on first use, so importing this package imports no format.  A layer above the core adds its
# own format through the ``tactiled.io.writers`` / ``tactiled.io.readers`` entry-point groups
# (name ``KIND.SUFFIX``): the service's MCAP writer is ``messages.mcap``.

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from importlib.metadata import entry_points
from pathlib import Path
from types import MappingProxyType
from typing import Any

#: (kind, suffix) -> ``"module:attribute"`` of the shipped readers (each takes a path).
READERS: Mapping[tuple[str, str], str] = MappingProxyType({
    ("recording", ".tact"): "tactiled.io.recording:RecordingReader",
    ("frames", ".npz"): "tactiled.io.framefile:load_frame_file",
    ("calibration", ".json"): "tactiled.io.calibration:load_calibration_file",
    ("presses", ".npz"): "tactiled.io.presses:load_presses",
})
#: (kind, suffix) -> ``"module:attribute"`` of the shipped writers.
WRITERS: Mapping[tuple[str, str], str] = MappingProxyType({
    ("recording", ".tact"): "tactiled.io.recording:RecordingWriter",
    ("frames", ".npz"): "tactiled.io.framefile:save_frame_file",
    ("calibration", ".json"): "tactiled.io.calibration:save_calibration",
    ("presses", ".npz"): "tactiled.io.presses:save_presses",
})
_GROUPS = {"reader": "tactiled.io.readers", "writer": "tactiled.io.writers"}
_registered: dict[tuple[str, str, str], str | Callable[..., Any]] = {}


def register(kind: str, suffix: str, *, reader: str | Callable[..., Any] | None = None,
             writer: str | Callable[..., Any] | None = None) -> None:
    """Add (or replace) the reader and/or writer of ``kind`` files ending in ``suffix``
    (``".mcap"``); a ``"module:attribute"`` string is imported on first use."""
    key = suffix.lower()
    if reader is not None:
        _registered[("reader", kind, key)] = reader
    if writer is not None:
        _registered[("writer", kind, key)] = writer


def _entry_points(role: str) -> dict[tuple[str, str], str]:
    out = {}
    for point in entry_points(group=_GROUPS[role]):
        kind, _, suffix = point.name.partition(".")
        out[(kind, f".{suffix.lower()}")] = point.value
    return out


def _target(role: str, kind: str, suffix: str) -> str | Callable[..., Any] | None:
    shipped = READERS if role == "reader" else WRITERS
    key = suffix.lower()
    return (_registered.get((role, kind, key)) or shipped.get((kind, key))
            or _entry_points(role).get((kind, key)))


def suffixes(kind: str, role: str = "writer") -> list[str]:
    """The suffixes a ``kind`` file can be read (``role="reader"``) or written with."""
    shipped = READERS if role == "reader" else WRITERS
    keys = {s for (k, s) in shipped if k == kind}
    keys |= {s for (r, k, s) in _registered if r == role and k == kind}
    keys |= {s for (k, s) in _entry_points(role) if k == kind}
    return sorted(keys)


def _load(role: str, kind: str, path: str | Path) -> Callable[..., Any]:
    suffix = Path(path).suffix
    target = _target(role, kind, suffix)
    if target is None:
        known = ", ".join(suffixes(kind, role)) or "none"
        raise ValueError(f"{path}: no {kind} {role} for {suffix or 'a name without a suffix'!r} "
                         f"(known: {known})")
    if callable(target):
        return target
    module, _, attr = target.partition(":")
    return getattr(importlib.import_module(module), attr)  # ImportError: a missing extra


def reader(kind: str, path: str | Path) -> Callable[..., Any]:
    """The reader of a ``kind`` file at ``path``, by its suffix (``ValueError`` naming the
    known suffixes for another; ``ImportError`` when the format's optional library is missing)."""
    return _load("reader", kind, path)


def writer(kind: str, path: str | Path) -> Callable[..., Any]:
    """The writer of a ``kind`` file at ``path``, by its suffix (see :func:`reader`)."""
    return _load("writer", kind, path)


__all__ = ["READERS", "WRITERS", "reader", "register", "suffixes", "writer"]

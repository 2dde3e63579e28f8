"""How the daemon and its fit workers pack what they send each other (see
:mod:`tactiled.pipeline.worker` for the protocol).

The arrays of a fit request travel as ``(bytes, shape, dtype)`` and the tuple is pickled once
by :func:`pickle.dumps`; the linearisations coming back pack themselves
(:mod:`tactiled.fit.linearize`).
"""

# Messages are tuples pickled over a ``multiprocessing`` Connection, and the parent sends a frame
# to fit or linearise a few hundred times a second.  Pickling a numpy array goes through its
# ``__reduce__`` (its dtype, flags and a copy), several times the cost of pickling its bytes;
# :meth:`Connection.recv` loads a message pickled by :func:`pickle.dumps` as it loads any other.

from __future__ import annotations

import pickle
from typing import Any

import numpy as np

#: An array as it travels: its bytes (C order), shape and dtype string; None for no array.
Packed = tuple[bytes, tuple[int, ...], str]


def pack_array(a: np.ndarray | None) -> Packed | None:
    """``a`` as :data:`Packed` (None stays None)."""
    if a is None:
        return None
    return a.tobytes(), a.shape, a.dtype.str


def unpack_array(packed: Packed | None) -> np.ndarray | None:
    """The array :func:`pack_array` packed: a writable copy of it (None stays None)."""
    if packed is None:
        return None
    data, shape, dtype = packed
    return np.frombuffer(data, dtype=dtype).reshape(shape).copy()


def dumps(message: tuple[Any, ...]) -> bytes:
    """``message`` as :meth:`multiprocessing.connection.Connection.send_bytes` takes it, to be
    read with :meth:`~multiprocessing.connection.Connection.recv`."""
    return pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)

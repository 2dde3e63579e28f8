"""The files the commands read and write: one place that turns every way a file can be wrong
into one line naming the file and what is wrong.
"""

# Every command that takes a file goes through here: ``tactiled fit`` (frames, calibration),
# ``simulate`` (frames or presses out), ``calibrate`` (presses in, calibration out), ``replay``
# (recording, calibration), ``record`` (recording out) and ``bench --plot`` (picture out).
# What each file must *hold* (keys, shapes, values) is checked by its own module
# (:mod:`tactiled.io.framefile`, :mod:`tactiled.calibration.presses`,
# :mod:`tactiled.io.calibration`), with :func:`plain` to show values: a message never
# holds a numpy repr such as ``array(5)`` or ``np.float64(nan)``.
#
# The errors raised are the caller's :class:`~tactiled.errors.TactiledError` subclass (a frame
# file's problems are :class:`~tactiled.errors.FrameError`, a press file's
# :class:`~tactiled.errors.CalibrationError`), which the command line turns into one line and
# exit code 2.

from __future__ import annotations

import math
import os
import tempfile
import zipfile
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

import numpy as np

from tactiled.errors import FrameError, TactiledError

ErrorType = type[TactiledError]

_NPY_MAGIC = b"\x93NUMPY"
_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")  # a local file header; an empty archive's end
_RECORDING_MAGIC = b"TACTREC\x00"  # tactiled.io.recording.MAGIC (not imported: keep this light)


def plain(value: Any) -> str:
    """``value`` as a user reads it: numbers and strings as Python prints them, an array as
    its shape and type (never numpy's ``array(...)`` or ``np.float64(...)``)."""
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value[()]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, np.ndarray):
        return f"an array of shape {tuple(int(n) for n in value.shape)} ({value.dtype.name})"
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)  # nan, inf, -inf
    if isinstance(value, bytes):
        return f"{len(value)} bytes"
    if isinstance(value, tuple):
        return "(" + ", ".join(plain(v) for v in value) + ("," if len(value) == 1 else "") + ")"
    return repr(value)


def check_input(path: str | os.PathLike[str], error: ErrorType = FrameError) -> Path:
    """``path`` as a :class:`Path` once it is known to be a readable file; ``error`` naming it
    when it is missing, a directory or unreadable."""
    path = Path(path)
    try:
        path.stat()
    except FileNotFoundError:
        parent = path.parent
        if str(parent) not in ("", ".") and not parent.is_dir():
            raise error(f"{path}: no such file (no directory {parent})") from None
        raise error(f"{path}: no such file") from None
    except OSError as err:
        raise error(f"{path}: cannot read it ({_why(err)})") from None
    if path.is_dir():
        raise error(f"{path}: is a directory, not a file")
    if not os.access(path, os.R_OK):
        raise error(f"{path}: cannot read it (permission denied)")
    return path


def check_output(path: str | os.PathLike[str], error: ErrorType = FrameError) -> Path:
    """``path`` as a :class:`Path` once a file can be written there (its directory exists
    and is writable, and it is not itself a directory): called before the work, so a long run
    never ends in a refusal to save it."""
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise error(f"{path}: is a directory; give a file name to write")
    if not parent.exists():
        raise error(f"{path}: cannot write it: no directory {parent}")
    if not parent.is_dir():
        raise error(f"{path}: cannot write it: {parent} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise error(f"{path}: cannot write it: directory {parent} is not writable")
    return path


def read_text(path: str | os.PathLike[str], what: str, error: ErrorType) -> str:
    """The UTF-8 text of ``path`` (a ``what``: "calibration file"...), or ``error``."""
    path = check_input(path, error)
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise error(f"{path}: not a {what} (not UTF-8 text)") from None
    except OSError as err:
        raise error(f"{path}: cannot read it ({_why(err)})") from None


def read_npz(path: str | os.PathLike[str], what: str = "frame file",
             error: ErrorType = FrameError) -> dict[str, np.ndarray]:
    """Every array of the ``.npz`` file ``path`` (a ``what``), read now; ``error`` naming the
    file and what is wrong when it is not one (a single ``.npy`` array, a text file, a
    recording, a truncated or corrupt archive, an array of pickled objects, which are never
    loaded)."""
    path = check_input(path, error)
    try:
        with open(path, "rb") as fh:
            head = fh.read(8)
    except OSError as err:
        raise error(f"{path}: cannot read it ({_why(err)})") from None
    if not head:
        raise error(f"{path}: empty file, not an .npz {what}")
    if head.startswith(_NPY_MAGIC):
        raise error(f"{path}: a single .npy array, not an .npz {what} of named arrays "
                    "(write one with numpy.savez)")
    if head.startswith(_RECORDING_MAGIC):
        raise error(f"{path}: a tactiled recording, not an .npz {what} (tactiled replay reads it)")
    if not head.startswith(_ZIP_MAGIC):
        raise error(f"{path}: not an .npz {what} (no zip archive signature; truncated, or "
                    "another kind of file?)")
    if not zipfile.is_zipfile(path):
        raise error(f"{path}: not a complete .npz {what} (the zip archive has no end; truncated?)")
    arrays: dict[str, np.ndarray] = {}
    try:
        with np.load(path, allow_pickle=False) as data:
            for key in data.files:
                arrays[key] = _member(data, key, path, error)
    except TactiledError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, KeyError) as err:
        raise error(f"{path}: not a readable .npz {what} ({_why(err)})") from None
    return arrays


def _member(data: Any, key: str, path: Path, error: ErrorType) -> np.ndarray:
    try:
        value = data[key]
    except ValueError as err:
        if "pickle" in str(err).lower() or "object" in str(err).lower():
            raise error(f"{path}: array {key!r} holds Python objects; tactiled reads only "
                        "numeric arrays (and never unpickles a file)") from None
        raise error(f"{path}: array {key!r} cannot be read ({_why(err)})") from None
    except (OSError, EOFError, zipfile.BadZipFile, zlib.error) as err:
        raise error(f"{path}: array {key!r} is corrupt ({_why(err)})") from None
    if not isinstance(value, np.ndarray):  # a member that is not an .npy: numpy gives bytes
        raise error(f"{path}: {key!r} is not a numpy array (another file inside the archive)")
    return value


def write_npz(path: str | os.PathLike[str], arrays: dict[str, Any], *, compressed: bool = True,
              error: ErrorType = FrameError) -> Path:
    """Write ``arrays`` to ``path`` as an ``.npz`` (the name as given: numpy appends no
    ``.npz``), atomically: a temporary file in the same directory renamed over ``path``, so
    a crash never leaves half a file.  ``error`` names the file when it cannot be written."""
    save: Callable[..., None] = np.savez_compressed if compressed else np.savez
    with atomic_output(path, error) as fh:
        save(fh, **arrays)
    return Path(path)


@contextmanager
def atomic_output(path: str | os.PathLike[str], error: ErrorType = FrameError,
                  mode: str = "wb") -> Iterator[IO[Any]]:
    """A file object to write ``path`` through: a temporary file in its directory, renamed
    over ``path`` when the block ends without an error (and removed when it does not)."""
    path = check_output(path, error)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent or ".")
    except OSError as err:
        raise error(f"{path}: cannot write it ({_why(err)})") from None
    try:
        with os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": "utf-8"})) as fh:
            yield fh
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except OSError as err:
        Path(tmp).unlink(missing_ok=True)
        raise error(f"{path}: cannot write it ({_why(err)})") from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _why(err: BaseException) -> str:
    """An OS or library error's reason, without the path numpy or the OS repeat in it."""
    if isinstance(err, OSError) and err.strerror:
        return err.strerror.lower()
    return str(err) or type(err).__name__

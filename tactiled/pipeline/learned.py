"""What the daemon learns of a finger from its own fits, kept across restarts.

The flat field (:mod:`tactiled.fit.flatfield`) is saved per sensor in the state directory
(``[state] dir``) as ``flatfield-<name>.npz``, and loaded at start only when it was learned by
the same sensor through the same sensor model; any other file is refused with one clear reason.
"""

# The flat field is each tactel's gain and position, with the normal equations they come from.
# "The same sensor" is its name and wire id; "the same sensor model" is the :func:`fingerprint`
# of the SensorModel the fits use and of the calibration file it came from.  Files are written
# whole: a temporary file in the same directory, flushed to disk, then renamed over the old one.

from __future__ import annotations

import hashlib
import json
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tactiled.sensors.model import SensorModel

log = logging.getLogger("tactiled.pipeline.sensor")

#: Bumped when the file's content changes meaning; older files are refused.
VERSION = 1
def fingerprint(sensor: SensorModel, calibration: str | os.PathLike[str] | None = None,
                description: str = "") -> str:
    """A digest of everything the fits take from the sensor model: every field of ``sensor``
    (geometry, cover, noise, tactel positions, model-error floor, and whatever a SensorModel
    comes to hold: its ``repr`` is taken whole, floats exactly), the sensor description's own
    fingerprint (``SensorDescription.fingerprint()``: its wire order and dead tactels too) and
    the calibration file's bytes, if any.  Learned state keyed on it is never applied through
    another model."""
    h = hashlib.sha256(repr(sensor).encode())
    h.update(b"\0description\0" + description.encode())
    if calibration is not None:
        h.update(b"\0calibration\0")
        h.update(Path(calibration).read_bytes())
    return h.hexdigest()


@dataclass(frozen=True)
class Owner:
    """Whose learned state a file holds: the sensor's name and wire id, and the model's
    :func:`fingerprint`."""

    name: str
    wire_id: int | None
    fingerprint: str

    def meta(self) -> dict[str, Any]:
        return {"version": VERSION, "name": self.name, "wire_id": self.wire_id,
                "fingerprint": self.fingerprint}


def state_path(directory: str | os.PathLike[str], name: str) -> Path:
    """The flat-field file of sensor ``name`` (names are ``[A-Za-z0-9_.-]``: safe in a path)."""
    return Path(directory) / f"flatfield-{name}.npz"


def save(path: Path, owner: Owner, state: dict[str, np.ndarray]) -> None:
    """Write ``state`` for ``owner`` to ``path`` whole (temporary file, fsync, rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as fh:
            np.savez(fh, meta=np.asarray(json.dumps(owner.meta())), **state)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def saved_fits(path: Path) -> int:
    """The fits the state at ``path`` was learned from; -1 without a readable file."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return int(data["fits"])
    except Exception:
        return -1


class Refused(Exception):
    """A learned-state file that must not be applied; the message says why, in one line."""


def load(path: Path, owner: Owner) -> dict[str, np.ndarray] | None:
    """The state saved for ``owner`` at ``path``; None when there is no file; :class:`Refused`
    when the file is unreadable or belongs to another sensor or model."""
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            state = {k: data[k] for k in data.files}
        meta = json.loads(str(state.pop("meta")))
    except Exception as err:  # a truncated or foreign file: refused, never a traceback
        raise Refused(f"{path}: not a learned-state file ({type(err).__name__}: {err})") from None
    if not isinstance(meta, dict) or meta.get("version") != VERSION:
        raise Refused(f"{path}: unknown format version {meta.get('version') if isinstance(meta, dict) else meta!r}")
    for key, what in (("name", "sensor"), ("wire_id", "wire id"), ("fingerprint", "sensor model")):
        if meta.get(key) != getattr(owner, key):
            raise Refused(f"{path}: learned by another {what} ({meta.get(key)!r}, this one is "
                          f"{getattr(owner, key)!r}): not applied")
    return state


@dataclass
class LearnedFile:
    """One sensor's flat-field file in the state ``directory`` (None: nothing kept): whether
    the workers start from it (``restore``), the fits it was loaded with, the files refused
    (and why)."""

    directory: Path | None
    restore: bool = False
    loaded_fits: int | None = None
    refused: int = 0
    refusal: str = ""

    def check(self, owner: Owner) -> None:
        """Load the file's verdict: restored when ``owner`` learned it through this model; a
        file that is not is logged, counted and left alone (the workers overwrite it once this
        sensor has learned)."""
        self.restore = False
        if self.directory is None:
            return
        path = state_path(self.directory, owner.name)
        try:
            state = load(path, owner)
        except Refused as err:
            self.refused += 1
            self.refusal = str(err)
            log.warning("%s: learned flat field refused: %s", owner.name, err)
            return
        if state is None:
            return
        self.loaded_fits = int(state["fits"])
        self.restore = True
        log.info("%s: learned flat field loaded from %s (%d fits)", owner.name, path,
                 self.loaded_fits)

    def fit_options(self, owner: Owner) -> tuple[tuple[str, Any], ...]:
        """The workers' fit option saying where ``owner``'s flat field is kept (none without
        a state directory)."""
        if self.directory is None:
            return ()
        path = str(state_path(self.directory, owner.name))
        return (("learned", (path, owner.name, owner.wire_id, owner.fingerprint, self.restore)),)

    def summary(self) -> dict[str, Any]:
        """``{"loaded_fits", "refused", "refusal"}``: the stats' ``learned_state``."""
        return {"loaded_fits": self.loaded_fits, "refused": self.refused,
                "refusal": self.refusal}

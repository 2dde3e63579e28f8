"""A press file from a recording: the presses found in the frames, paired with known contacts."""

# The lab records the whole session with ``tactiled record`` (the array unloaded at the start,
# then each press: load, hold, lift off fully) and writes down, in the order pressed, the known
# contact of every press: a CSV file with the header ``r1_mm,r2_mm,angle_deg,force_n,x_mm,y_mm``
# (``inf`` for a cylinder's ``r2``; ``#`` starts a comment).  A row with ``force_n`` 0 is an
# unloaded sample (its other columns are ignored).
#
# How the frames are read:
#
# * the **rest**: each tactel's median over the first ``quiet`` frames, and its noise, their
#   standard deviation (at least half a count, the rounding of an integer count);
# * a frame is **loaded** when some tactel departs from its rest by more than ``threshold``
#   times its noise; a **press** is a run of loaded frames (runs less than ``gap`` frames apart
#   are one press; shorter than ``average`` frames is an error naming it);
# * a press's counts are the mean of its last ``average`` frames before its release (the last
#   tenth of the run is left out: the indenter lifting off), the settled load;
# * an unloaded row is the mean of the ``average`` unloaded frames just before the next loaded
#   press (after the last press: the recording's last ``average`` frames); the contacts'
#   own checks (:class:`PressSet`) then apply.
#
# The presses found must be as many as the loaded rows, else :class:`CalibrationError` with both
# counts, so a missed or extra press never shifts every contact onto the wrong frames.

from __future__ import annotations

import csv
import os

import numpy as np

from tactiled.calibration.presses import CONTACT_COLUMNS, PressSet
from tactiled.errors import CalibrationError, FrameError

#: Defaults: frames at rest that set the rest, the loaded threshold (noise sigmas), the
#: frames averaged per press, the longest quiet spell inside one press (frames).
QUIET, THRESHOLD, AVERAGE, GAP = 50, 8.0, 32, 5


def read_contacts(path: str | os.PathLike[str]) -> np.ndarray:
    """The ``(N, 6)`` known contacts of a CSV file (see the module text)."""
    rows: list[list[float]] = []
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            lines = [line for line in fh if line.strip() and not line.lstrip().startswith("#")]
    except OSError as err:
        raise CalibrationError(f"{path}: cannot read: {err.strerror or err}") from None
    reader = csv.reader(lines)
    header = [h.strip() for h in next(reader, [])]
    if tuple(header) != CONTACT_COLUMNS:
        raise CalibrationError(f"{path}: the first line must be {','.join(CONTACT_COLUMNS)}, "
                               f"got {','.join(header) or 'nothing'}")
    for k, row in enumerate(reader, start=1):
        try:
            values = [float(v) for v in row]
        except ValueError:
            raise CalibrationError(f"{path}: contact {k}: not numbers: {','.join(row)}") from None
        if len(values) != len(CONTACT_COLUMNS):
            raise CalibrationError(f"{path}: contact {k}: {len(values)} values, expected "
                                   f"{len(CONTACT_COLUMNS)}")
        rows.append(values)
    if not rows:
        raise CalibrationError(f"{path}: no contacts")
    return np.asarray(rows, dtype=np.float64)


def recorded_counts(path: str | os.PathLike[str]) -> tuple[np.ndarray, int]:
    """The raw counts ``(N, rows, cols)`` of a recording's frames, and its sensor id."""
    from tactiled.frames import FrameDecoder
    from tactiled.io.recording import RecordingReader

    decoder = FrameDecoder()
    frames: list[np.ndarray] = []
    try:
        with RecordingReader(path) as reader:
            sensor_id = int(reader.header.sensor_id)
            for t, data in reader:
                frames.extend(np.asarray(f.raw) for f in decoder.feed(data, t))
    except (OSError, FrameError) as err:
        raise CalibrationError(f"{path}: {err}") from None
    if not frames:
        raise CalibrationError(f"{path}: no frames")
    if len({f.shape for f in frames}) > 1:
        raise CalibrationError(f"{path}: frames of several shapes")
    return np.stack(frames), sensor_id


def find_presses(counts: np.ndarray, *, quiet: int = QUIET, threshold: float = THRESHOLD,
                 average: int = AVERAGE, gap: int = GAP) -> list[tuple[int, int]]:
    """The presses of a frame sequence as ``(first, end)`` frame ranges (see the module text)."""
    c = np.asarray(counts, dtype=np.float64)
    if len(c) < quiet + average:
        raise CalibrationError(f"{len(c)} frames: fewer than the {quiet} at rest and {average} "
                               "of one press")
    rest = np.median(c[:quiet], axis=0)
    noise = np.maximum(c[:quiet].std(axis=0), 0.5)
    loaded = (np.abs(c - rest) / noise).reshape(len(c), -1).max(axis=1) > threshold
    if loaded[:quiet].any():
        raise CalibrationError(f"a tactel moves by more than {threshold:g} noise sigmas within "
                               f"the first {quiet} frames: start the recording unloaded")
    runs: list[list[int]] = []
    for i in np.flatnonzero(loaded):
        if runs and i - runs[-1][1] <= gap:
            runs[-1][1] = int(i) + 1
        else:
            runs.append([int(i), int(i) + 1])
    for k, (a, b) in enumerate(runs, start=1):
        if b - a - max(1, (b - a) // 10) < average:
            raise CalibrationError(f"press {k} (frames {a}..{b - 1}) holds for {b - a} frames: "
                                   f"too short to average {average} settled frames")
    return [(a, b) for a, b in runs]


def presses_from_recording(counts: np.ndarray, contacts: np.ndarray, sensor_id: int | None, *,
                           quiet: int = QUIET, threshold: float = THRESHOLD,
                           average: int = AVERAGE, gap: int = GAP) -> PressSet:
    """The press file's content: one averaged counts frame per row of ``contacts``."""
    runs = find_presses(counts, quiet=quiet, threshold=threshold, average=average, gap=gap)
    loaded_rows = int((contacts[:, 3] > 0).sum())
    if len(runs) != loaded_rows:
        raise CalibrationError(f"the recording holds {len(runs)} press(es), but the contacts "
                               f"list {loaded_rows} loaded one(s)")
    c = np.asarray(counts, dtype=np.float64)
    out = np.zeros((len(contacts), *c.shape[1:]))
    press = 0
    for k, row in enumerate(contacts):
        if row[3] > 0:
            a, b = runs[press]
            end = b - max(1, (b - a) // 10)
            out[k] = c[end - average:end].mean(axis=0)
            press += 1
            continue
        end = runs[press][0] - gap if press < len(runs) else len(c)
        start = max(end - average, runs[press - 1][1] + gap if press > 0 else 0)
        if end - start < average:
            raise CalibrationError(f"unloaded contact {k + 1}: fewer than {average} frames at "
                                   "rest before the next press")
        out[k] = c[start:end].mean(axis=0)
    clean = contacts.copy()
    clean[clean[:, 3] <= 0] = 0.0
    counts_out = np.clip(np.rint(out), 0, 0xFFFF).astype(np.uint16)
    return PressSet(counts_out, None, sensor_id, clean)

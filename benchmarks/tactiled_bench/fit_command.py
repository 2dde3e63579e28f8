"""Frames through ``tactiled fit`` as a user runs it: a frame file, the command, its lines."""
# The command runs in this process (``tactiled.cli.main``, the same parser and code the shell
# runs, one job: its output does not depend on the job count), its stdout and stderr captured.
# Its learning pass runs as it does by default (``--learn``): what it says is returned.

from __future__ import annotations

import io
import json
import tempfile
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

import numpy as np

from tactiled.io.framefile import save_frame_file
from tactiled.sensors import SensorDescription


def fit_lines(frames: np.ndarray, desc: SensorDescription, model: str,
              spec: str | None = None) -> tuple[list[dict[str, Any]], str]:
    """``tactiled fit FRAMES.npz --sensor SPEC --model MODEL``'s output lines (one per frame,
    parsed) and what it said on stderr.  ``spec``: the ``--sensor`` argument (a built-in's
    name or a description file; default ``desc.name``)."""
    from tactiled.cli import main

    with tempfile.TemporaryDirectory(prefix="tactiled-bench-") as tmp:
        path = Path(tmp) / "frames.npz"
        save_frame_file(path, frames, desc.pitch_x_mm, desc.pitch_y_mm)
        out, err = io.StringIO(), io.StringIO()
        with redirect_stdout(out), redirect_stderr(err):
            rc = main(["fit", str(path), "--sensor", spec or desc.name, "--model", model,
                       "--jobs", "1", "--no-progress"])
    if rc != 0:
        raise RuntimeError(f"tactiled fit exited {rc}: {err.getvalue().strip()}")
    return [json.loads(line) for line in out.getvalue().splitlines()], err.getvalue().strip()


def contacts_of(line: dict[str, Any]) -> list[dict[str, Any]]:
    """The contacts one ``tactiled fit`` line reports (none, one, or its ``contacts``)."""
    if not line.get("contact"):
        return []
    return list(line.get("contacts") or [line])

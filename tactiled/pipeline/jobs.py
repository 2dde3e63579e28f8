"""What the worker pool and a sensor pipeline exchange: a fit job, and the sensor as the pool
sees it (its owner)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from tactiled.fit.warm import SEVERAL
from tactiled.pipeline.contact_filter import within_reason
from tactiled.sensors.model import Geometry


class JobOwner(Protocol):
    """What the pool needs of a sensor pipeline."""

    name: str

    def job_waiting_since(self) -> float | None:
        """Monotonic time its waiting frame became ready to fit, or None if nothing waits."""

    def job_background(self) -> bool:
        """True when the waiting job answers no frame (a relinearisation for the tracker):
        it goes to a worker only when no frame of any sensor waits for a fit."""

    def take_job(self) -> FitJob:
        """Hand over the waiting frame as a job (now in flight)."""

    def on_fit_result(self, job: FitJob, fit: dict[str, Any] | None, worker_ms: float,
                      error: str | None, warm: tuple[str, tuple[float, ...]] | None = None,
                      lin: Any = None) -> None:
        """The worker answered (``fit`` is None and ``error`` says why if the fitter raised);
        ``warm`` is the solution as a warm start for the sensor's next frame (None if unfit
        for one); ``lin`` the linearisation the job asked for (None if there is none)."""

    def on_fit_failed(self, job: FitJob, reason: str) -> None:
        """The job is lost: its worker died, hung, or the pool stopped."""



@dataclass
class FitJob:
    """One frame to fit: ``ordinal`` is the sensor's own arrival count (never wraps)."""

    owner: JobOwner
    ordinal: int
    seq: int
    strain: np.ndarray
    model: str
    spec: int
    mask: np.ndarray | None = None  # usable tactels (None: all)
    #: the sensor's previous fit on a persisting contact, ``(model, params)``: a warm start
    warm: tuple[str, tuple[float, ...]] | None = None
    #: "fit"; "fit+lin": a fit and its linearisation; "lin": only the linearisation of the
    #: frame at ``warm`` (the tracker's state, see tactiled.pipeline.contact_filter)
    kind: str = "fit"
    sent_at: float = 0.0


#: Warm starts go to the workers rounded to this grid (internal units: ln mm, ln N, rad, mm),
#: so the last bits of whatever CPU computed the tracker's state never reach an estimate
#: through a fit that stops short of convergence (but for a start within 1e-16 of the grid).
WARM_GRID = 1e-9


def warm_start(warm: tuple[str, tuple[float, ...]] | None,
                geometry: Geometry) -> tuple[str, tuple[float, ...]] | None:
    """A warm start as it goes to a worker: within what a finger carries (a filter whose
    radius ran off, an edge too light for its curvature, must not start a fit whose first
    evaluation outlasts the worker's deadline), on the grid."""
    if warm is None:
        return None
    if warm[0] == SEVERAL:
        each = (warm_start(w, geometry) for w in warm[1])  # type: ignore[arg-type]
        return SEVERAL, tuple(w for w in each if w is not None)  # type: ignore[return-value]
    p = within_reason(warm[1], geometry)
    return warm[0], tuple([round(v / WARM_GRID) * WARM_GRID for v in p])

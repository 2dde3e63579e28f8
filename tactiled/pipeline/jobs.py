"""What the worker pool and a sensor pipeline exchange: a fit job, and the sensor as the pool
sees it (its owner)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np


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


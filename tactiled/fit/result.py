"""FitResult: what a fit found, how sure it is, and why anything is missing.

Like lmfit's MinimizerResult it carries values, uncertainties, residual, iterations, convergence
and a message; a quantity that could not be estimated is ``None`` with an entry in ``reasons``
(lmfit's ``errorbars = False``), never NaN or inf, so every result serialises to strict JSON.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from tactiled.fit.params import VALUE_KEYS


def _finite_or_none(x: float | None) -> float | None:
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass
class FitResult:
    """Outcome of one fit (or of the decision not to fit).

    ``values`` and ``std`` are keyed by ``VALUE_KEYS`` (mm, N, degrees; ``r2_mm`` None means
    infinite for a cylinder; ``angle_deg`` is psi in [0, 180), None for a sphere).  ``std`` are
    1-sigma Cramer-Rao uncertainties ``sigma^2 (J^T J)^-1`` propagated to user units.  ``rms`` is
    the RMS residual over the window as a fraction of the peak strain.
    """

    contact: bool
    model: str | None = None
    label: str | None = None
    values: dict[str, float | None] = field(default_factory=lambda: dict.fromkeys(VALUE_KEYS))
    std: dict[str, float | None] = field(default_factory=lambda: dict.fromkeys(VALUE_KEYS))
    rms: float | None = None
    chi2: float | None = None
    iterations: int = 0
    evaluations: int = 0
    converged: bool = False
    condition: float | None = None
    peak: float | None = None
    n_points: int = 0
    window: tuple[int, int, int, int] | None = None  # (row0, col0, rows, cols)
    starts: int = 0
    fit_ms: float = 0.0
    message: str = ""
    reasons: dict[str, str] = field(default_factory=dict)
    criterion: dict[str, float] | None = None  # model -> information criterion (auto)
    #: the model's internal parameter vector at the solution (a warm start for the next frame)
    params: tuple[float, ...] | None = None
    #: the fitted contact ellipse, for display: semi-axes a >= b in mm, major axis direction
    #: theta in degrees from +x toward +y, in [0, 180)
    ellipse: dict[str, float] | None = None
    #: a line contact's own quantities (a cylinder on a flat array, tactiled.fit.line):
    #: load_n_per_mm and offset_mm with their 1-sigma bounds (``*_std``); None otherwise
    line: dict[str, float | None] | None = None

    def __post_init__(self) -> None:
        self.sanitise()

    def sanitise(self) -> None:
        """Replace any non-finite number by None with a reason (never NaN on the wire)."""
        isfinite = math.isfinite
        for table, what in ((self.values, "value"), (self.std, "uncertainty")):
            for k, v in table.items():
                if v is None or (type(v) is float and isfinite(v)):
                    continue  # the common case: nothing to change (a dict's values may be set)
                fv = _finite_or_none(v)
                if fv is None:
                    self.reasons.setdefault(k, f"{what} not finite")
                table[k] = fv
        # the common case, a finite float or None, is left as it is (what _finite_or_none gives)
        for name in ("rms", "chi2", "condition", "peak"):
            v = getattr(self, name)
            if not (v is None or (type(v) is float and isfinite(v))):
                setattr(self, name, _finite_or_none(v))
        if self.ellipse is not None:
            for v in self.ellipse.values():
                if not isfinite(v):
                    self.ellipse = None
                    break

    def to_json_dict(self, frame: int | None = None) -> dict[str, Any]:
        """The ``tactiled fit`` line (also the WebSocket estimate body)."""
        out: dict[str, Any] = {}
        if frame is not None:
            out["frame"] = frame
        out.update(
            contact=self.contact,
            model=self.model,
            **{k: self.values.get(k) for k in VALUE_KEYS},
            rms=self.rms,
            std={k: self.std.get(k) for k in VALUE_KEYS},
            fit_ms=round(self.fit_ms, 4),
            label=self.label,
            converged=self.converged,
            iterations=self.iterations,
            condition=self.condition,
            peak=self.peak,
            reasons=dict(self.reasons),
            message=self.message,
            ellipse=dict(self.ellipse) if self.ellipse else None,
        )
        if self.line is not None:
            out["line"] = {k: _finite_or_none(v) for k, v in self.line.items()}
        return out

"""The contact model in the daemon's own process: linearisations for the tracker, at once.

The tracker measures each contact frame through a linearisation of the model
(:mod:`tactiled.fit.linearize`).  A moving contact leaves a linearisation's range within
milliseconds, and asking a fit worker for a new one costs a round trip (pickling, two context
switches, a worker that may be busy with another finger's fit): 1.5-4 ms at the median on a
loaded 2-core controller, during which the frames of that finger wait or are only predicted.
One linearisation costs about 50 us of CPU (one compiled evaluation of the strains and their
Jacobian on the window, and a 5x5 solve), so the daemon computes them itself, synchronously,
as the tracker needs them:

* **relinearising** where the state has moved (was a worker job of kind ``lin``);
* **iterating** on a frame that left the linear range (an iterated extended Kalman filter):
  linearise at the contact predicted to the frame's time, measure the frame there, and if it
  is still outside the range, once more at where that measurement put it.  A frame that
  passes the linearity test at either point is measured (answered now, by the same test as
  any tracked frame); one that does not (a jump, a new indentor, a contact the prediction
  does not reach) gets a fit of its own from a worker, as before.

Only linearisations run here, never a fit: each is one model evaluation at a point near a
contact the tracker already holds, so its cost is bounded (a frame far outside the model
costs a worker its time, not the loop).  The price is the fitter's code in this process
(numba's compiled kernels, loaded from its cache: about 0.7 s at start and 80-90 MB of
resident memory), paid only when a sensor tracks (the sensor setting ``track``).
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from tactiled.config import Geometry, SensorModel
from tactiled.fit.params import RADIUS_LIMITS

log = logging.getLogger(__name__)

#: Linearisations tried on a frame that left the linear range before it is sent to be fitted:
#: at the predicted contact, then at the measurement through that.
ITERATIONS = 2
#: Points the daemon does not linearise at (a filter that has run away): a force beyond this
#: (N), or a centre more than ``OFF_ARRAY_MM`` outside the array.  The model's cost grows with
#: the contact's size (one evaluation of an ellipse larger than the array takes tens of ms):
#: in the event loop only contacts a finger can carry are evaluated.
MAX_FORCE_N = 100.0
MIN_FORCE_N = 1e-4
OFF_ARRAY_MM = 5.0
#: ... nor at a radius beyond what the fitter's own search may reach (half and twice
#: ``RADIUS_LIMITS``): a filter whose curvature ran off (an edge too light for its radius)
LN_R_BOUNDS = (math.log(0.5 * RADIUS_LIMITS[0]), math.log(2.0 * RADIUS_LIMITS[1]))


def within_reason(p: np.ndarray, geometry: Geometry) -> np.ndarray:
    """``p`` (a model's internal vector: ``(ln_r..., ..., ln_f, x0, y0)``) with its radius,
    force and centre clipped to what a finger carries (see ``MAX_FORCE_N``, ``OFF_ARRAY_MM``,
    ``LN_R_BOUNDS``): where a linearisation or a fit may start."""
    q = np.array(p, dtype=float)
    q[0] = min(max(q[0], LN_R_BOUNDS[0]), LN_R_BOUNDS[1])
    q[-3] = min(max(q[-3], math.log(MIN_FORCE_N)), math.log(MAX_FORCE_N))
    g = geometry
    q[-2] = min(max(q[-2], -OFF_ARRAY_MM), (g.rows - 1) * g.dx + OFF_ARRAY_MM)
    q[-1] = min(max(q[-1], -OFF_ARRAY_MM), (g.cols - 1) * g.dy + OFF_ARRAY_MM)
    return q


_SHARED: dict[tuple[SensorModel, tuple[tuple[str, Any], ...]], LocalModel] = {}


class LocalModel:
    """Linearisations of one sensor's window model (its ``SensorModel`` and fit options, as
    the workers build their fitters), computed in this process."""

    def __init__(self, sensor: SensorModel, options: tuple[tuple[str, Any], ...]) -> None:
        from tactiled.fit.fitter import Fitter, FitOptions
        from tactiled.fit.linearize import linearize

        self.key = (sensor, options)
        self._fitter = Fitter(sensor, FitOptions(**dict(options)))
        self._geometry = sensor.geometry
        self._linearize = linearize
        #: linearisations computed, those that raised (a bug: counted, logged once), and
        #: points refused (outside what a finger carries)
        self.calls = 0
        self.errors = 0
        self.refused = 0
        #: linearisations :meth:`iterate` adopted, and those that gave none
        self.adopted = 0
        self.lost = 0
        self._warm_up(sensor)

    def _warm_up(self, sensor: SensorModel) -> None:
        """One linearisation now, so the first contact does not stall the loop while numba
        loads its kernels from the cache and the quadrature tables are built (~0.1-0.3 s)."""
        from tactiled.fit.models import get_model
        from tactiled.physics.contact import Contact
        from tactiled.physics.strain import StrainModel

        g = sensor.geometry
        c = Contact(10.0, math.inf, 60.0, 1.0, (g.rows - 1) * g.dx / 2, (g.cols - 1) * g.dy / 2)
        try:
            frame = StrainModel(sensor).predict(c)
            p = get_model("cylinder").from_values(c.r1, c.r2, c.psi_deg, c.force, c.x0, c.y0)
            self._linearize(self._fitter, frame, "cylinder", p, None)
        except Exception as err:  # noqa: BLE001 - a slower first contact, never a failure
            log.warning("warming up the daemon's linearisations failed: %s", err)

    @classmethod
    def shared(cls, sensor: SensorModel, options: tuple[tuple[str, Any], ...]) -> LocalModel:
        """One instance per sensor model and options in this process: sensors of one model
        share it, and only the first pays for building it (~0.5-2 s)."""
        key = (sensor, options)
        local = _SHARED.get(key)
        if local is None:
            if len(_SHARED) >= 16:  # settings changed many times: forget the oldest
                del _SHARED[next(iter(_SHARED))]
            local = _SHARED[key] = cls(sensor, options)
        return local

    def linearize(self, strain: np.ndarray, at: tuple[str, Any],
                  mask: np.ndarray | None = None):
        """The :class:`~tactiled.fit.linearize.Linearization` of the window on ``strain``
        (zeroed frame, (rows, cols)) at ``at = (model, internal parameters)``; None where there
        is none (no contact in the window, a point outside the model's domain, a parameter
        the window does not determine)."""
        p = np.asarray(at[1], dtype=float)
        if p.size < 4 or not np.array_equal(within_reason(p, self._geometry), p):
            self.refused += 1
            return None
        self.calls += 1
        try:
            return self._linearize(self._fitter, strain, at[0], p, mask)
        except Exception as err:  # a bug must cost this frame a worker fit, not the loop
            self.errors += 1
            if self.errors == 1:
                log.exception("linearisation in the daemon failed: %s", err)
            return None

    def iterate(self, tracker, strain: np.ndarray, t: float, mask: np.ndarray | None = None,
                zero_var: float = 0.0) -> bool:
        """Measure a frame that ``tracker`` could not measure through its linearisation (its
        :meth:`Tracker.step` said "refit": outside the linear range, or an apparent jump, which
        a linearisation far from a moving contact also gives) through one nearer to it: at the contact
        predicted for the frame's device time ``t`` (s) and, if that one does not measure it
        either, at where the frame puts the contact through it, provided that point lies
        within the jump test's reach of the prediction; :data:`ITERATIONS` points at most.
        The first linearisation that measures the frame is adopted and the frame measured:
        True (``tracker`` holds its estimate).  False: it needs a fit of its own (a jump, or a
        frame no linearisation near the prediction explains); the tracker then keeps the
        linearisation it had, unless the frame was measured and found to jump.
        ``strain``: the zeroed frame, (rows, cols); ``zero_var``: as for ``Tracker.adopt``."""
        at = tracker.predicted(t)
        f = strain.ravel()
        for _ in range(ITERATIONS):
            if at is None:
                return False
            lin = self.linearize(strain, at, mask)
            if lin is None or lin.model != tracker.model:
                self.lost += 1
                return False
            if tracker.measures(lin, f):
                tracker.adopt(lin, zero_var)
                self.adopted += 1
                return tracker.step(f, t) != "refit"  # "refit" now: measured, and a jump
            p = lin.p + lin.gain @ (f[lin.index] - lin.strain)
            if not tracker.within_reach(p, t):
                return False
            at = (lin.model, p)
        return False

"""The calibration stage's per-frame arithmetic, as compiled kernels: the core's
(core/calibrate.cpp, ``tactiled._core``) or, with ``TACTILED_CORE=python``, their reference
in NumPy (:mod:`tactiled.calibration.fused_reference`, which says what each does).  The two
take the same arguments and give the same bits (tests/native/test_calibrate_core.py).
"""

# * :func:`zero_frame`: raw counts -> linearised, zeroed, hysteresis-compensated strain and the
#   matched filter's statistic, in one pass;
# * :func:`follow_baseline`: the baseline's step towards an untouched frame;
# * :func:`average_maps`: the detector's running mean of its filter maps;
# * :func:`drift_error`, :func:`pull_baseline`: drift followed around a held contact;
# * :func:`learn_hysteresis`: a step of the hysteresis learner;
# * :class:`ZeroRun`: a read's frames through the whole stage in one call, until one in contact.
#
# Nothing is compiled at first use: the core is built by ``pip install``.

from __future__ import annotations

import numpy as np

from tactiled import native

if native.core is None:
    from tactiled.calibration.fused_reference import (  # noqa: F401  (re-exported)
        average_maps,
        drift_error,
        follow_baseline,
        learn_hysteresis,
        pull_baseline,
        ZeroRun,
        zero_frame,
    )
else:
    zero_frame = native.core.zero_frame
    average_maps = native.core.average_maps
    follow_baseline = native.core.follow_baseline
    drift_error = native.core.drift_error
    pull_baseline = native.core.pull_baseline
    learn_hysteresis = native.core.learn_hysteresis
    ZeroRun = native.core.ZeroRun


def filter_bands(ax: np.ndarray, ay_t: np.ndarray) -> np.ndarray:
    """``(4, max(U, V))`` int64: for each row ``u`` of ``Ax`` the first and one past the last
    column not zero (rows 0, 1), and likewise for each column ``v`` of ``Ay^T`` its rows
    (rows 2, 3): :func:`zero_frame` multiplies only there."""
    def span(nonzero: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lo = np.where(nonzero.any(axis=1), nonzero.argmax(axis=1), 0)
        hi = np.where(nonzero.any(axis=1), nonzero.shape[1] - nonzero[:, ::-1].argmax(axis=1), 0)
        return lo, hi

    out = np.zeros((4, max(ax.shape[0], ay_t.shape[1])), dtype=np.int64)
    out[0, :ax.shape[0]], out[1, :ax.shape[0]] = span(ax != 0.0)
    out[2, :ay_t.shape[1]], out[3, :ay_t.shape[1]] = span((ay_t != 0.0).T)
    return out

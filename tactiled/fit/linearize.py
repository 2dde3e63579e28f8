"""A fit's linearisation: what the temporal tracker needs to measure later frames without a fit."""

# Near a contact ``p`` the window's strains are ``s(p + dp) ~ s(p) + J dp``, so a later frame
# ``f`` of the same contact measures the parameters by one weighted least-squares step,
# ``p + G (f - s(p))`` with ``G = (J^T W J)^-1 J^T W``: a matrix-vector product, microseconds,
# where a fit costs hundreds.  Its noise covariance is ``sigma^2 G G^T`` (the single-frame
# Cramer-Rao bound when ``W`` is the noise's), and the part of ``f - s(p)`` that ``J dp`` does not
# explain says whether the frame still lies in the linear range (or a new fit is due).
#
# Computed in the fit worker, at a fit's solution or at a point the tracker asks for, and sent
# to the daemon's main process, which has no physics of its own.

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from tactiled.fit import compiled
from tactiled.fit.models import Model, get_model
from tactiled.fit.warm import SEVERAL
from tactiled.physics.contact import Contact


#: ``(A^-1)_ii A_ii`` beyond this (a variance inflated 1e12-fold by correlation): singular.
SINGULAR = 1e12
_ROWS = np.arange(64)


@dataclass(frozen=True)
class Linearization:
    """The window's strains around one contact of one model (internal parameters, see
    :mod:`tactiled.fit.params`).  Arrays are per usable window tactel, ``n`` of them, and per
    parameter, ``k``."""

    model: str
    #: the internal parameter vector it was taken at, (k,)
    p: np.ndarray
    #: flat (row-major) indices of the window's usable tactels in the frame, (n,)
    index: np.ndarray
    #: the model's strains there at ``p``, (n,)
    strain: np.ndarray
    #: d strain / d p, (n, k)
    jacobian: np.ndarray
    #: the least-squares step from a strain residual to a parameter change, (k, n)
    gain: np.ndarray
    #: 1 / variance of one frame's reading (noise and model-error floor), (n,), strain^-2
    weight: np.ndarray
    #: one frame's noise covariance of ``p + gain @ (f - strain)``, (k, k)
    cov: np.ndarray
    #: one frame's strain noise, 1 sigma
    sigma: float
    #: the covariance the finger's identified model-error floor (``SensorModel.model_error``,
    #: from its calibration) gives ``p + gain @ (f - strain)``, (k, k).  The same in every
    #: frame: averaging frames does not shrink it.  (The floor a fitter learns from single
    #: frames' residuals, :mod:`tactiled.fit.floor`, is not in it: part of what a frame shows
    #: does average away; the tracker measures what does not on the frames' mean residual.)
    systematic: np.ndarray
    #: the model's strains on the whole array at ``p`` (rows, cols), in the frames' units, or
    #: None (a contact too large to integrate): what the zeroer follows drift around
    #: (``Zeroer.follow_drift``)
    predicted: np.ndarray | None = None

    @property
    def dof(self) -> int:
        """Degrees of freedom of the linearity test (usable tactels minus parameters)."""
        return int(self.index.size - self.p.size)

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        """Pickled as two buffers (:func:`_pack`): a worker sends the daemon hundreds of
        linearisations a second, and unpickling costs per array, not per byte."""
        return _unpack_one, _pack((self,))


#: The float arrays of a Linearization packed into one buffer, in this order (then
#: ``predicted``, when there is one).
_PACKED = ("p", "strain", "jacobian", "gain", "weight", "cov", "systematic")


def _pack(lins: tuple[Linearization, ...]) -> tuple[Any, ...]:
    """``lins`` as ``(heads, floats, indices)``: per linearisation its model, sigma and its
    arrays' shapes; every float array of every one in one float64 buffer, every window's
    indices in one int64 buffer."""
    heads, floats, indices = [], [], []
    for lin in lins:
        arrays = [getattr(lin, name) for name in _PACKED]
        if lin.predicted is not None:
            arrays.append(lin.predicted)
        heads.append((lin.model, float(lin.sigma), tuple(a.shape for a in arrays)))
        floats.extend(np.asarray(a, dtype=np.float64).ravel() for a in arrays)
        indices.append(np.asarray(lin.index, dtype=np.int64))
    return tuple(heads), np.concatenate(floats), np.concatenate(indices)


def _unpack(heads: tuple[Any, ...], floats: np.ndarray,
            indices: np.ndarray) -> list[Linearization]:
    """The linearisations :func:`_pack` packed (arrays are views of the buffers,
    C-contiguous)."""
    lins, start, at = [], 0, 0
    for model, sigma, shapes in heads:
        arrays = []
        for shape in shapes:
            size = math.prod(shape)
            arrays.append(floats[start:start + size].reshape(shape))
            start += size
        fields = dict(zip(_PACKED, arrays))
        n = arrays[1].size  # (strain: one per window tactel)
        fields.update(model=model, sigma=sigma, index=indices[at:at + n],
                      predicted=arrays[len(_PACKED)] if len(arrays) > len(_PACKED) else None)
        at += n
        # (as pickle restores any object: the fields as they were, without the frozen
        # dataclass's __init__, which sets each through object.__setattr__)
        lin = object.__new__(Linearization)
        lin.__dict__.update(fields)
        lins.append(lin)
    return lins


def _unpack_one(heads: tuple[Any, ...], floats: np.ndarray, indices: np.ndarray) -> Linearization:
    return _unpack(heads, floats, indices)[0]


def _unpack_several(model: str, heads: tuple[Any, ...], floats: np.ndarray,
                    indices: np.ndarray) -> SeveralLinearizations:
    return SeveralLinearizations(tuple(_unpack(heads, floats, indices)), model)


def linearize(fitter, strain: np.ndarray, model: str, p: np.ndarray,
              mask: np.ndarray | None = None, whole: np.ndarray | None = None) -> Linearization | None:
    """The linearisation of ``fitter``'s window on ``strain`` at ``model``'s internal vector
    ``p``; None where there is none (no contact in the frame, too few tactels, a singular
    Jacobian, a point outside the model's domain).  ``whole``: :func:`whole_array` at ``p``,
    when the caller has it already."""
    fr = fitter._frame(fitter.flattened(strain), mask)
    m = get_model(model)
    p = np.asarray(p, dtype=float)
    if not hasattr(fr, "target") or fr.n_points <= m.size or p.shape != (m.size,):
        return None
    window = (fr.xs, fr.ys, fr.target, fr.valid, fr.inv_scale, fr.ex, fr.ey)
    status, r, jac = compiled.evaluate(compiled.KINDS[model], p, fitter._model_args, window,
                                       fitter.options.tol)
    if status == "invalid":  # an infinite line contact, or too long to integrate
        return None
    if status == "fallback":  # a contact too large for the compiled rules
        try:
            r, jac = fitter.model.window_residual_function(m.physical, *window)(p)
        except ValueError:
            return None
    inv = fr.inv_scale[fr.valid]
    s = fr.target[fr.valid] + r / inv
    js = jac / inv[:, None]
    sigma = fitter._sigma1
    # inv_scale = (1 / peak) (sigma / sd): each tactel's sd with the model-error floor
    sd = fitter.sigma / (fr.peak * inv)
    w = 1.0 / (sd * sd)
    jw = js.T * w
    a = jw @ js
    try:
        ainv = np.linalg.inv(a)
    except np.linalg.LinAlgError:
        return None
    # a parameter the window does not determine: a singular or NaN normal matrix, or a
    # variance inflated SINGULAR-fold by correlation (NaN fails both tests)
    q = np.diag(ainv) * np.diag(a)
    if not (bool((q > 0.0).all()) and bool((q < SINGULAR).all())):
        return None
    gain = ainv @ jw
    with np.errstate(over="ignore", invalid="ignore"):
        cov = (sigma * sigma) * (gain @ gain.T)
    if not (np.isfinite(gain).all() and np.isfinite(cov).all() and (np.diag(cov) > 0.0).all()):
        return None  # a parameter the window cannot resolve at all
    r0, c0, nr, nc = fr.win
    cols = fitter._all_ok.shape[1]
    index = ((r0 + _ROWS[:nr, None]) * cols + (c0 + _ROWS[None, :nc])).ravel()[fr.valid]
    me = fitter.sensor.model_error  # the floor's variance per tactel, as Fitter._tactel_sd's
    systematic = (gain * (me.strain ** 2 + (me.relative * s) ** 2)) @ gain.T
    flat = fitter.flat
    predicted = whole_array(fitter, m, p) if whole is None else whole
    if flat is not None and flat.active:
        # the flat field's corrections are as wrong in every frame: systematic; and the
        # tracker reads frames as they come, so the same linearisation in their units
        # (reading = tactel gain x what the fit reads)
        wc = flat.error_covariance(index, s / sd, js[:, -2] / sd, js[:, -1] / sd)
        systematic = systematic + gain @ (sd[:, None] * wc * sd[None, :]) @ gain.T
        g = flat.gain.ravel()[index]
        s, js, gain, w = s * g, js * g[:, None], gain / g, w / (g * g)
        cov = (sigma * sigma) * (gain @ gain.T)
        if predicted is not None:
            predicted = predicted * flat.gain
    return Linearization(model=model, p=p.copy(), index=np.ascontiguousarray(index),
                         strain=np.ascontiguousarray(s), jacobian=np.ascontiguousarray(js),
                         gain=np.ascontiguousarray(gain), weight=w, cov=cov, sigma=sigma,
                         systematic=systematic, predicted=predicted)


def whole_array(fitter, model: Model, p: np.ndarray) -> np.ndarray | None:
    """The strain ``model`` at internal vector ``p`` gives on ``fitter``'s whole array as its
    fits read frames (each tactel where the sensor puts it, displaced as the fitter's flat
    field has learnt; before the flat field's gains), or None for a contact too long to
    integrate."""
    (ka, kb, psi, force, x0, y0), _ = model.physical(p)
    flat = fitter.flat
    moved = (flat.dx, flat.dy) if flat is not None and flat.active else None
    try:
        contact = Contact(1.0 / ka, 1.0 / kb if kb > 0.0 else math.inf, math.degrees(psi), force,
                          x0, y0)
        return fitter.model.predict(contact, moved=moved)
    except (ValueError, ZeroDivisionError, OverflowError):
        return None


@dataclass(frozen=True)
class SeveralLinearizations:
    """The linearisations of several contacts of one frame, each taken on the frame less the
    others' predicted strain (:func:`tactiled.fit.multi.linearize_several`), in the order of
    the contacts they were asked for.  The temporal tracker measures each contact through its
    own (:class:`tactiled.pipeline.multi_contact.ContactTrackers`)."""

    lins: tuple[Linearization, ...]
    #: the tag of several contacts (``tactiled.fit.warm.SEVERAL``)
    model: str = SEVERAL

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        """Pickled as every contact's arrays in two buffers (:func:`_pack`)."""
        return _unpack_several, (self.model, *_pack(self.lins))

    @property
    def predicted(self) -> np.ndarray | None:
        """The contacts' strains on the whole array, summed (None if one has none)."""
        if any(lin.predicted is None for lin in self.lins):
            return None
        total = self.lins[0].predicted + 0.0
        for lin in self.lins[1:]:
            total += lin.predicted
        return total

    @property
    def index(self) -> np.ndarray:
        """Every tactel some contact's window measures (flat row-major indices)."""
        return np.unique(np.concatenate([lin.index for lin in self.lins]))

"""A linearisation crosses from a fit worker to the daemon pickled, its arrays packed into
two buffers: what arrives is what was sent."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from tactiled.fit.linearize import Linearization, SeveralLinearizations


def _lin(rng: np.random.Generator, n: int, k: int, lo: int, predicted: bool) -> Linearization:
    jacobian = np.asfortranarray(rng.normal(size=(n, k)))  # as a solver may leave it
    return Linearization(
        model="sphere" if k == 4 else "general", p=rng.normal(size=k),
        index=np.arange(lo, lo + n), strain=rng.normal(size=n), jacobian=jacobian,
        gain=np.linalg.pinv(jacobian), weight=rng.uniform(size=n), cov=np.eye(k) * 0.1,
        sigma=1e-3, systematic=rng.normal(size=(k, k)),
        predicted=rng.normal(size=(16, 16)) if predicted else None)


def _same(a: Linearization, b: Linearization) -> None:
    assert type(b) is Linearization
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert y.shape == x.shape and y.dtype == x.dtype and np.array_equal(x, y), f.name
            assert y.flags.c_contiguous, f.name
        else:
            assert x == y, f.name
    assert b.dof == a.dof


@pytest.mark.parametrize("predicted", [True, False])
def test_one_linearization_round_trips(predicted: bool) -> None:
    a = _lin(np.random.default_rng(1), 40, 4, 10, predicted)
    _same(a, pickle.loads(pickle.dumps(a, protocol=pickle.HIGHEST_PROTOCOL)))


def test_several_linearizations_round_trip_each_contact_whole() -> None:
    rng = np.random.default_rng(2)
    several = SeveralLinearizations((_lin(rng, 40, 4, 0, True), _lin(rng, 55, 6, 100, True),
                                     _lin(rng, 30, 4, 200, False)))
    back = pickle.loads(pickle.dumps(several))
    assert type(back) is SeveralLinearizations and back.model == several.model
    assert len(back.lins) == 3
    for a, b in zip(several.lins, back.lins):
        _same(a, b)
    # a replaced field (the tracker moves a psi by pi) leaves the packed original alone
    moved = dataclasses.replace(back.lins[0], p=back.lins[0].p + 1.0)
    assert np.array_equal(back.lins[0].p, several.lins[0].p)
    assert np.array_equal(moved.p, several.lins[0].p + 1.0)

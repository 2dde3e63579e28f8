"""A frame of several contacts computes each window, prepared frame and joint bound once
(tactiled.fit.linewindow.KeptFrames, tactiled.fit.multi.joint_bounds): the answers are those
of the same frames with every window computed afresh, and the bounds those of an independent
Fisher computation."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.fit.linewindow import KeptFrames
from tactiled.fit.models import get_model
from tactiled.fit.multi import fit_contacts, joint_bounds
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
from tactiled.sensors import load_description
from tactiled_bench import grasps


class _Afresh(KeptFrames):
    """Keeps nothing: every line window, point window and prepared frame computed again, as
    before they were kept (the reference path)."""

    def get(self, key: tuple, point: bool = False):
        return None

    @property
    def prepared(self):
        return None

    @prepared.setter
    def prepared(self, value) -> None:
        pass


def _fitter(name: str, afresh: bool = False) -> Fitter:
    desc = load_description(name)
    fitter = Fitter(desc.sensor_model(), FitOptions(window=desc.window))
    fitter.frozen = True
    if afresh:
        fitter.line.frames = _Afresh()
    return fitter


def _published(results) -> str:
    return json.dumps([{k: v for k, v in r.to_json_dict().items() if k != "fit_ms"}
                       for r in results], sort_keys=True)


@pytest.mark.parametrize("name", ["fearing1988", "flat16"])
def test_grasp_frames_publish_the_same_contacts_with_every_window_computed_afresh(name) -> None:
    """The contacts bench's grasps (tactiled_bench.grasps: lines, edges, balls, three
    contacts; a frame of each, seeded), fitted with the kept windows and without: every
    published key identical.  On the flat pad a candidate's ridge test and its fit read the
    same windows (kept); on the curved finger, a refitted general ellipse's simpler models
    (ModelSelector.simpler) read the square window its refit read."""
    desc = load_description(name)
    model = StrainModel(desc.sensor_model())
    drawn = [(grasp, frame) for grasp, _, truths, frame in
             grasps.frames_of(model, 1, np.random.default_rng(5)) if truths is not None]
    kept, afresh = _fitter(name), _fitter(name, afresh=True)
    hits = []
    real_get = KeptFrames.get

    def counting_get(self, key, point=False):
        fr = real_get(self, key, point)
        hits.append(fr is not None)
        return fr

    several = 0
    KeptFrames.get = counting_get
    try:
        for grasp, frame in drawn:
            got = fit_contacts(kept, frame, "auto")
            want = fit_contacts(afresh, frame, "auto")
            several += len(got) > 1
            assert _published(got) == _published(want), grasp
    finally:
        KeptFrames.get = real_get
    assert several >= len(drawn) // 2, several  # the frames hold several contacts
    assert any(hits), "no kept window reused"


def _fisher(model: StrainModel, contacts: list[tuple[str, np.ndarray]], tactels: np.ndarray,
            sigma: float) -> np.ndarray:
    """Fisher information of every contact's internal parameters by central differences of
    the physics (StrainModel.predict), independent of the compiled Jacobians."""
    cols = []
    for name, p in contacts:
        spec = get_model(name)

        def strain(q):
            (ka, kb, psi, force, x0, y0), _ = spec.physical(q)
            r1 = 1.0 / ka
            r2 = math.inf if kb == 0.0 else 1.0 / kb
            return model.predict(Contact(r1, r2, math.degrees(psi), force, x0, y0))

        for k in range(p.size):
            up, dn = p.copy(), p.copy()
            up[k] += 1e-5
            dn[k] -= 1e-5
            cols.append(((strain(up) - strain(dn)) / 2e-5)[tactels])
    j = np.array(cols).T / sigma
    return j.T @ j


def test_joint_and_alone_bounds_of_mixed_models_match_an_independent_fisher_computation() -> None:
    """A cylinder and a general ellipse on the paper's finger: each one's bound with the other
    unknown (joint) and known (alone) against the inverse of the finite-difference Fisher
    information and of its own block; values a model lacks are None in both."""
    desc = load_description("fearing1988")
    fitter = _fitter("fearing1988")
    model = StrainModel(desc.sensor_model())
    contacts = [("cylinder", get_model("cylinder").from_values(8.0, math.inf, 60.0, 1.0, 9.0, 12.0)),
                ("general", get_model("general").from_values(5.0, 12.0, 20.0, 0.8, 14.0, 15.0))]
    g = desc.sensor_model().geometry
    tactels = np.zeros((g.rows, g.cols), bool)
    tactels[1:8, 2:9] = True
    joint, alone = joint_bounds(fitter, [(m, tuple(p)) for m, p in contacts], tactels)
    info = _fisher(model, contacts, tactels, fitter.sigma)
    cov = np.linalg.inv(info)
    start = 0
    for i, (name, p) in enumerate(contacts):
        n = p.size
        block = slice(start, start + n)
        start += n
        _, grad = get_model(name).report(p)
        want_joint = np.einsum("ki,ij,kj->k", grad, cov[block, block], grad)
        want_alone = np.einsum("ki,ij,kj->k", grad, np.linalg.inv(info[block, block]), grad)
        for k, key in enumerate(("x_mm", "y_mm", "force_n", "r1_mm", "r2_mm", "angle_deg")):
            if not np.isfinite(want_joint[k]):
                assert joint[i][key] is None and alone[i][key] is None, (name, key)
                continue
            assert joint[i][key] == pytest.approx(math.sqrt(want_joint[k]), rel=1e-3), (name, key)
            assert alone[i][key] == pytest.approx(math.sqrt(want_alone[k]), rel=1e-3), (name, key)
            assert joint[i][key] >= alone[i][key] * (1 - 1e-9), (name, key)
    assert joint[0]["r2_mm"] is None  # a cylinder has no second radius

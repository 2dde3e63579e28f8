"""The slip detector on the simulator's scenes, estimated as the daemon estimates them (a fit
every 10th frame, the step from it on every frame): a pull on the PaXini module whose friction
turns kinetic at the onset is declared within 5 frames of it; a contact held at 0.95 mu P is
not; `tactiled fit` (a real process) on the 16x16 pad's pull that stays put at the friction's
limit raises the onset event where the frames' own state reads slip."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tactiled.fit.shear import ShearFitter
from tactiled.fit.slip import SlipDetector
from tactiled.sensors import load_description
from tactiled.sim.shear import sequence

FIT_EVERY = 10


def _onsets(desc, frames: np.ndarray, first: int, last: int) -> list[int]:
    """The frames on which an onset is declared along ``frames[first:last]``."""
    fitter, det, prev, step, out = ShearFitter(desc), SlipDetector(), None, None, []
    for i in range(first, last):
        if step is None or (i - first) % FIT_EVERY == 0:
            fit = fitter.fit(frames[i], start=prev)
            prev, step = fit.params, fitter.step(fit)
        _, _, ev = det.track(i, step, frames[i])
        if ev is not None and ev.kind == "onset":
            out.append(i)
    return out


def test_a_pull_on_the_paxini_module_is_declared_within_5_frames():
    """The friction turns kinetic at the onset (0.8 of the static): the tangential force falls
    by many of its bounds while the stick zone is gone; declared within 5 frames, once."""
    desc = load_description("paxini_px6ax")
    frames, truth = sequence(desc, "pull", np.random.default_rng(11))
    onset = int(truth["true_onset"])
    got = _onsets(desc, frames, onset - 50, onset + 12)
    assert len(got) == 1 and 0 <= got[0] - onset <= 5, (got, onset)


def test_a_hold_at_095_mu_p_on_the_paxini_module_is_no_slip():
    """A push to 0.95 mu P held 100 ms: its force levels off as a slip's does and its margin to
    slip comes near 0, but nothing moves; no onset along the whole scene."""
    desc = load_description("paxini_px6ax")
    frames, truth = sequence(desc, "push", np.random.default_rng(12), hold=0.95)
    loaded = int(np.argmax(np.hypot(truth["true_fx"], truth["true_fy"]) > 0))
    assert np.max(truth["true_lam"]) == pytest.approx(0.95)
    assert _onsets(desc, frames, max(0, loaded - 30), len(frames)) == []


@pytest.mark.slow  # 170 fits of the 16x16 pad (5 min on the shared 2-core machine)
def test_fit_raises_the_onset_event_on_the_pads_pull_at_the_limit(tmp_path: Path):
    """The pad's pull that stays put at the friction's limit (no motion, no drop): `tactiled
    fit` on its frames from half-way up the ramp raises one onset event, within 5 frames of the
    truth, from the margin to slip."""
    from tactiled_bench.shear import resolve

    desc = resolve("flat16_3axis")
    toml = tmp_path / "flat16_3axis.toml"
    toml.write_text(desc.to_toml())
    frames, truth = sequence(desc, "limit", np.random.default_rng(1))
    onset = int(truth["true_onset"])
    first = onset - 150
    part = frames[first:onset + 20]
    out = tmp_path / "limit.npz"
    np.savez(out, taxels=part, sensor=np.str_(str(toml)), sequence=np.zeros(len(part), np.int64),
             rate_hz=np.float64(1000.0))
    proc = subprocess.run([sys.executable, "-m", "tactiled.cli", "fit", str(out)], capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    lines = [json.loads(line) for line in proc.stdout.splitlines()]
    events = [(o["frame"] + first, o["slip"]["event"]) for o in lines if o.get("contact") and o["slip"]["event"]]
    assert len(events) == 1 and events[0][1] == "onset" and abs(events[0][0] - onset) <= 5, (events, onset)

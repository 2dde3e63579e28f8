"""The tracker inside the daemon: the ``temporal`` scene (a press held 3 s, a 3 mm roll, a
60 deg/s turn, a 20 % force step, a 0.5 mm jump, a release) played by the simulated finger
at 1 kHz through the real chain (wire bytes, decoder, table, zeroing with drift and
hysteresis, real worker processes), lossless so each run gives the same estimates.  The
finger is the ideal one (no drift, no hysteresis): what averaging can reach is then the
noise's business alone."""

from __future__ import annotations

import numpy as np
import pytest
from pipeline_helpers import accounted, check_estimates, collect, strict_json

from tactiled.pipeline import Daemon
from tactiled.settings import load_settings
from tactiled.sim import named_scene

RATE = 1000.0


@pytest.fixture(scope="module")
def run(request):
    import asyncio

    url = f"sim://?scene=temporal&seed=5&rate={RATE:g}&speed=0&loop=0&drift=0&hysteresis=0"
    overrides = {"sensor[0].url": url, "sensor[0].model": "cylinder"}

    async def main():
        daemon = Daemon(load_settings(None, {}, overrides), lossless=True)
        estimates = collect(daemon)
        await daemon.start()
        assert await daemon.wait_finished(240)
        st = daemon.stats("finger0")
        await daemon.stop()
        return estimates, st

    return asyncio.run(main())


def at(estimates, t0: float, t1: float) -> list:
    return [e for e in estimates if t0 <= e.device_time_us * 1e-6 < t1]


def test_every_frame_answered_in_order_with_the_tracker_keys(run) -> None:
    estimates, st = run
    check_estimates(estimates, "finger0", 0)
    assert st["frames"] == len(estimates) == accounted(st) and st["superseded"] == 0
    # from the end of the press to the release, nearly every frame is measured by the tracker
    # (the press and the release, where the contact changes fastest, take fits)
    middle = at(estimates, 1.2, 8.0)
    assert all(e.contact for e in middle)
    assert sum(e.gate == "fit" for e in middle) < 0.01 * len(middle)
    assert 0 < st["fitted"] < 0.05 * len(estimates)
    for e in estimates[::97]:
        d = e.to_json_dict()
        strict_json(d)
        assert {"frames_used", "vx_mm_s", "vy_mm_s", "angle_rate_deg_s",
                "force_rate_n_s"} <= d.keys() and "vx_mm_s" in d["std"]


def test_a_held_contact_sharpens(run) -> None:
    estimates, _ = run
    held = at(estimates, 1.2, 4.0)  # the hold, after the press settled
    used = [e.fit["frames_used"] for e in held]
    assert used == sorted(used) and used[-1] > 2500
    first, last = held[0].fit, held[-1].fit
    # ~600 -> ~3300 frames: sigma down by sqrt(5.4) but for the zeroing's own error (the zero
    # of each tactel is a mean of the idle frames), which the mean residual reveals and which
    # leaves ~0.035 mm; the single-frame bound here is 0.86 mm (test_contact_filter.py checks
    # 1/sqrt(frames) exactly).  Every 300 frames the sigma is smaller than before.
    sds = [e.fit["std"]["r1_mm"] for e in held[::300]]
    assert all(b < a for a, b in zip(sds, sds[1:])), sds
    assert last["std"]["r1_mm"] < first["std"]["r1_mm"] / 1.4 and last["std"]["r1_mm"] < 0.05
    assert abs(last["r1_mm"] - 10.0) < 3 * last["std"]["r1_mm"]
    assert abs(last["force_n"] - 1.2) < 0.02


def test_rolling_and_turning_are_tracked_with_their_rates(run) -> None:
    estimates, _ = run
    scene = named_scene("temporal")
    roll = at(estimates, 4.1, 4.9)  # 3 mm in 1 s, linear
    assert np.median([e.fit["vx_mm_s"] for e in roll]) == pytest.approx(3.0, rel=0.1)
    lag = [e.fit["x_mm"] - scene.contact_at(e.device_time_us * 1e-6).x0 for e in roll]
    assert abs(float(np.median(lag))) < 0.01  # mm: a fifth of a single frame's sigma
    turn = at(estimates, 5.6, 6.4)  # 60 -> 120 deg in 1 s
    assert np.median([e.fit["angle_rate_deg_s"] for e in turn]) == pytest.approx(60.0, rel=0.1)
    lag = [e.fit["angle_deg"] - scene.contact_at(e.device_time_us * 1e-6).psi_deg for e in turn]
    assert abs(float(np.median(lag))) < 0.3  # deg


def test_steps_show_within_two_frames(run) -> None:
    estimates, st = run
    by_t = {round(e.device_time_us * 1e-6, 3): e for e in estimates}
    # the 20 % force step at 7.0 s (1.2 -> 1.44 N) and the 0.5 mm jump along y at 7.501 s
    for t, key, before, after in ((7.0, "force_n", 1.2, 1.44), (7.501, "y_mm", None, None)):
        prior = by_t[round(t - 0.002, 3)].fit[key]
        if before is None:
            before, after = prior, prior + 0.5
        k = round(t * RATE)
        seen = [by_t[round((k + i) / RATE, 3)].fit for i in range(2)]
        assert any(abs(f[key] - after) < 0.2 * abs(after - before) for f in seen), (key, seen)
        assert any(f["frames_used"] <= 2 for f in seen)  # the accumulation restarted
    assert st["track_resets"] >= 2

"""`tactiled simulate` and `tactiled fit` on a 3-axis array, as a user runs them: subprocesses."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

TACTILED = [sys.executable, "-m", "tactiled.cli"]


def run(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    proc = subprocess.run([*TACTILED, *args], capture_output=True, text=True, timeout=300)
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


def test_random_frames_round_trip(tmp_path: Path):
    out = tmp_path / "xela.npz"
    run("simulate", str(out), "--sensor", "xela_uskin_4x4", "--frames", "4", "--seed", "2")
    data = np.load(out)
    assert data["taxels"].shape == (4, 4, 4, 3) and str(data["sensor"]) == "xela_uskin_4x4"
    lines = [json.loads(line) for line in run("fit", str(out)).stdout.splitlines()]
    assert [obj["frame"] for obj in lines] == [0, 1, 2, 3]
    for i, obj in enumerate(lines):
        assert obj["contact"] is True and obj["model"] == "sphere"
        sh = obj["shear"]
        assert {"fx_n", "fy_n", "torque_nmm", "q_over_p", "mu", "slip_margin", "std"} <= sh.keys()
        assert obj["slip"]["state"] in ("stick", "partial", "slip")
        assert abs(sh["fx_n"] - data["true_fx"][i]) < 5 * sh["std"]["fx_n"]
        assert abs(sh["fy_n"] - data["true_fy"][i]) < 5 * sh["std"]["fy_n"]
        if sh["mu"] is None:
            assert obj["reasons"]["mu"]


@pytest.mark.slow  # every frame of a whole pull fitted (~40 s); the default suite runs the short
# version below (the frames around the onset, against the daemon's path)
def test_pull_until_slip_declares_the_onset(tmp_path: Path):
    out = tmp_path / "pull.npz"
    run("simulate", str(out), "--sensor", "xela_uskin_4x4", "--load", "pull", "--seed", "7")
    onset = int(np.load(out)["true_onset"][0])
    lines = [json.loads(line) for line in run("fit", str(out)).stdout.splitlines()]
    events = [(o["frame"], o["slip"]["event"]) for o in lines if o.get("contact") and o["slip"]["event"]]
    assert events and events[0][1] == "onset"
    assert onset <= events[0][0] <= onset + 5
    assert all(o["slip"]["state"] == "slip" for o in lines[events[0][0]:])


def test_three_axis_file_with_a_one_axis_sensor_is_refused(tmp_path: Path):
    out = tmp_path / "xela.npz"
    run("simulate", str(out), "--sensor", "xela_uskin_4x4", "--frames", "1")
    proc = run("fit", str(out), "--sensor", "flat16", check=False)
    assert proc.returncode == 2 and "1-axis" in proc.stderr and proc.stdout == ""
    proc = run("fit", str(out), "--sensor", "xela_uskin_4x6", check=False)
    assert proc.returncode == 2 and "(N, 4, 6, 3)" in proc.stderr


def test_the_fit_commands_slip_is_the_daemons_on_a_recorded_pull(tmp_path: Path):
    """The last 50 frames of a pull before its true onset and 12 after, as a 3-axis frame file:
    `tactiled fit` (a real process) and the daemon's shear track (tactiled.pipeline.shear_track,
    every frame's fit awaited: no fit superseded) run the same path, the step from the newest
    fit into the slip detector; both declare the onset within 5 frames of the truth, a frame
    apart at most (the daemon's step comes from the previous frame's fit, the command's from
    the frame's own)."""
    import asyncio

    from tactiled.frames import Frame
    from tactiled.pipeline.shear_track import for_sensor
    from tactiled.sensors import load_description
    from tactiled.sim.shear import sequence

    desc = load_description("xela_uskin_4x4")
    rng = np.random.default_rng(3)
    scene, truth = sequence(desc, "pull", rng)
    onset = int(truth["true_onset"])
    first, last = onset - 50, onset + 12
    part = scene[first:last]
    out = tmp_path / "pull.npz"
    np.savez(out, taxels=part, sensor=np.str_("xela_uskin_4x4"), sequence=np.zeros(len(part), np.int64),
             rate_hz=np.float64(1000.0))
    lines = [json.loads(line) for line in run("fit", str(out)).stdout.splitlines()]
    assert len(lines) == len(part) and all(o["contact"] for o in lines)
    by_fit = [o["frame"] for o in lines if o["slip"]["event"] == "onset"]

    rest = np.array([0x8000, 0x8000, 10000.0])
    noise = np.array(desc.axis_noise)

    def frame(k: int, readings: np.ndarray) -> Frame:
        counts = np.round(readings + rest).astype(np.uint16)
        return Frame(seq=k, device_time_us=k * 1000, raw=counts[..., 2].copy(), sensor_id=1,
                     host_time=float(k), taxels=counts)

    async def daemon() -> list[int]:
        events: list = []
        track = for_sensor(desc, "xela", events.append)
        for k in range(60):  # at rest: the readings' zero (the frames' rounding to counts aside)
            track.on_frame(frame(k, rng.normal(size=part.shape[1:]) * noise), False)
        for k, readings in enumerate(part):
            track.on_frame(frame(60 + k, readings), True)
            while track._busy:  # every frame's fit awaited: a condition, not a sleep
                await asyncio.sleep(0.001)
        track.close()
        return [e.seq - 60 for e in events if e.event == "onset"]

    by_daemon = asyncio.run(daemon())
    assert len(by_fit) == 1 and len(by_daemon) == 1, (by_fit, by_daemon)
    assert 0 <= by_fit[0] - 50 <= 5 and 0 <= by_daemon[0] - 50 <= 5, (by_fit, by_daemon)
    assert abs(by_fit[0] - by_daemon[0]) <= 1, (by_fit, by_daemon)
    # the states the command reports follow the detector: slip from the onset on
    assert all(o["slip"]["state"] == "slip" for o in lines[by_fit[0]:])

"""Descriptions through the daemon, identification and the CLI: a flat pad simulated, fitted and
identified end to end; a bad description refused at start with the key it names."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from procs import PACE

from tactiled.calibration.identify import identify
from tactiled.calibration.presses import synthesize_contact_presses
from tactiled.errors import CalibrationError, ConfigError
from tactiled.sensors.finger import FingerSpec
from tactiled.pipeline import Daemon
from tactiled.sensors import load_description
from tactiled.settings import load_settings


def test_a_flat_pad_runs_through_the_daemon(arun, no_leftover_workers) -> None:
    # the demo scene on the flat 16x16 pad: its cylinders are lines, its sphere an ellipse
    url = "sim://?sensor=flat16&scene=demo&seed=2&rate=200&speed=0&loop=0"
    overrides = {"sensor[0].url": url, "sensor[0].description": "flat16", "fit.workers": 1}

    async def main():
        daemon = Daemon(load_settings(None, {}, overrides), lossless=True)
        seen: list[dict] = []
        daemon.hub.add_listener(lambda item: seen.append(item.fit) if item.kind == "estimate" else None)
        await daemon.start()
        assert await daemon.wait_finished(120 * PACE)
        st = daemon.stats("finger0")
        await daemon.stop()
        return seen, st

    fits, st = arun(main())
    assert st["errors"] == 0 and st["bad_shape"] == 0 and st["fit_errors"] == 0 and st["fit_failed"] == 0
    contact = [f for f in fits if f and f.get("contact")]
    assert len(contact) > 100
    lines = [f for f in contact if f.get("label") == "line"]
    assert lines, "the demo's cylinders on a flat pad are line contacts"
    for f in lines:
        assert f["force_n"] is None and "load per length" in f["reasons"]["force_n"]
        assert f["line"]["load_n_per_mm"] > 0


def test_a_bad_description_stops_the_daemon_before_it_starts(tmp_path) -> None:
    bad = tmp_path / "pad.toml"
    bad.write_text('name = "pad"\nrows = 4\ncols = 4\npitch_x_mm = 2\npitch_y_mm = 0\n')
    with pytest.raises(ConfigError, match=r"sensor\[0\]\.description.*key 'pitch_y_mm'"):
        load_settings(None, {}, {"sensor[0].description": str(bad)})
    cfg = tmp_path / "t.toml"
    cfg.write_text('[[sensor]]\ndescription = "pad.toml"\n')  # relative to the config file
    res = subprocess.run([sys.executable, "-m", "tactiled.cli", "run", "--config", str(cfg)],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert "pitch_y_mm" in res.stderr


def test_the_noise_comes_from_the_description_unless_the_sensor_sets_it() -> None:
    s = load_settings(None, {}, {"sensor[0].description": "robotiq_tsf85"})
    assert s.sensors[0].noise_sigma == load_description("robotiq_tsf85").noise_sigma
    s = load_settings(None, {}, {"sensor[0].description": "robotiq_tsf85", "sensor[0].noise_sigma": 0.002})
    assert s.sensors[0].noise_sigma == 0.002


def test_identification_on_a_flat_array_recovers_its_cover() -> None:
    base = load_description("xela_uskin_4x4").sensor_model()
    g = base.geometry
    truth = FingerSpec.of_sensor(base, depth_x=3.75, modulus=0.39, gain_error=0.05, seed=2)
    presses = synthesize_contact_presses(truth, 300, geometry=g, seed=3, noise_sigma=base.noise.sigma)
    res = identify(presses, g, nominal=base, nominal_name="the description's")
    got = res.model.constants()
    for k, true in (("depth_x", 3.75), ("modulus", 0.39), ("depth_y", 3.0), ("nu_x", 0.5)):
        assert abs(got[k] - true) < 4 * res.model.sigma[k] + 1e-9, (k, got[k], res.model.sigma[k])
    # a cylinder's force on a flat array is not defined: refused, with the reason
    presses.contacts[presses.contacts[:, 3] > 0, 1] = math.inf  # the same presses, as cylinders
    with pytest.raises(CalibrationError, match="spheres or ellipsoids"):
        identify(presses, g, nominal=base)


def test_fit_takes_a_description(tmp_path) -> None:
    from tactiled.physics.contact import LineContact
    from tactiled.physics.strain import StrainModel

    sensor = load_description("robotiq_tsf85").sensor_model()
    strain = StrainModel(sensor).predict(LineContact(6.0, 100.0, 0.2, 12.0, 6.0))
    frames = tmp_path / "f.npz"
    np.savez(frames, strain=np.stack([strain] * 3))
    res = subprocess.run([sys.executable, "-m", "tactiled.cli", "fit", str(frames), "--sensor",
                          "robotiq_tsf85"], capture_output=True, text=True, timeout=120 * PACE)
    assert res.returncode == 0, res.stderr
    import json

    line = json.loads(res.stdout.splitlines()[0])
    assert line["label"] == "line" and line["r1_mm"] == pytest.approx(6.0, rel=1e-3)
    wrong = subprocess.run([sys.executable, "-m", "tactiled.cli", "fit", str(frames), "--sensor", "flat16"],
                           capture_output=True, text=True, timeout=120 * PACE)
    assert wrong.returncode == 2 and "16x16" in wrong.stderr and "Traceback" not in wrong.stderr


def test_simulate_writes_a_flat_arrays_frames_and_fit_reads_its_description(tmp_path) -> None:
    import json

    out = tmp_path / "pad.npz"
    res = subprocess.run([sys.executable, "-m", "tactiled.cli", "simulate", str(out), "--sensor", "flat16",
                          "--r1", "8", "--angle", "30", "--force", "2", "--x", "18", "--y", "18",
                          "--frames", "6", "--seed", "3"], capture_output=True, text=True, timeout=120 * PACE)
    assert res.returncode == 0, res.stderr
    data = np.load(out)
    assert data["strain"].shape == (6, 16, 16) and str(data["sensor"]) == "flat16"
    fit = subprocess.run([sys.executable, "-m", "tactiled.cli", "fit", str(out)],
                         capture_output=True, text=True, timeout=120 * PACE)
    assert fit.returncode == 0, fit.stderr
    lines = [json.loads(x) for x in fit.stdout.splitlines()]
    for line, load in zip(lines, data["true_load_n_per_mm"]):
        assert line["label"] == "line" and line["force_n"] is None
        err = line["line"]["load_n_per_mm"] - load
        assert abs(err) < 4 * line["line"]["load_n_per_mm_std"]
        assert abs(line["angle_deg"] - 30.0) < 4 * line["std"]["angle_deg"]
    presses = tmp_path / "p.npz"
    res = subprocess.run([sys.executable, "-m", "tactiled.cli", "simulate", str(presses), "--sensor",
                          "xela_uskin_4x4", "--presses", "40"], capture_output=True, text=True, timeout=120 * PACE)
    assert res.returncode == 0 and np.load(presses)["counts"].shape == (40, 4, 4)
    # spheres and ellipsoids only: a cylinder's force on a flat array is not defined
    assert np.all(np.isfinite(np.load(presses)["contacts"][:, 1]))


def test_a_vendor_url_brings_its_arrays_description(arun) -> None:
    from tactiled.pipeline import Daemon

    s = load_settings(None, {}, {"sensor[0].url": "robotiq:///dev/ttyUSB0?finger=1"})
    assert s.sensors[0].description == "robotiq_tsf85"
    assert s.sensors[0].noise_sigma == load_description("robotiq_tsf85").noise_sigma
    # a 4x4 text-line array is no built-in: the default description (8x8) is refused at start
    s = load_settings(None, {}, {"sensor[0].url": "lines:///dev/null?rows=4&cols=4"})
    with pytest.raises(ConfigError, match="array is 4x4, but its description 'fearing1988' is 8x8"):
        Daemon(s)


def test_a_flat_pads_recording_replays_and_exports_with_its_description(tmp_path) -> None:
    import json

    rec = tmp_path / "pad.tact"
    res = subprocess.run([sys.executable, "-m", "tactiled.cli", "record",
                          "sim://?sensor=flat16&scene=press&rate=200&speed=0&loop=0", "-o", str(rec),
                          "--frames", "400"], capture_output=True, text=True, timeout=120 * PACE)
    assert res.returncode == 0, res.stderr
    out = subprocess.run([sys.executable, "-m", "tactiled.cli", "replay", str(rec), "--sensor", "flat16",
                          "--model", "cylinder"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    lines = [json.loads(x) for x in out.stdout.splitlines() if x.strip()]
    fits = [x for x in lines if x.get("contact")]
    assert fits and all(x["label"] == "line" and x["line"]["load_n_per_mm"] > 0 for x in fits
                        if x.get("converged"))
    # without the description the 16x16 frames are not the paper's 8x8: none is fitted
    wrong = subprocess.run([sys.executable, "-m", "tactiled.cli", "replay", str(rec)],
                           capture_output=True, text=True, timeout=300)
    assert not any(json.loads(x).get("contact") for x in wrong.stdout.splitlines() if x.strip())

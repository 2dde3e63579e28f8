"""``tactiled bench --suite sensors``: a short run through ``tactiled fit`` scores every kind of
contact on a flat array within loose bars (an ellipsoid's second radius too), a line's offset is
scored along its own reported normal, and a value counts as resolved by the reference bound's
rule."""

from __future__ import annotations

import math

import pytest

from tactiled_bench import sensors
from tactiled.physics.contact import LineContact
from tactiled.sensors import load_description


def test_a_line_offset_is_scored_along_the_normal_of_the_angle_it_reports() -> None:
    centre = (10.0, 10.0)
    line = LineContact(5.0, 0.5, 0.1, 10.0, 11.0)  # 1 mm off the centre, at 0.5 deg
    truth = line.offset_from(*centre)
    assert truth == pytest.approx(math.cos(math.radians(0.5)), rel=1e-9)
    # an estimate at 0.4 deg: the same normal, the same sign
    assert sensors._offset_err(truth + 0.01, 0.4, truth, 0.5) == pytest.approx(0.01)
    # the same line reported at 179.6 deg (angles are modulo 180): its normal is turned, and
    # the offset it reports has the other sign; the error is still 0.01 mm, not 2 mm
    assert sensors._offset_err(-truth - 0.01, 179.6, truth, 0.5) == pytest.approx(-0.01)
    # with no reported angle the offset is compared as it is
    assert sensors._offset_err(truth, None, truth, 0.5) == 0.0


def test_a_short_run_on_a_flat_array_is_near_the_bound() -> None:
    s = sensors.score_description(load_description("xela_uskin_4x4"), contacts=3, draws=8, seed=5)
    for kind in sensors.KINDS:
        names = [n for n in s.seen if n.startswith(f"{kind}/")]
        assert names, kind
    assert s.seen["ellipsoid/r2_mm"] == 3 * 8 and "ellipsoid/r2_mm" in s.z
    for name in s.z:
        rms = s.rms_over_crb(name)
        assert rms is not None and 0.3 < rms < 2.5, (name, rms)
        assert s.coverage(name) >= 0.6, name
        # a 4x4 pad: the reference window (6x6) is the whole pad, which the fit's window is too
        assert s.rms_over_crb(name, reference=True) == pytest.approx(rms, rel=1e-6), name
    assert sum(s.withheld.values()) <= 0.25 * sum(s.seen.values())
    assert s.withheld_resolved() <= 0.1
    # every frame's file line reports the one contact pressed
    assert s.contacts[1] == len(sensors.KINDS) * 3 * 8
    assert len(s.fit_ms) == len(s.auto_ms) == len(sensors.KINDS) * 3 * 8


def test_a_value_is_resolved_where_its_bound_leaves_it_two_bounds_from_zero() -> None:
    assert sensors.resolved_by("r1_mm", 10.0, 4.9) and not sensors.resolved_by("r1_mm", 10.0, 5.1)
    assert sensors.resolved_by("force_n", 1.0, 0.2) and not sensors.resolved_by("r2_mm", 30.0, 40.0)
    assert sensors.resolved_by("angle_deg", 30.0, 19.0) and not sensors.resolved_by("angle_deg", 30.0, 21.0)
    assert sensors.resolved_by("x_mm", 3.0, 50.0)
    # an ellipse's orientation only where its best circle lies two sigmas or more away
    assert sensors.resolved_by("angle_deg", 30.0, 19.0, circle_chi2=4.1)
    assert not sensors.resolved_by("angle_deg", 30.0, 19.0, circle_chi2=2.3)
    assert not sensors.resolved_by("angle_deg", 30.0, 21.0, circle_chi2=400.0)
    assert not sensors.resolved_by("x_mm", 3.0, None) and not sensors.resolved_by("r1_mm", 3.0, math.inf)


def test_the_bench_reads_what_tactiled_fit_writes_in_a_shell(tmp_path) -> None:
    """The bench's frames through ``tactiled fit`` in its process give the lines the command
    gives run as a user runs it (a process of its own), key for key but the fit's clock."""
    import json
    import subprocess
    import sys

    import numpy as np

    from tactiled_bench.fit_command import contacts_of, fit_lines
    from tactiled.io.framefile import save_frame_file
    from tactiled.physics.contact import Contact
    from tactiled.physics.strain import StrainModel

    desc = load_description("xela_uskin_4x6")
    sensor = desc.sensor_model()
    clean = StrainModel(sensor).predict(Contact(8.0, 8.0, 0.0, 1.5, 9.0, 11.0))
    rng = np.random.default_rng(3)
    frames = np.array([clean + rng.normal(0.0, sensor.noise.sigma, clean.shape) for _ in range(3)])
    lines, _ = fit_lines(frames, desc, "sphere")
    path = tmp_path / "frames.npz"
    save_frame_file(path, frames, desc.pitch_x_mm, desc.pitch_y_mm)
    run = subprocess.run([sys.executable, "-m", "tactiled.cli", "fit", str(path), "--sensor",
                          "xela_uskin_4x6", "--model", "sphere"], capture_output=True, text=True,
                         timeout=120, check=True)
    shell = [json.loads(t) for t in run.stdout.splitlines()]
    assert len(lines) == len(shell) == 3
    def timeless(line: dict) -> dict:
        out = {k: v for k, v in line.items() if k != "fit_ms"}
        if "contacts" in out:
            out["contacts"] = [timeless(c) for c in out["contacts"]]
        return out

    for a, b in zip(lines, shell):
        assert timeless(a) == timeless(b)
        assert len(contacts_of(a)) == 1 and abs(a["x_mm"] - 9.0) < 1.0

"""``tactiled presses``: a press file from a recorded session and the contacts pressed, run as a
user runs it (the console script on a real recording file).  The session is rendered here on a
flat 16x16 pad (any array, not the paper's finger): rest, then each press ramped, held and
lifted, every frame with its own count noise; the press file must hold, for each press, the
held counts to within what averaging 32 noisy frames leaves."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tactiled.calibration.presses import CONTACT_COLUMNS
from tactiled.io.presses import load_presses
from tactiled.frames import Frame, encode_frame
from tactiled.physics.contact import Contact
from tactiled.physics.strain import StrainModel
from tactiled.io.recording import RecordingWriter
from tactiled.sensors import load_description

TACTILED = Path(sys.executable).with_name("tactiled")
ZERO, GAIN, NOISE_COUNTS = 10000.0, 20000.0, 10.0  # counts at rest, per unit strain, 1 sigma
SENSOR_ID = 7


def contacts_pressed(n: int = 24, seed: int = 2) -> np.ndarray:
    """Spheres and ellipsoids (a cylinder on a flat pad is a line contact, whose total force is
    not defined) over the pad, every sixth row an unloaded sample."""
    g = load_description("flat16").geometry()
    rng = np.random.default_rng(seed)
    rows = []
    for k in range(n):
        if k % 6 == 5:
            rows.append((0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
            continue
        r1 = float(rng.choice([3.0, 6.0]))
        r2 = r1 if k % 2 else 3 * r1
        rows.append((r1, r2, float(rng.uniform(30, 150)), float(rng.uniform(0.5, 2.0)),
                     float(rng.uniform(0.2, 0.8) * g.span_x), float(rng.uniform(0.2, 0.8) * g.span_y)))
    return np.asarray(rows)


def record_session(path: Path, contacts: np.ndarray, seed: int = 3) -> np.ndarray:
    """Write the session as `tactiled record` would; return each row's noiseless held counts."""
    model = StrainModel(load_description("flat16").sensor_model())
    rng = np.random.default_rng(seed)
    held = np.zeros((len(contacts), 16, 16))
    frames: list[np.ndarray] = [np.zeros((16, 16))] * 60
    for k, (r1, r2, angle, force, x, y) in enumerate(contacts):
        if force > 0:
            strain = model.predict(Contact(r1, r2, angle, force, x, y))
            held[k] = ZERO + GAIN * strain
            frames += [strain * (i + 1) / 6 for i in range(6)] + [strain] * 60
            frames += [strain * (5 - i) / 6 for i in range(6)]
        else:
            held[k] = ZERO
        frames += [np.zeros((16, 16))] * 40
    with RecordingWriter(path, sensor_id=SENSOR_ID) as writer:
        for seq, strain in enumerate(frames):
            counts = np.rint(ZERO + GAIN * strain + rng.normal(0, NOISE_COUNTS, strain.shape))
            frame = Frame(seq=seq, device_time_us=seq * 1000, raw=counts.astype(np.uint16),
                          sensor_id=SENSOR_ID)
            writer.write(seq * 1e-3, encode_frame(frame))
    return held


def write_csv(path: Path, contacts: np.ndarray) -> Path:
    path.write_text("# pressed in this order\n" + ",".join(CONTACT_COLUMNS) + "\n" + "".join(
        ",".join(repr(float(v)) for v in row) + "\n" for row in contacts))
    return path


def presses(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(TACTILED), "presses", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=120)


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> tuple[Path, np.ndarray, np.ndarray]:
    where = tmp_path_factory.mktemp("session")
    contacts = contacts_pressed()
    held = record_session(where / "session.tact", contacts)
    return where, contacts, held


def test_each_press_is_its_held_counts_paired_with_its_contact(session) -> None:
    where, contacts, held = session
    write_csv(where / "pressed.csv", contacts)
    done = presses("session.tact", "--contacts", "pressed.csv", "-o", "presses.npz", cwd=where)
    assert done.returncode == 0, done.stderr
    assert "24 press(es) (20 loaded) of sensor 7, 16x16 tactels" in done.stdout
    got = load_presses(where / "presses.npz")
    assert got.sensor_id == SENSOR_ID and got.shape == (16, 16)
    np.testing.assert_array_equal(got.contacts, contacts)
    # the mean of 32 frames of 10-count noise, rounded: 5 standard errors and the rounding
    tolerance = 5 * NOISE_COUNTS / math.sqrt(32) + 0.5
    error = np.abs(got.counts.astype(float) - held)
    assert error.max() <= tolerance, (error.max(), tolerance)
    # the check can fail: the press before it (a neighbour's counts) is far off
    assert np.abs(got.counts[1:].astype(float) - held[:-1]).max() > 50 * tolerance


def test_a_press_too_many_or_too_few_is_refused_with_both_counts(session) -> None:
    where, contacts, _ = session
    extra = np.vstack([contacts, [[3.0, 3.0, 90.0, 1.0, 10.0, 10.0]]])
    write_csv(where / "extra.csv", extra)
    done = presses("session.tact", "--contacts", "extra.csv", "-o", "x.npz", cwd=where)
    assert done.returncode == 2
    assert done.stderr.splitlines() == [
        "tactiled presses: error: session.tact: the recording holds 20 press(es), but the "
        "contacts list 21 loaded one(s)"]
    assert not (where / "x.npz").exists()


def test_a_contacts_file_without_its_header_is_refused(session) -> None:
    where, contacts, _ = session
    (where / "bare.csv").write_text("3,3,90,1,10,10\n")
    done = presses("session.tact", "--contacts", "bare.csv", "-o", "y.npz", cwd=where)
    assert done.returncode == 2
    assert len(done.stderr.splitlines()) == 1
    assert "bare.csv: the first line must be r1_mm,r2_mm,angle_deg,force_n,x_mm,y_mm" in done.stderr

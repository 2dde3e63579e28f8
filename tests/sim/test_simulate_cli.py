"""``tactiled simulate``: the .npz file mode, and the device mode on a real pty."""

from __future__ import annotations

import os
import select
import signal
import time
from pathlib import Path

import numpy as np
import pytest
import serial
from procs import SimulatedDevice

from tactiled.cli import main
from tactiled.io.framefile import load_frame_file
from tactiled.frames import FrameDecoder


def test_npz_mode_still_works(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cyl.npz"
    assert main(["simulate", str(out), "--r1", "10", "--angle", "45", "--frames", "5",
                 "--seed", "2"]) == 0
    data = np.load(out)
    assert data["strain"].shape == (5, 8, 8)
    assert np.all(data["true_angle"] == 45.0) and float(data["noise_sigma"]) == 0.0003
    assert load_frame_file(out).strain.shape == (5, 8, 8)
    assert "wrote 5 frame(s)" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["simulate"], "give an output .npz file, or --pty / --serial"),
    (["simulate", "x.npz", "--pty"], "not both"),
    (["simulate", "x.npz", "--link", "L"], "--link needs --pty"),
    (["simulate", "--pty", "--scene", "nope"], "unknown scene 'nope'"),
    (["simulate", "--pty", "--rate", "0"], "--rate"),
    (["simulate", "--serial", "/nonexistent/ttyX"], "cannot open serial port /nonexistent/ttyX"),
])
def test_usage_errors(argv: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_pty_and_serial_are_exclusive(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["simulate", "--pty", "--serial", "/dev/null"])
    assert "not allowed with" in capsys.readouterr().err


def test_pty_device_streams_decodable_frames_and_stops_on_sigterm(tmp_path: Path) -> None:
    link = tmp_path / "tty"
    with SimulatedDevice("--pty", "--link", str(link), "--scene", "press", "--rate", "1000",
                         "--sensor-id", "4") as device:
        line = device.line(60.0)
        assert line.startswith("pty: /dev/pts/"), line
        slave = line.split(": ", 1)[1]
        assert os.path.realpath(link) == slave
        decoder = FrameDecoder()
        frames = []
        with serial.Serial(str(link), timeout=0.05) as port:
            deadline = time.monotonic() + 10.0
            while len(frames) < 200 and time.monotonic() < deadline:
                frames += decoder.feed(port.read(4096))
        assert len(frames) >= 200, decoder.stats
        assert {f.sensor_id for f in frames} == {4}
        assert all(f.raw.shape == (8, 8) for f in frames)
        seqs = [f.seq for f in frames]
        assert seqs == sorted(seqs)
        # Once reading, no frame is lost (the pty holds ~120 frames, far more than a read gap).
        assert seqs[-1] - seqs[10] == len(frames) - 11
        assert decoder.stats.crc_errors == 0
        rc = device.signal(signal.SIGTERM, 5.0)
        err = device.stderr()
        assert rc == 0, err
        assert "sent" in err and "dropped" in err
        assert not link.exists() and not link.is_symlink()  # removed on exit


def test_pty_device_survives_no_reader_and_reader_churn(tmp_path: Path) -> None:
    link = tmp_path / "tty"
    with SimulatedDevice("--pty", "--link", str(link), "--scene", "empty",
                         "--rate", "2000") as device:
        assert device.line(60.0).startswith("pty: ")
        time.sleep(0.5)  # nobody reading: the pty fills up, frames are dropped, no blocking
        for _ in range(2):  # a reader comes and goes
            decoder = FrameDecoder()
            with serial.Serial(str(link), timeout=0.05) as port:
                deadline = time.monotonic() + 10.0
                got = []
                while len(got) < 50 and time.monotonic() < deadline:
                    got += decoder.feed(port.read(4096))
            assert len(got) >= 50
        assert device.proc.poll() is None
        assert device.signal(signal.SIGINT, 5.0) == 0
        err = device.stderr()
        dropped = int(err.rsplit("dropped ", 1)[1].split()[0])
        assert dropped > 0


def test_serial_mode_writes_to_an_existing_pty(pty_device) -> None:
    # pty_device (tests/conftest.py): we read its master; the simulator writes to its slave.
    slave = os.path.realpath(pty_device.path)
    with SimulatedDevice("--serial", slave, "--scene", "press", "--rate", "500") as device:
        decoder = FrameDecoder()
        frames = []
        deadline = time.monotonic() + 60.0
        while len(frames) < 50 and time.monotonic() < deadline and device.proc.poll() is None:
            ready, _, _ = select.select([pty_device.master], [], [], 0.1)
            if not ready:
                continue
            try:
                frames += decoder.feed(os.read(pty_device.master, 4096))
            except OSError:  # EIO: the simulator has not opened the slave yet
                time.sleep(0.05)
        assert len(frames) >= 50, device.stderr()
        assert decoder.stats.crc_errors == 0
        assert device.signal(signal.SIGTERM, 5.0) == 0

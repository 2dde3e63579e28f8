"""Every command that reads or writes a file, on every way a file can be wrong: one line on
stderr naming the file and what is wrong, nothing on stdout, exit code 2, never a traceback
and never a numpy repr (``array(5)``, ``np.float64(nan)``) nor an invitation to unpickle.

The matrix runs through the command line's ``main()`` in this process (a traceback there is an
exception that fails the test); the two inputs a user first met as tracebacks also run as real
subprocesses.  (A file without read permission is not in the matrix when the tests run as
root, who may read it anyway.)"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tactiled.io.calibration import save_calibration
from tactiled.calibration.lut import LookupTable
from tactiled.cli import main
from tactiled.frames import Frame
from tactiled.io.recording import Recorder

#: What must never reach a user: numpy's reprs, pickle hints, a traceback.
LEAKS = re.compile(r"array\(|np\.[a-z_0-9]+\(|dtype\(|allow_pickle|Traceback|Error:")


def _inputs(tmp: Path) -> dict[str, tuple[Path, str]]:
    """name -> (a bad input file, words its message must hold), for any .npz reader."""
    out: dict[str, tuple[Path, str]] = {}

    def add(name: str, path: Path, words: str) -> None:
        out[name] = (path, words)

    add("missing", tmp / "absent.npz", "no such file")
    add("missing directory", tmp / "no-dir" / "x.npz", "no such file (no directory")
    (tmp / "folder.npz").mkdir()
    add("a directory", tmp / "folder.npz", "is a directory")
    np.save(tmp / "plain.npy", np.zeros((2, 8, 8)))
    os.replace(tmp / "plain.npy", tmp / "plain.npz")
    add("a .npy as .npz", tmp / "plain.npz", "a single .npy array")
    (tmp / "text.npz").write_text("strain = 1, 2, 3\n")
    add("text renamed .npz", tmp / "text.npz", "no zip archive signature")
    (tmp / "empty.npz").write_bytes(b"")
    add("empty", tmp / "empty.npz", "empty file")
    with open(tmp / "good.npz", "wb") as fh:
        np.savez(fh, strain=np.zeros((4, 8, 8)))
    good = (tmp / "good.npz").read_bytes()
    (tmp / "cut.npz").write_bytes(good[: len(good) // 2])
    add("truncated", tmp / "cut.npz", "truncated")
    flipped = bytearray(good)
    flipped[len(good) // 2] ^= 0xFF
    (tmp / "flipped.npz").write_bytes(bytes(flipped))
    add("corrupt", tmp / "flipped.npz", "is corrupt")
    with open(tmp / "pickled.npz", "wb") as fh:
        np.savez(fh, strain=np.array([{"a": 1}, None], dtype=object), counts=np.array([None]))
    add("pickled objects", tmp / "pickled.npz", "holds Python objects")
    with Recorder(tmp / "rec.npz", sensor_id=1):
        pass
    add("a recording", tmp / "rec.npz", "a tactiled recording")
    if os.geteuid() != 0:
        locked = tmp / "locked.npz"
        locked.write_bytes(good)
        locked.chmod(0)
        add("unreadable", locked, "permission denied")
    return out


def _save(path: Path, **arrays: np.ndarray) -> Path:
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    return path


def _frame_contents(tmp: Path) -> dict[str, tuple[Path, str]]:
    """Frame files that are .npz archives holding the wrong things."""
    nan = np.zeros((3, 8, 8))
    nan[1, 2, 3] = np.nan
    return {
        "no strain": (_save(tmp / "keys.npz", frames=np.zeros((2, 8, 8))), "missing array 'strain'"),
        "2-d strain": (_save(tmp / "flat.npz", strain=np.zeros((8, 8))), "got (8, 8)"),
        "no frames": (_save(tmp / "none.npz", strain=np.zeros((0, 8, 8))), "holds no frames"),
        "text strain": (_save(tmp / "str.npz", strain=np.array([["a"]])), "real numeric array"),
        "nan strain": (_save(tmp / "nan.npz", strain=nan), "frame 1 tactel [2, 3] (nan)"),
        "nan pitch": (_save(tmp / "dx.npz", strain=np.zeros((2, 8, 8)), dx=np.float64(np.nan)),
                      "positive number (tactel pitch in mm), got nan"),
        "array pitch": (_save(tmp / "dxa.npz", strain=np.zeros((2, 8, 8)), dx=np.ones(3)),
                        "got an array of shape (3,) (float64)"),
        "array noise": (_save(tmp / "ns.npz", strain=np.zeros((2, 8, 8)), noise_sigma=np.ones(3)),
                        "'noise_sigma' must be a single number"),
        "text noise": (_save(tmp / "nt.npz", strain=np.zeros((2, 8, 8)),
                             noise_quantum=np.array("x")), "got 'x'"),
        "nan noise": (_save(tmp / "nn.npz", strain=np.zeros((2, 8, 8)),
                            noise_sigma=np.float64(np.nan)), "non-negative number"),
    }


def _press_contents(tmp: Path) -> dict[str, tuple[Path, str]]:
    counts = np.full((30, 8, 8), 10000, np.uint16)
    ref = np.zeros((30, 8, 8))
    bad_ref = ref.copy()
    bad_ref[4, 1, 1] = np.inf
    return {
        "no counts": (_save(tmp / "p-keys.npz", strain_ref=ref), "missing array 'counts'"),
        "no reference": (_save(tmp / "p-ref.npz", counts=counts), "missing array 'strain_ref'"),
        "shape mismatch": (_save(tmp / "p-shape.npz", counts=counts, strain_ref=ref[:, :4]),
                           "does not match 'counts' shape"),
        "inf reference": (_save(tmp / "p-inf.npz", counts=counts, strain_ref=bad_ref),
                          "not finite at press 4, tactel [1, 1]"),
        "float counts": (_save(tmp / "p-float.npz", counts=counts.astype(float), strain_ref=ref),
                         "must be integers"),
        "sensor id array": (_save(tmp / "p-sid.npz", counts=counts, strain_ref=ref,
                                  sensor_id=np.array([5, 6])),
                            "got an array of shape (2,) (int64)"),
        "sensor id text": (_save(tmp / "p-sidt.npz", counts=counts, strain_ref=ref,
                                 sensor_id=np.array("five")), "got 'five'"),
    }


def _run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    rc = main(list(args))
    got = capsys.readouterr()
    return rc, got.out, got.err


def _check(result: tuple[int, str, str], command: str, path: Path, words: str) -> str:
    rc, out, err = result
    lines = err.strip().splitlines()
    assert rc == 2 and out == "" and len(lines) == 1, (command, path, result)
    line = lines[0]
    assert line.startswith(f"tactiled {command}: error: "), line
    assert str(path) in line and words in line.replace(str(path), ""), (words, line)
    assert not LEAKS.search(line), line
    return line


def test_frame_and_press_readers_refuse_every_bad_file(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out.json"
    lines = []
    for name, (path, words) in _inputs(tmp_path).items():
        lines.append(_check(_run(capsys, "fit", str(path)), "fit", path, words))
        lines.append(_check(_run(capsys, "calibrate", str(path), "-o", str(out)), "calibrate",
                            path, words))
        lines.append(_check(_run(capsys, "calibrate", str(path), "-o", str(out), "--identify"),
                            "calibrate", path, words))
    for name, (path, words) in _frame_contents(tmp_path).items():
        lines.append(_check(_run(capsys, "fit", str(path)), "fit", path, words))
    for name, (path, words) in _press_contents(tmp_path).items():
        lines.append(_check(_run(capsys, "calibrate", str(path), "-o", str(out)), "calibrate",
                            path, words))
    assert not out.exists()
    assert len(lines) >= 40


def test_raw_counts_with_a_calibration_of_another_sensor(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    cal = save_calibration(LookupTable.linear(8, 8, sensor_id=3), tmp_path / "cal.json")
    frames = _save(tmp_path / "raw.npz", counts=np.full((2, 8, 8), 10000, np.uint16),
                   sensor_id=np.array(5))
    line = _check(_run(capsys, "fit", str(frames), "--calibration", str(cal)), "fit", frames,
                  "'sensor_id' is 5, but the calibration is for sensor 3")
    assert "array(5)" not in line


def test_calibration_files_read_by_fit_and_replay(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    frames = _save(tmp_path / "frames.npz", strain=np.zeros((2, 8, 8)))
    recording = tmp_path / "r.tact"
    with Recorder(recording, sensor_id=0):
        pass
    (tmp_path / "dir.json").mkdir()
    (tmp_path / "bin.json").write_bytes(b"\xff\xfe\x00garbage")
    (tmp_path / "text.json").write_text("hello")
    cases = {
        tmp_path / "absent.json": "no such file",
        tmp_path / "dir.json": "is a directory",
        tmp_path / "bin.json": "not UTF-8 text",
        tmp_path / "text.json": "not valid JSON",
        frames: "not UTF-8 text",
    }
    for path, words in cases.items():
        _check(_run(capsys, "fit", str(frames), "--calibration", str(path)), "fit", path, words)
        _check(_run(capsys, "replay", str(recording), "--calibration", str(path), "--no-timing"),
               "replay", path, words)


def test_recordings_read_by_replay(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = _inputs(tmp_path)
    frames = _save(tmp_path / "frames.npz", strain=np.zeros((2, 8, 8)))
    cases = {bad[k][0]: bad[k][1] for k in ("missing", "missing directory", "a directory")}
    cases[bad["text renamed .npz"][0]] = "not a tactiled recording"
    cases[bad["empty"][0]] = "header truncated"
    cases[frames] = "an .npz file (tactiled fit reads frame files)"
    for path, words in cases.items():
        _check(_run(capsys, "replay", str(path), "--no-timing"), "replay", path, words)
        _check(_run(capsys, "export", str(path), "-o", str(tmp_path / "out.npz")), "export",
               path, words)
    assert not (tmp_path / "out.npz").exists()


def test_every_output_in_a_directory_that_does_not_exist(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    presses = tmp_path / "presses.npz"
    assert _run(capsys, "simulate", str(presses), "--presses", "30")[0] == 0
    recording = tmp_path / "r.tact"
    with Recorder(recording, sensor_id=0) as rec:
        rec.record(Frame(seq=0, device_time_us=0, raw=np.zeros((8, 8), np.uint16)), 1.0)
    (tmp_path / "taken").mkdir()
    for target, words in ((tmp_path / "no-dir" / "out", "cannot write it: no directory"),
                          (tmp_path / "taken", "is a directory")):
        npz, js, tact, png = (Path(f"{target}{ext}") if target.name == "out" else target
                              for ext in (".npz", ".json", ".tact", ".png"))
        commands = {
            "simulate": (["simulate", str(npz), "--frames", "2"], npz),
            "simulate --presses": (["simulate", str(npz), "--presses", "30"], npz),
            "calibrate": (["calibrate", str(presses), "-o", str(js)], js),
            "calibrate --identify": (["calibrate", str(presses), "-o", str(js), "--identify"], js),
            "record": (["record", "sim://?scene=press", "-o", str(tact), "--frames", "2"], tact),
            "simulate --pty --link": (["simulate", "--pty", "--link", str(tact)], tact),
            "export": (["export", str(recording), "-o", str(npz)], npz),
            "bench --plot": (["bench", "--quick", "--suite", "configs", "--plot", str(png)], png),
        }
        for name, (args, path) in commands.items():
            _check(_run(capsys, *args), args[0], path, words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["presses.npz", "r.tact", "taken"]


@pytest.mark.parametrize("args", [["fit", "{tmp}/plain.npy"],
                                  ["simulate", "{tmp}/nonexistent/dir/x.npz"]])
def test_the_first_two_tracebacks_are_one_line_now(tmp_path: Path, args: list[str]) -> None:
    np.save(tmp_path / "plain.npy", np.zeros((2, 8, 8)))
    argv = [a.format(tmp=tmp_path) for a in args]
    proc = subprocess.run([sys.executable, "-m", "tactiled.cli", *argv], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2 and proc.stdout == "", proc
    assert len(proc.stderr.splitlines()) == 1 and argv[1] in proc.stderr, proc.stderr
    assert not LEAKS.search(proc.stderr), proc.stderr


def test_the_daemon_refuses_its_files_at_start(tmp_path: Path) -> None:
    """``tactiled run``: a configuration file that is a directory, and a recording path in a
    directory that does not exist, refused at start (before it serves), one line, exit 2."""
    config = tmp_path / "rec.toml"
    config.write_text('[record]\npath = "no-dir/{sensor}.tact"\n\n[[sensor]]\nurl = "sim://"\n')
    cases = {"config": (["--config", str(tmp_path)], str(tmp_path), "is a directory"),
             "record": (["--config", str(config), "--port", "0"], "record.path: ",
                        "cannot write it: no directory")}
    procs = {name: subprocess.Popen([sys.executable, "-m", "tactiled.cli", "run", *args],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for name, (args, _, _) in cases.items()}
    for name, p in procs.items():
        out, err = p.communicate(timeout=60)
        _, names, words = cases[name]
        lines = err.strip().splitlines()
        assert p.returncode == 2 and out == "" and len(lines) == 1, (name, out, err)
        assert lines[0].startswith("tactiled run: error: ") and names in lines[0], lines[0]
        assert words in lines[0] and not LEAKS.search(lines[0]), lines[0]


def test_identification_presses_that_contradict_the_array(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    good = tmp_path / "presses.npz"
    assert _run(capsys, "simulate", str(good), "--presses", "40", "--seed", "2")[0] == 0
    arrays = dict(np.load(good))
    nan = arrays["contacts"].copy()
    nan[5, 0] = np.nan
    cases = {
        _save(tmp_path / "nan.npz", **{**arrays, "contacts": nan}): "press 5: r1_mm must be finite, got nan",
        _save(tmp_path / "cols.npz", **{**arrays, "contacts": nan[:, :5]}): "got shape (40, 5)",
        _save(tmp_path / "few.npz", **{k: v[:8] if v.ndim else v for k, v in arrays.items()}):
            "identification needs at least 20",
        _save(tmp_path / "sid.npz", **{**arrays, "sensor_id": np.float64(3.5)}): "got 3.5",
    }
    for path, words in cases.items():
        _check(_run(capsys, "calibrate", str(path), "-o", str(tmp_path / "cal.json"), "--identify"),
               "calibrate", path, words)
    assert not (tmp_path / "cal.json").exists()

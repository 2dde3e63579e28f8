"""Configuration, calibration and recording files that are truncated, of the wrong version or
with non-monotone tables: refused at start, before any worker process starts, with a message
naming the problem (in process: ``load_settings`` / ``Daemon``; at the process edge: the
``tactiled replay`` and ``tactiled record`` commands run as subprocesses, one error line and
exit code 2)."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from rel_helpers import figures, scene_frames

from tactiled.io.calibration import save_calibration
from tactiled.calibration.lut import LookupTable
from tactiled.errors import ConfigError
from tactiled.pipeline import Daemon
from tactiled.pipeline import supervision
from tactiled.io.recording import HEADER_SIZE, RECORD_HEADER_SIZE, Recorder
from tactiled.settings import load_settings

SENSOR_ID = 3


# --------------------------------------------------------------------------------------------
# The files


def _good_calibration(tmp: Path) -> Path:
    return save_calibration(LookupTable.linear(8, 8, sensor_id=SENSOR_ID), tmp / "good.json")


def _bad_calibrations(tmp: Path) -> dict[str, tuple[Path, str]]:
    """name -> (file, words the error must contain)."""
    text = _good_calibration(tmp).read_text()
    doc = json.loads(text)
    out: dict[str, tuple[Path, str]] = {}

    def write(name: str, content: str, expect: str) -> None:
        path = tmp / f"{name}.json"
        path.write_text(content)
        out[name] = (path, expect)

    def edited(edit) -> str:
        d = json.loads(text)
        edit(d)
        return json.dumps(d)

    write("truncated", text[: len(text) // 2], "truncated")
    write("truncated_at_end", text.rstrip()[:-2], "truncated")
    write("empty", "", "not valid JSON")
    write("version_3", edited(lambda d: d.update(version=3)), "this tactiled reads versions")
    write("version_2_without_model", edited(lambda d: d.update(version=2)),
          "missing key 'model' (version 2)")
    write("not_a_calibration", edited(lambda d: d.update(format="something-else")), "format")
    write("counts_not_increasing",
          edited(lambda d: d["tactels"][9].update(counts=d["tactels"][9]["counts"][::-1])),
          "strictly increasing")
    write("strain_decreasing",
          edited(lambda d: d["tactels"][10].update(strain=d["tactels"][10]["strain"][::-1])),
          "non-decreasing")
    def reshape(d: dict) -> None:
        d.update(rows=4, cols=16)
        for t in d["tactels"]:
            del t["index"]

    write("wrong_shape", edited(reshape), "table shape (4, 16) is not the sensor's (8, 8)")
    write("missing_tactels", edited(lambda d: d["tactels"].pop()), "tactels")
    assert doc["version"] == 1
    return out


def _recording(tmp: Path, name: str = "good.tact", frames: int = 40) -> Path:
    path = tmp / name
    with Recorder(path, sensor_id=SENSOR_ID) as rec:
        for k, frame in enumerate(scene_frames(frames, scene="press", rate_hz=50,
                                               sensor_id=SENSOR_ID)):
            rec.record(frame, host_time=10.0 + 0.02 * k)
    return path


def _bad_recordings(tmp: Path, good_path: Path) -> dict[str, tuple[Path, str]]:
    good = good_path.read_bytes()
    out: dict[str, tuple[Path, str]] = {}

    def write(name: str, data: bytes, expect: str) -> None:
        path = tmp / f"{name}.tact"
        path.write_bytes(data)
        out[name] = (path, expect)

    write("header_truncated", good[:20], "header truncated")
    write("empty", b"", "header truncated")
    write("bad_magic", b"XXXXREC\x00" + good[8:], "not a tactiled recording")
    v2 = bytearray(good)
    struct.pack_into("<H", v2, 8, 2)
    write("version_2", bytes(v2), "version 2 is not supported")
    return out


def _corrupt_mid_file(tmp: Path) -> tuple[Path, int]:
    """A recording whose 11th record has length 0 (corrupt in the middle, not at the end)."""
    data = bytearray(_recording(tmp, "mid.tact").read_bytes())
    offset = HEADER_SIZE
    for _ in range(10):
        _, length = struct.unpack_from("<dI", data, offset)
        offset += RECORD_HEADER_SIZE + length
    struct.pack_into("<I", data, offset + 8, 0)
    path = tmp / "corrupt_mid.tact"
    path.write_bytes(bytes(data))
    return path, offset


# --------------------------------------------------------------------------------------------
# In process: load_settings and Daemon refuse before anything starts


def test_truncated_and_invalid_config_files_are_refused(tmp_path: Path) -> None:
    good = tmp_path / "good.toml"
    good.write_text(f'[fit]\ntimeout = 0.5\n\n[[sensor]]\nname = "thumb"\n'
                    f'url = "sim://?scene=press"\ncalibration = "{_good_calibration(tmp_path)}"\n')
    load_settings(good)
    text = good.read_text()
    cases = {
        "truncated mid-table": (text[: text.index("url") + 8], "not valid TOML"),
        "truncated mid-key": (text[:7], "not valid TOML"),
        "wrong type": (text.replace("0.5", '"fast"'), "fit.timeout"),
        "unknown section": ("[fits]\ntimeout = 1\n", "fits: unknown section"),
        "missing calibration": (text.replace("good.json", "absent.json"),
                                "sensor[0].calibration: no such file"),
        "binary garbage": ("\x00\x01\x02[[[", "not valid TOML"),
    }
    messages = {}
    for name, (content, expect) in cases.items():
        path = tmp_path / "bad.toml"
        path.write_text(content)
        with pytest.raises(ConfigError) as info:
            load_settings(path)
        assert expect in str(info.value), (name, str(info.value))
        messages[name] = str(info.value)
    figures("config_files_refused", messages=messages)


def test_bad_calibration_files_are_refused_before_any_worker_starts(tmp_path: Path) -> None:
    spawned = len(supervision.SPAWNED_PIDS)
    messages = {}
    for name, (path, expect) in _bad_calibrations(tmp_path).items():
        settings = load_settings(None, {}, {"sensor[0].url": "sim://?scene=press",
                                            "sensor[0].calibration": str(path)})
        with pytest.raises(ConfigError) as info:
            Daemon(settings)
        message = str(info.value)
        assert message.startswith("sensor[0].calibration: "), message
        assert path.name in message and expect in message.replace(str(path), ""), (name, message)
        messages[name] = message
    # A calibration of another sensor than the configured wire id.
    settings = load_settings(None, {}, {"sensor[0].url": "sim://?scene=press",
                                        "sensor[0].wire_id": SENSOR_ID + 1,
                                        "sensor[0].calibration": str(tmp_path / "good.json")})
    with pytest.raises(ConfigError, match=f"calibration of sensor {SENSOR_ID}"):
        Daemon(settings)
    assert len(supervision.SPAWNED_PIDS) == spawned, "a worker started for a refused config"
    figures("calibration_files_refused", messages=messages)


# --------------------------------------------------------------------------------------------
# At the process edge: tactiled replay / tactiled record as subprocesses


def _run_all(commands: dict[str, list[str]], parallel: int = 4) -> dict[str, tuple]:
    """Run ``tactiled ARGS...`` for each entry, a few at a time; name -> (rc, stdout, stderr)."""
    results: dict[str, tuple] = {}
    items = list(commands.items())
    for start in range(0, len(items), parallel):
        procs = {name: subprocess.Popen([sys.executable, "-m", "tactiled.cli", *args],
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True)
                 for name, args in items[start:start + parallel]}
        for name, p in procs.items():
            out, err = p.communicate(timeout=120)
            results[name] = (p.returncode, out, err)
    return results


def _one_error_line(result: tuple, expect: str, *words: str) -> str:
    rc, out, err = result
    lines = err.strip().splitlines()
    assert rc == 2, result
    assert out == "", "estimates were printed before the refusal"
    assert len(lines) == 1, lines
    assert all(w in lines[0] for w in words), lines[0]
    assert expect in lines[0].replace(words[-1], ""), lines[0]  # not just in the file name
    return lines[0]


def test_replay_and_record_commands_refuse_bad_files(tmp_path: Path) -> None:
    recording = _recording(tmp_path)
    calibrations = _bad_calibrations(tmp_path)
    recordings = _bad_recordings(tmp_path, recording)
    other_sensor = tmp_path / "other_sensor.tact"
    with Recorder(other_sensor, sensor_id=SENSOR_ID + 1) as rec:
        rec.record(scene_frames(1, sensor_id=SENSOR_ID + 1)[0], host_time=1.0)
    commands = {f"replay --calibration {name}": ["replay", str(recording), "--calibration",
                                                 str(path), "--no-timing"]
                for name, (path, _) in calibrations.items()}
    commands |= {f"replay {name}": ["replay", str(path), "--no-timing"]
                 for name, (path, _) in recordings.items()}
    commands |= {f"record --append {name}": ["record", f"replay://{recording}?speed=0", "-o",
                                             str(path), "--append"]
                 for name, (path, _) in recordings.items() if name in ("version_2", "bad_magic")}
    commands["record --append other sensor"] = ["record", f"replay://{recording}?speed=0",
                                                "-o", str(other_sensor), "--append"]
    commands["replay good (control)"] = ["replay", str(recording), "--no-timing"]
    results = _run_all(commands)

    messages = {}
    for name, (path, expect) in calibrations.items():
        key = f"replay --calibration {name}"
        messages[key] = _one_error_line(results[key], expect, "tactiled replay: error:",
                                        "sensor[0].calibration", str(path))
    for name, (path, expect) in recordings.items():
        key = f"replay {name}"
        messages[key] = _one_error_line(results[key], expect, "tactiled replay: error:",
                                        str(path))
    for name in ("version_2", "bad_magic"):
        key = f"record --append {name}"
        messages[key] = _one_error_line(results[key], recordings[name][1],
                                        "tactiled record: error:")
    key = "record --append other sensor"
    messages[key] = _one_error_line(results[key], f"recording is of sensor {SENSOR_ID + 1}",
                                    "tactiled record: error:")
    rc, out, err = results["replay good (control)"]
    assert rc == 0 and len(out.splitlines()) == 40, err
    figures("bad_files_refused_by_the_commands", messages=messages)


def test_replay_of_a_recording_cut_short_replays_the_complete_records(tmp_path: Path) -> None:
    """A truncated *last* record is not an error (the recorder was killed): documented in
    docs/reference/file-formats.md; the complete records are replayed and the truncation is reported."""
    data = _recording(tmp_path).read_bytes()
    cut = tmp_path / "cut.tact"
    cut.write_bytes(data[:-50])
    rc, out, err = _run_all({"cut": ["replay", str(cut), "--no-timing"]})["cut"]
    assert rc == 0, err
    assert len(out.splitlines()) == 39
    assert "truncated last record" in err and "39 complete records" in err


def test_replay_refuses_a_recording_corrupt_in_the_middle(tmp_path: Path) -> None:
    path, offset = _corrupt_mid_file(tmp_path)
    result = _run_all({"mid": ["replay", str(path), "--no-timing"]})["mid"]
    figures("replay_corrupt_mid_file", rc=result[0], lines=len(result[1].splitlines()),
            stderr=result[2].strip())
    _one_error_line(result, f"corrupt record at byte {offset}", "tactiled replay: error:")

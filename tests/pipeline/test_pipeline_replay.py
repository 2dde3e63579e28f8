"""`tactiled record` and `tactiled replay`: a round trip, and replays that repeat exactly."""

from __future__ import annotations

import json
from pathlib import Path

from pipeline_helpers import contact_path, make_frames, np_frames_equal, write_recording

from tactiled.cli import main as cli
from tactiled.pipeline import without_timing
from tactiled.frames import decode_frame
from tactiled.io.recording import read_recording


def scene_frames():
    """Press, hold still (so the gate reuses fits), roll, release: every gate decision."""
    held = contact_path(30, moving=False, force=0.8)
    rolling = contact_path(30, force=0.8)
    return make_frames(held + rolling, seed=21, tail=15)


def test_record_then_replay_twice_gives_identical_estimates(tmp_path: Path, capsys) -> None:
    frames = scene_frames()
    source = write_recording(tmp_path / "source.tact", frames)
    recorded = tmp_path / "recorded.tact"

    assert cli(["record", f"replay://{source}?speed=0", "-o", str(recorded)]) == 0
    err = capsys.readouterr().err
    assert f"recorded {len(frames)} frame(s)" in err
    back = [decode_frame(wire) for _, wire in read_recording(recorded)]
    assert len(back) == len(frames) and all(map(np_frames_equal, back, frames))

    outputs = []
    for _ in range(2):
        assert cli(["replay", str(recorded), "--speed", "0", "--no-timing"]) == 0
        outputs.append(capsys.readouterr().out)
    assert outputs[0] == outputs[1], "two replays of one recording differ"
    lines = [json.loads(line) for line in outputs[0].splitlines()]
    assert [x["seq"] for x in lines] == [f.seq for f in frames]
    gates = {x["gate"] for x in lines}
    assert gates == {"fit", "unchanged", "no_contact"}, gates
    # the stream's key for what a message is, "type" (it was "class" here until 2026-11-23)
    assert all(x["type"] == "estimate" and x["sensor"] == "replay" for x in lines)
    assert all("class" not in x for x in lines)
    assert not any(k in lines[0] for k in ("latency_ms", "host_time", "fit_ms"))
    assert not any(k in c for x in lines for c in x["contacts"] for k in ("fit_ms", "latency_ms"))

    # With timing (the default), the timing keys are there and the rest is unchanged.
    assert cli(["replay", str(recorded), "--speed", "0"]) == 0
    timed = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert all(x["latency_ms"] >= 0 for x in timed)
    for a, b in zip(timed, lines):
        assert without_timing(a) == b
        assert all("fit_ms" in c for c in a["contacts"])


def test_record_stops_after_frames_and_never_overwrites(tmp_path: Path, capsys) -> None:
    source = write_recording(tmp_path / "s.tact", make_frames(contact_path(5), settle=20))
    out = tmp_path / "o.tact"
    assert cli(["record", f"replay://{source}?speed=0", "-o", str(out), "--frames", "7"]) == 0
    assert len(read_recording(out)) == 7
    assert cli(["record", f"replay://{source}?speed=0", "-o", str(out)]) == 2
    assert "exists" in capsys.readouterr().err
    assert cli(["record", f"replay://{source}?speed=0", "-o", str(out), "--append",
                "--frames", "3"]) == 0
    assert len(read_recording(out)) == 10
    assert cli(["record", "foo://x", "-o", str(tmp_path / "n.tact")]) == 2
    assert "unknown frame source scheme" in capsys.readouterr().err


def test_replay_of_a_file_that_is_not_a_recording_is_one_error_line(tmp_path: Path,
                                                                     capsys) -> None:
    bad = tmp_path / "bad.tact"
    bad.write_bytes(b"not a recording at all, just bytes")
    assert cli(["replay", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a tactiled recording" in err
    assert cli(["replay", str(tmp_path / "absent.tact")]) == 2

"""`tactiled export`: a recording to MCAP (ROS 2 messages) and to npz (raw frames).

The golden press session (tests/data/golden) is exported twice in subprocesses, with the
numerics pinned as the golden replay test pins them; the MCAP files are read with the MCAP
project's reader (file structure) and decoded with its ROS 2 decoder (``mcap_ros2``, not the
rosbags serializer that wrote them), and their Contact messages are compared with the checked-
in golden estimates of ``tactiled replay --no-timing`` for the same file.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from tactiled.frames import encode_frame
from tactiled.io.recording import RecordingReader
from tactiled_service.ros2 import messages

ROOT = Path(__file__).resolve().parents[2]
GOLDEN = ROOT / "tests" / "data" / "golden"
sys.path.insert(0, str(ROOT / "tests" / "reliability"))
import regen_golden  # noqa: E402  (the golden replay's pinned numerics)

RECORDING = GOLDEN / "press.tact"


def export(out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "tactiled.cli", "export", str(RECORDING),
                           "-o", str(out), *extra], capture_output=True, text=True,
                          timeout=600, env={**os.environ, **regen_golden.PINNED_ENV})


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("export")
    outs = {"a": tmp / "a.mcap", "b": tmp / "b.mcap", "npz": tmp / "press.npz"}
    procs = {k: subprocess.Popen([sys.executable, "-m", "tactiled.cli", "export",
                                  str(RECORDING), "-o", str(p)],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                 env={**os.environ, **regen_golden.PINNED_ENV})
             for k, p in outs.items()}
    for k, proc in procs.items():
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, (k, err)
        assert err.strip().splitlines()[-1].startswith("exported 90 frame(s)"), err
    return outs


def read(path: Path) -> tuple[Any, Any, list[tuple[Any, Any, Any]]]:
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        summary = reader.get_summary()
        decoded = [(ch, msg, dec) for _schema, ch, msg, dec in reader.iter_decoded_messages()]
    return header, summary, decoded


def test_mcap_has_the_ros2_profile_topics_and_types(exported: dict[str, Path]) -> None:
    header, summary, decoded = read(exported["a"])
    assert header.profile == "ros2"
    topics = {c.topic: c for c in summary.channels.values()}
    expected = {f"/tactiled/finger0/{k}": messages.TYPES[k]
                for k in ("wrench", "contact", "contacts", "markers", "strain")}
    expected["/diagnostics"] = messages.TYPES["diagnostics"]
    assert {t: summary.schemas[c.schema_id].name for t, c in topics.items()} == expected
    for topic, channel in topics.items():
        schema = summary.schemas[channel.schema_id]
        assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
        assert channel.metadata == {"topic_type_hash": messages.type_hash(schema.name)}, topic
    per_topic: dict[str, list[Any]] = defaultdict(list)
    for channel, msg, _ in decoded:
        per_topic[channel.topic].append(msg)
    for k in ("wrench", "contact", "contacts", "markers", "strain"):
        assert len(per_topic[f"/tactiled/finger0/{k}"]) == 90, k  # every frame, every estimate
    for topic, msgs in per_topic.items():
        assert [m.sequence for m in msgs] == list(range(len(msgs))), topic
    assert summary.statistics.message_count == len(decoded)
    assert len(per_topic["/diagnostics"]) >= 1


def test_contacts_are_the_golden_estimates(exported: dict[str, Path]) -> None:
    golden = [json.loads(line) for line in (GOLDEN / "press.jsonl").read_text().splitlines()]
    _, _, decoded = read(exported["a"])
    contacts = [dec for ch, _, dec in decoded if ch.topic.endswith("/contact")]
    wrenches = [dec for ch, _, dec in decoded if ch.topic.endswith("/wrench")]
    arrays = [dec for ch, _, dec in decoded if ch.topic.endswith("/contacts")]
    assert len(contacts) == len(golden) == len(wrenches) == len(arrays)

    def same(a: float, b: Any) -> bool:
        return math.isnan(a) if b is None else math.isclose(a, b, rel_tol=regen_golden.REL_TOL)

    for c, w, a, e in zip(contacts, wrenches, arrays, golden):
        where = f"seq {e['seq']}"
        assert c.contact_id == (-1 if e["contact_id"] is None else e["contact_id"]), where
        assert (a.seq, a.sensor) == (e["seq"], c.sensor), where  # (export names it --name)
        assert [k.contact_id for k in a.contacts] == [k["contact_id"] for k in e["contacts"]]
        for k, g in zip(a.contacts, e["contacts"]):  # the strongest first, as the contact topic's
            assert (k.seq, k.gate, k.model, k.frames_used) == (
                e["seq"], e["gate"], g["model"], g["frames_used"]), where
            for key in ("x_mm", "y_mm", "force_n", "r1_mm", "angle_deg"):
                assert same(getattr(k, key), g[key]), (where, key)
                assert same(getattr(k, f"std_{key}"), g["std"][key]), (where, key)
        assert (c.seq, c.gate, c.contact, c.model, c.converged, c.frames_used) == (
            e["seq"], e["gate"], e["contact"], e["model"] or "", bool(e["converged"]),
            e["frames_used"]), where
        assert c.fitted_seq == (-1 if e["fitted_seq"] is None else e["fitted_seq"]), where
        for key in ("x_mm", "y_mm", "force_n", "r1_mm", "r2_mm", "angle_deg", "rms", "peak"):
            assert same(getattr(c, key), e[key]), (where, key)
            assert same(getattr(c, f"std_{key}") if key not in ("rms", "peak") else 0.0,
                        e["std"].get(key) if key not in ("rms", "peak") else 0.0), (where, key)
        for key in ("latency_ms", "worker_ms", "fit_ms"):  # timing: not the recording's
            assert math.isnan(getattr(c, key)), (where, key)
        force = -e["force_n"] if e["contact"] and e["force_n"] is not None else 0.0
        assert same(w.wrench.force.z, force), where
    assert sum(c.contact for c in contacts) > 10


def test_stamps_are_the_recorded_times(exported: dict[str, Path]) -> None:
    with RecordingReader(RECORDING) as reader:
        created = reader.header.created
        host = [t for t, _ in reader]
    _, _, decoded = read(exported["a"])
    images = [(msg, dec) for ch, msg, dec in decoded if ch.topic.endswith("/strain")]
    assert len(images) == len(host)
    for (msg, img), t in zip(images, host):
        expected_ns = messages.nanoseconds(created + (t - host[0]))
        assert msg.log_time == msg.publish_time == expected_ns
        assert img.header.stamp.sec * 1_000_000_000 + img.header.stamp.nanosec == expected_ns


def test_export_is_byte_for_byte_deterministic(exported: dict[str, Path]) -> None:
    assert exported["a"].read_bytes() == exported["b"].read_bytes()


def test_npz_holds_the_raw_frames(exported: dict[str, Path]) -> None:
    data = np.load(exported["npz"])
    assert set(data.files) == {"counts", "host_time_s", "seq", "sensor_id"}
    counts, seq = data["counts"], data["seq"]
    assert counts.shape == (90, 8, 8) and counts.dtype == np.uint16
    golden = [json.loads(line) for line in (GOLDEN / "press.jsonl").read_text().splitlines()]
    assert seq.tolist() == [e["seq"] for e in golden]
    with RecordingReader(RECORDING) as reader:
        records = list(reader)
    np.testing.assert_array_equal(data["host_time_s"], [t for t, _ in records])
    assert set(data["sensor_id"].tolist()) == {reader.header.sensor_id}
    # Each frame re-encoded from the arrays gives back the recorded wire bytes.
    from tactiled.frames import Frame
    for i, (_, wire) in enumerate(records):
        frame = Frame(seq=int(seq[i]), device_time_us=golden[i]["device_time_us"],
                      raw=counts[i], sensor_id=int(data["sensor_id"][i]))
        assert encode_frame(frame) == wire, i


@pytest.mark.parametrize(("args", "message"), [
    (["-o", "x.bag"], "the output must end in .mcap or .npz"),
    (["-o", "exists.mcap"], "exists (an export never overwrites a file)"),
])
def test_bad_arguments_are_one_line_and_exit_2(tmp_path: Path, args: list[str],
                                               message: str) -> None:
    (tmp_path / "exists.mcap").write_bytes(b"keep")
    args = [a if not a.endswith((".bag", ".mcap")) else str(tmp_path / a) for a in args]
    done = subprocess.run([sys.executable, "-m", "tactiled.cli", "export", str(RECORDING),
                           *args], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and message in done.stderr, done.stderr
    assert (tmp_path / "exists.mcap").read_bytes() == b"keep"


def test_a_file_that_is_not_a_recording_is_refused(tmp_path: Path) -> None:
    bad = tmp_path / "bad.tact"
    bad.write_bytes(b"not a recording at all, just text" * 3)
    done = subprocess.run([sys.executable, "-m", "tactiled.cli", "export", str(bad), "-o",
                           str(tmp_path / "o.mcap")], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "not a tactiled recording" in done.stderr
    assert "Traceback" not in done.stderr and not (tmp_path / "o.mcap").exists()


def test_the_foxglove_layout_names_what_an_export_holds(exported: dict[str, Path]) -> None:
    layout = json.loads((ROOT / "docs" / "foxglove" / "tactiled.json").read_text())
    _, summary, decoded = read(exported["a"])
    topics = {c.topic for c in summary.channels.values()}
    first = {}
    for ch, _, dec in decoded:
        first.setdefault(ch.topic, dec)
    named: list[str] = []
    for panel_id, config in layout["configById"].items():
        kind = panel_id.split("!")[0]
        if kind == "Image":
            named.append(config["imageMode"]["imageTopic"])
        elif kind == "3D":
            named += list(config["topics"])
        elif kind == "Plot":
            named += [p["value"] for p in config["paths"]]
        elif kind == "RawMessages":
            named.append(config["topicPath"])
    assert len(named) >= 8
    for path in named:
        topic, _, field = path.partition(".")
        assert topic in topics, path
        if field:
            assert hasattr(first[topic], field), path
    panels = set()

    def walk(node: Any) -> None:
        if isinstance(node, str):
            panels.add(node)
        else:
            walk(node["first"])
            walk(node["second"])

    walk(layout["layout"])
    assert panels == set(layout["configById"])

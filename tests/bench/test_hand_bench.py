"""The acquisition bench on the hand: six simulated devices (five fingertips, a 16x16 palm) on
real ptys into one daemon, every figure of its tables also written as JSON.  Speed is reported
by the benchmark (docs/performance/hand.md), never asserted."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tactiled_bench import acquisition_report as report
from tactiled_bench import acquisition_runs as runs
from tactiled.sim import HAND_PARTS

TACTILED = [sys.executable, "-m", "tactiled.cli", "bench", "--no-progress"]


def test_the_hand_devices_and_their_timeline() -> None:
    devs = runs.devices("hand")
    assert [d.name for d in devs] == list(HAND_PARTS)
    assert {d.description for d in devs} == {"flat16", "fearing1988"}
    # the timeline says whether each part touches: every part's contacts start and end together
    truth = runs.scene_truth("hand", 1000.0)
    from tactiled.sensors import load_description
    from tactiled.sim import named_scene

    for d in devs:
        sc = named_scene(d.scene, load_description(d.description).sensor_model().geometry)
        for k in range(0, 4000, 7):
            assert (truth(k) is None) == (not sc.contacts_at(k / 1000.0))
    lo, hi = runs.tare_window("hand", 1000.0)
    assert all(truth(k) is None for k in range(lo, hi + 300))


def _cell(value: float | None, fmt: str) -> str:
    return "-" if value is None else fmt.format(value)


def test_a_short_hand_run_writes_every_figure_of_its_tables_as_json(tmp_path, table_rows) -> None:
    out_json = tmp_path / "hand.json"
    proc = subprocess.run([*TACTILED, "--suite", "acquisition", "--scene", "hand", "--quick",
                           "--seconds", "2", "--json", str(out_json)],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert "a hand: six devices" in out
    doc = json.loads(out_json.read_text())
    assert doc["scene"] == "hand" and doc["rate_hz"] == 1000.0 and doc["cores"] >= 1
    assert doc["conditions"] in out
    (run,) = doc["runs"]
    sensors, total = run["sensors"], run["total"]
    assert list(sensors) == list(HAND_PARTS)
    every = {"frames", "frames_per_s", "device_sent", "device_not_sent", "gaps_seen",
             "lost_in_acquisition", "rejected", "duplicated", "unaccounted", "contact_frames",
             "own_fit", "reused", "predicted", "superseded", "unanswered", "answered_pct",
             "latency_ms", "contacts_reported", "estimates_with_several_contacts"}
    for s in [*sensors.values(), total]:
        assert every <= set(s), every - set(s)
        assert set(s["latency_ms"]) == {"p50", "p99", "max"}
        assert s["own_fit"] + s["reused"] + s["superseded"] + s["unanswered"] == s["contact_frames"]
    for key in ("frames", "contact_frames", "unaccounted", "device_sent", "contacts_reported"):
        assert total[key] == sum(s[key] for s in sensors.values()), key
    assert total["frames"] > 0 and all(s["device_sent"] > 0 for s in sensors.values())
    # ... and the tables say the same
    (answers,) = table_rows(out, "| workers | contact frames |")
    assert int(answers[1]) == total["contact_frames"]
    assert answers[2] == _cell(total["own_fit_pct"], "{:.1f} %")
    per = table_rows(out, "| workers | sensor | contact frames |")
    assert [r[1] for r in per] == [*HAND_PARTS, "all"]
    for r in per:
        s = total if r[1] == "all" else sensors[r[1]]
        assert int(r[2]) == s["contact_frames"] and int(r[4]) == s["contacts_reported"]
        assert r[3] == _cell(s["answered_pct"], "{:.1f} %")
        lat = s["latency_ms"]
        assert r[6] == " / ".join(_cell(lat[q], "{:.2f}") for q in ("p50", "p99", "max"))
    (cpu,) = table_rows(out, "| workers | main process CPU per frame")
    c = run["main_process_cpu_per_frame"]
    assert c["windows"] >= 1 and c["median_us"] > 0
    assert cpu[1] == f"{c['median_us']:.1f} / {c['p99_us']:.1f}" and int(cpu[3]) == c["windows"]
    # the collector's young generations run many times a second in any Python process
    g = run["garbage_collection"]
    assert g["collections"] > 0 and g["total_ms"] >= g["max_ms"] > 0
    assert cpu[4] == f"{g['collections']} / {g['total_ms']:.1f} / {g['max_ms']:.1f}"
    integrity = table_rows(out, "| workers | finger |")
    assert [r[1] for r in integrity] == list(HAND_PARTS)
    for r in integrity:
        s = sensors[r[1]]
        assert int(r[3]) == s["gaps_seen"] and r[5] == str(s["lost_in_acquisition"])
        assert int(r[-1]) == s["unaccounted"]


def test_a_run_without_collections_recorded_says_so() -> None:
    """A baseline's code records no collections: its figures are None, not 0."""
    from types import SimpleNamespace

    assert report.garbage_collection(SimpleNamespace()) == {  # type: ignore[arg-type]
        "collections": None, "total_ms": None, "max_ms": None}
    assert report.garbage_collection(SimpleNamespace(gc_s=[0.002, 0.0005])) == {  # type: ignore[arg-type]
        "collections": 2, "total_ms": pytest.approx(2.5), "max_ms": pytest.approx(2.0)}


@pytest.mark.parametrize("argv, message", [
    (["--scene", "hands"], "unknown scene 'hands'"),
    (["--scene", "hand", "--json", "/nonexistent/dir/x.json"], "no directory /nonexistent/dir"),
])
def test_bad_hand_options(argv: list[str], message: str) -> None:
    proc = subprocess.run([*TACTILED, "--suite", "acquisition", *argv], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2 and message in proc.stderr

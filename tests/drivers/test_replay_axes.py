"""3-axis arrays through the recording and replay path: a simulated 3-axis stream (``sim://``
on ``xela_uskin_4x4`` playing a tangential scene) recorded, replayed as the same 3-axis frames
bit for bit, exported to npz and MCAP with its x, y, z; and the daemon's shear and slip
estimates out of a replayed pull-until-slip (``tactiled record`` then ``tactiled replay``, real
processes)."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys

import numpy as np
import pytest

from procs import SimulatedDevice, read_source
from tactiled.frames import Frame, encode_frame
from tactiled.io.recording import Recorder, RecordingReader
from tactiled.sensors import load_description
from tactiled.sim.taxel_stream import REST_FRAMES, TaxelScenes
from tactiled.sources import open_source

SIM_PULL = "sim://?sensor=xela_uskin_4x4&scene=pull&speed=0&loop=0&seed=4"


def cli(*args: str, timeout: float = 600.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tactiled.cli", *args], capture_output=True,
                          text=True, timeout=timeout)


async def read_all(url: str) -> list:
    async with open_source(url) as src:
        return [f async for f in src.frames(timeout=10.0)]


def test_a_tangential_scene_streams_3_axis_frames_as_version_2() -> None:
    scenes = TaxelScenes(load_description("xela_uskin_4x4"), "pull", seed=1)
    frame = scenes.next_frame()
    assert frame.taxels.shape == (4, 4, 3) and frame.taxels.dtype == np.uint16
    np.testing.assert_array_equal(frame.raw, frame.taxels[..., 2])
    assert encode_frame(frame)[1] == 2  # COBS code byte, then the version: 2
    # a pass is the rest, then the scene: the pull's sphere moves the readings well past noise
    counts = np.stack([scenes.next_counts() for _ in range(scenes.ticks_per_pass - 1)])
    rest = counts[:REST_FRAMES - 1].astype(float)
    assert np.abs(rest - rest.mean(axis=0)).max() < 10 * 2.0  # axis_noise 2 readings
    assert np.abs(counts.astype(float) - rest.mean(axis=0)).max() > 50


def test_a_1_axis_sensor_has_no_tangential_scene() -> None:
    with pytest.raises(ValueError, match="1-axis"):
        open_source("sim://?scene=pull")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux ptys")
def test_simulate_pty_streams_3_axis_wire_frames(tmp_path) -> None:
    """`tactiled simulate --pty` on a 3-axis sensor and a tangential scene: a real pty carrying
    version-2 frames, read by the serial driver as 3-axis frames, none rejected."""
    link = tmp_path / "tact"
    with SimulatedDevice("--pty", "--link", str(link), "--sensor", "xela_uskin_4x4",
                         "--scene", "pull", "--rate", "1000", "--seed", "3") as device:
        assert device.line().startswith("pty: ")
        assert device.line() == f"link: {link}"

        got, stats = read_source(f"serial://{link}", lambda got: len(got) >= 100, 30.0)
    assert all(f.taxels is not None and f.taxels.shape == (4, 4, 3) for f in got)
    assert stats.rejected == 0 and stats.version_errors == 0


def test_a_3_axis_recording_replays_as_the_same_3_axis_frames(tmp_path) -> None:
    live = asyncio.run(read_all(SIM_PULL))
    assert len(live) == TaxelScenes(load_description("xela_uskin_4x4"), "pull").ticks_per_pass
    path = tmp_path / "pull.tact"
    with Recorder(path, sensor_id=0) as rec:
        for k, frame in enumerate(live):
            rec.record(frame, host_time=100.0 + k / 1000)
    replayed = asyncio.run(read_all(f"replay://{path}?speed=0"))
    assert len(replayed) == len(live)
    for a, b in zip(live, replayed):
        assert (a.seq, a.device_time_us) == (b.seq, b.device_time_us)
        np.testing.assert_array_equal(a.taxels, b.taxels)
        np.testing.assert_array_equal(a.raw, b.raw)
    # npz export: the counts as received, x, y, z
    out = tmp_path / "pull.npz"
    done = cli("export", str(path), "-o", str(out), "--no-progress", timeout=120)
    assert done.returncode == 0, done.stderr
    with np.load(out) as data:
        np.testing.assert_array_equal(data["taxel_counts"], np.stack([f.taxels for f in live]))
        np.testing.assert_array_equal(data["counts"], np.stack([f.raw for f in live]))


def test_an_old_1_axis_recording_exports_no_taxels(tmp_path, frame_factory) -> None:
    path = tmp_path / "old.tact"
    with Recorder(path) as rec:
        for k, frame in enumerate(frame_factory(5, seed=2)):
            rec.record(frame, host_time=1.0 + k)
    out = tmp_path / "old.npz"
    done = cli("export", str(path), "-o", str(out), "--no-progress", timeout=120)
    assert done.returncode == 0, done.stderr
    with np.load(out) as data:
        assert "taxel_counts" not in data.files and data["counts"].shape[0] == 5
    with RecordingReader(path) as reader:
        assert reader.header.version == 1


@pytest.mark.slow  # ~25 s each: the pipeline's fit worker starts, and fits every frame
def test_a_replayed_pull_gives_shear_and_slip_estimates(tmp_path) -> None:
    path = tmp_path / "pull.tact"
    done = cli("record", SIM_PULL, "-o", str(path))
    assert done.returncode == 0, done.stderr
    done = cli("replay", str(path), "--sensor", "xela_uskin_4x4", "--no-timing")
    assert done.returncode == 0, done.stderr
    lines = [json.loads(x) for x in done.stdout.splitlines()]
    sheared = [x for x in lines if x.get("contact") and isinstance(x.get("shear"), dict)]
    assert sheared, done.stdout[-2000:]
    for x in sheared:
        assert isinstance(x["shear"]["fx_n"], float) and x["slip"]["state"] in (
            "stick", "partial", "slip")
    # the scene pulls until the contact slides: a slip is declared in the replay
    assert any(x["slip"]["state"] == "slip" for x in sheared)


@pytest.mark.slow
def test_a_3_axis_recording_exports_its_readings_to_mcap_as_a_3_channel_image(tmp_path) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    path, out = tmp_path / "pull.tact", tmp_path / "pull.mcap"
    done = cli("record", SIM_PULL, "-o", str(path))
    assert done.returncode == 0, done.stderr
    done = cli("export", str(path), "-o", str(out), "--sensor", "xela_uskin_4x4", "--name",
               "xela", "--no-progress")
    assert done.returncode == 0, done.stderr
    with open(out, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        by_topic: dict[str, list] = {}
        for _s, ch, _m, msg in reader.iter_decoded_messages():
            by_topic.setdefault(ch.topic, []).append(msg)
    images, strain = by_topic["/tactiled/xela/taxels"], by_topic["/tactiled/xela/strain"]
    # every zeroed frame but the first: its readings' zero is learned from the frames before
    assert len(images) == len(strain) - 1 > 0
    assert all(im.encoding == "32FC3" and (im.height, im.width, im.step) == (4, 4, 48)
               for im in images)
    # zeroed readings: near 0 at rest, the pull's press moves z by far more than the noise
    z = np.stack([np.frombuffer(bytes(im.data), "<f4").reshape(4, 4, 3)[..., 2] for im in images])
    assert np.abs(z[:50]).max() < 20 and z.max() > 50


def test_a_vendor_recording_replays_through_its_device_table(tmp_path) -> None:
    """A PaXini recording (z counts offset by 0x8000, 5000 counts per strain) replays through
    the PaXini table, as its live run did; a recording naming no device through the wire
    format's (LookupTable.linear)."""
    from tactiled.sensors.devices import device_array
    from tactiled_drivers.paxini import ZERO_COUNTS

    xyz = np.full((10, 12, 3), ZERO_COUNTS, np.uint16)
    xyz[4, 5, 2] += 100
    frame = Frame(seq=0, device_time_us=0, raw=xyz[..., 2].copy(), taxels=xyz)
    for device in ("paxini", None):
        path = tmp_path / f"{device}.tact"
        with Recorder(path, device=device) as rec:
            rec.record(frame, host_time=1.0)
        src = open_source(f"replay://{path}?speed=0")
        array = src.device_array()
        if device is None:
            assert array is None
            continue
        assert array.kind == "paxini" and array.shape == (10, 12)
        live = device_array("paxini", 10, 12).nominal_table()
        replayed = array.nominal_table()
        counts = xyz[..., 2].astype(float)
        np.testing.assert_array_equal(replayed.to_strain(counts), live.to_strain(counts))
        assert replayed.to_strain(counts)[4, 5] == pytest.approx(100 / 5000)

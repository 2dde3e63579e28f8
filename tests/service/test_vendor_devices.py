"""`tactiled run` on the vendor drivers: the simulated devices (`tactiled simulate --as`) give
contact estimates through each driver, and a third party's driver package, pip-installed from
tests/plugin_pkg, is found on the entry point and runs in the daemon."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from procs import SimulatedDevice
from svc_helpers import http, wait_for

from tactiled.cli import main as cli_main
from tactiled.frames import decode_frame
from tactiled.io.recording import RecordingReader

SHAPES = {"lines": (8, 8), "flexitac": (12, 32), "robotiq": (7, 4), "xela": (4, 4),
          "paxini": (10, 12)}
PLUGIN = Path(__file__).resolve().parent.parent / "plugin_pkg"

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux ptys")


def launch_device(kind: str, device: str, *extra: str) -> SimulatedDevice:
    """``tactiled simulate --as KIND --device DEVICE [EXTRA...]`` at 100 Hz."""
    return SimulatedDevice("--as", kind, "--device", device, "--rate", "100", "--seed", "3",
                           *extra)


def first_line(proc: subprocess.Popen) -> str:
    """The address line a simulated device prints first ("pty: ..." or "xela: ws://...")."""
    line = proc.stdout.readline().strip()
    assert line, proc.stderr.read()
    return line


def start_device(kind: str, device: str, *extra: str) -> tuple[SimulatedDevice, str]:
    """:func:`launch_device`, and the address line it prints first."""
    proc = launch_device(kind, device, *extra)
    return proc, proc.line()


def write_config(path: Path, sensors: dict[str, str],
                 descriptions: dict[str, str] | None = None) -> Path:
    text = "[server]\nport = 0\n" + "".join(
        f'[[sensor]]\nname = "{name}"\nurl = "{url}"\n'
        + (f'description = "{descriptions[name]}"\n' if name in (descriptions or {}) else "")
        for name, url in sensors.items())
    path.write_text(text)
    return path


def estimates_with_contact(url: str, names: list[str]) -> dict[str, dict]:
    """The latest estimate of every sensor whose estimate has a fitted contact (a model and
    finite values for what the fit could determine)."""
    out = {}
    for name in names:
        r = http(url, "GET", f"/v1/sensors/{name}/estimate")
        if r.status_code == 200 and r.json().get("contact") and r.json().get("model"):
            out[name] = r.json()
    return out


@pytest.mark.slow  # ~80 s here: the fit workers build a start table for each new array shape
def test_daemon_estimates_contacts_on_every_simulated_device(daemon_process, tmp_path) -> None:
    devices = []
    try:
        for kind in ("lines", "flexitac", "robotiq"):
            devices.append(start_device(kind, str(tmp_path / f"tty_{kind}")))
        xela_proc, xela_line = start_device("xela", "0")
        devices.append((xela_proc, xela_line))
        xela_addr = xela_line.removeprefix("xela: ws://")
        sensors = {
            "lines": f"lines://{tmp_path}/tty_lines?rows=8&cols=8",
            "flexitac": f"flexitac://{tmp_path}/tty_flexitac",
            "left": f"robotiq://{tmp_path}/tty_robotiq?finger=0",
            "right": f"robotiq://{tmp_path}/tty_robotiq?finger=1",
            "xela": f"xela://{xela_addr}?sensor=1",
        }
        config = write_config(tmp_path / "vendors.toml", sensors, {
            "flexitac": "flexitac_12x32", "left": "robotiq_tsf85", "right": "robotiq_tsf85",
            "xela": "xela_uskin_4x4"})
        proc = daemon_process(["--config", str(config)])
        url = proc.wait_url()
        seen: dict[str, dict] = {}

        def all_in_contact() -> bool:
            seen.update(estimates_with_contact(url, list(sensors)))
            return len(seen) == len(sensors)

        wait_for(all_in_contact, 120.0, poll=0.2, what=f"estimates with contact ({seen.keys()})")
        health = http(url, "GET", "/v1/health").json()["sensors"]
        for name in sensors:
            h = health[name]
            assert h["connected"] and h["frames"] > 0 and h["published"] > 0, (name, h)
            assert h["rejected_chunks"] <= 1, (name, h)  # a first line read mid-way, at most
            assert seen[name]["rms"] is not None and seen[name]["gate"] in ("fit", "unchanged", "tracked")
        assert {seen["left"]["sensor_id"], seen["right"]["sensor_id"]} == {0, 1}
        proc.proc.terminate()
        assert proc.proc.wait(15) == 0
    finally:
        codes = [dev.stop() for dev, _ in devices]
    assert codes == [0] * len(devices), codes


def test_a_16x16_pad_rehearsed_on_the_simulated_lines_device(daemon_process, tmp_path) -> None:
    """`simulate --as lines --sensor flat16` prints 16x16 frames, and a daemon configured for a
    16x16 pad (the text-lines device page's configuration) reads every one and fits them."""
    device, line = start_device("lines", str(tmp_path / "ttyPAD"), "--sensor", "flat16")
    try:
        assert line.startswith("pty: ")
        config = write_config(tmp_path / "pad.toml",
                              {"pad": f"lines://{tmp_path}/ttyPAD?rows=16&cols=16"},
                              {"pad": "flat16"})
        proc = daemon_process(["--config", str(config)])
        url = proc.wait_url()
        seen: dict[str, dict] = {}

        def fitted() -> bool:
            seen.update(estimates_with_contact(url, ["pad"]))
            return "pad" in seen

        wait_for(fitted, 120.0, poll=0.2, what="an estimate with a contact on the 16x16 pad")
        frame = http(url, "GET", "/v1/sensors/pad/frame").json()
        assert (frame["rows"], frame["cols"]) == (16, 16), {k: frame[k] for k in ("rows", "cols")}
        health = http(url, "GET", "/v1/health").json()["sensors"]["pad"]
        assert health["frames"] > 0 and health["published"] > 0, health
        assert health["rejected_chunks"] <= 1 and health["wrong_sensor"] == 0, health
        # the contact lies on the pad, 16 tactels of 2.5 mm a side
        assert 0 <= seen["pad"]["x_mm"] <= 37.5 and 0 <= seen["pad"]["y_mm"] <= 37.5, seen["pad"]
        proc.proc.terminate()
        assert proc.proc.wait(15) == 0
    finally:
        code = device.stop()
    assert code == 0, device.stderr()[-2000:]


def test_record_from_each_simulated_device(tmp_path, capsys) -> None:
    """The short version of the test above: `tactiled record` through each driver."""
    queries = {"lines": "?rows=8&cols=8", "flexitac": "", "robotiq": "?finger=1",
               "xela": "?sensor=2", "paxini": ""}
    procs = {kind: launch_device(kind, "0" if kind == "xela" else str(tmp_path / f"tty_{kind}"))
             for kind in queries}
    try:
        for kind, query in queries.items():
            line = procs[kind].line()
            where = line.removeprefix("xela: ws://") if kind == "xela" else f"{tmp_path}/tty_{kind}"
            out = tmp_path / f"{kind}.tact"
            rc = cli_main(["record", f"{kind}://{where}{query}", "-o", str(out),
                           "--frames", "30", "--seconds", "20"])
            err = capsys.readouterr().err
            assert rc == 0 and "recorded 30 frame(s)" in err and "crc errors 0" in err, err
            reader = RecordingReader(out)
            shapes = {decode_frame(data).shape for _, data in reader}
            reader.close()
            assert reader.records == 30 and shapes == {SHAPES[kind]}, kind
            # the file names its device: a replay reads the counts through the device's table
            assert reader.header.device == kind
            from tactiled.sources import open_source

            replayed = open_source(f"replay://{out}").device_array()
            assert (replayed.kind, replayed.shape) == (kind, SHAPES[kind])
    finally:
        for proc in procs.values():
            proc.stop()


def test_third_party_driver_installed_with_pip(daemon_process, tmp_path) -> None:
    src = tmp_path / "plugin_src"
    shutil.copytree(PLUGIN, src)  # the build writes beside the sources: not in the repository
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps",
                    "--no-build-isolation", "--no-index", "--target", str(target), str(src)],
                   check=True, capture_output=True, timeout=120)
    assert list(target.glob("simlines_plugin-*.dist-info/entry_points.txt"))
    config = write_config(tmp_path / "plugin.toml", {"plug": "simlines://?seed=4"})
    proc = daemon_process(["--config", str(config)], env={"PYTHONPATH": str(target)})
    url = proc.wait_url()
    wait_for(lambda: bool(estimates_with_contact(url, ["plug"])), 120.0, poll=0.2,
             what="an estimate from the plug-in's frames")
    h = http(url, "GET", "/v1/health").json()["sensors"]["plug"]
    assert h["connected"] and h["frames"] > 10 and h["rejected_chunks"] == 0
    proc.proc.terminate()
    assert proc.proc.wait(15) == 0

"""Shear and slip live: a real `tactiled run` (uvicorn) on a simulated 3-axis XELA server
(`tactiled simulate --as xela --scene pull`, a real WebSocket server playing the 3-axis model's
pull-until-slip scene) gives estimates with `shear` and `slip` tables over REST, a
WebSocket client subscribed to the `slip` stream alone receives the slip events and nothing
else, and a Zenoh subscriber to the sensor's `slip` key receives the same events."""

from __future__ import annotations

import asyncio
import os
import sys

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from svc_helpers import http, recv_json, subscribe, wait_for, ws_connect
from test_vendor_devices import first_line, write_config
from test_zenoh import Collector, free_port, zconfig, zenoh

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux")


def start_pull_device(scene: str = "pull") -> tuple:
    """The simulated XELA server playing a tangential scene at 200 Hz: (process, address line)."""
    import subprocess

    proc = subprocess.Popen(
        [sys.executable, "-m", "tactiled.cli", "simulate", "--as", "xela", "--device", "0",
         "--rate", "200", "--seed", "5", "--scene", scene],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return proc, first_line(proc)


@pytest.mark.slow  # minutes on a loaded machine: the fit worker builds the 4x4 array's start table
def test_slip_stream_and_shear_tables(daemon_process, tmp_path) -> None:
    device, line = start_pull_device()
    try:
        addr = line.removeprefix("xela: ws://")
        config = write_config(tmp_path / "xela.toml", {"xela": f"xela://{addr}?sensor=1"},
                              {"xela": "xela_uskin_4x4"})
        port = free_port()
        config.write_text(config.read_text() + "[fit]\nworkers = 1\nstartup_timeout = 300\n"
                          + f'[record]\npath = "{tmp_path}/live"\nformat = "mcap"\n'
                          + '[zenoh]\nenabled = true\nmulticast_scouting = false\n'
                          + f'prefix = "shear/test"\nlisten = ["tcp/127.0.0.1:{port}"]\n')
        reader = zenoh.open(zconfig("peer", connect=[f"tcp/127.0.0.1:{port}"]))
        bus = Collector(reader, "shear/test/**")
        proc = daemon_process(["--config", str(config)])
        url = proc.wait_url()
        ws_url = url.replace("http://", "ws://") + "v1/stream"
        seen: dict = {}

        def shear_table() -> bool:
            r = http(url, "GET", "/v1/sensors/xela/estimate")
            body = r.json() if r.status_code == 200 else {}
            if body.get("contact") and isinstance(body.get("shear"), dict):
                seen.update(body)
                return True
            return False

        wait_for(shear_table, 400.0, poll=0.1, what="an estimate with a shear table")
        shear, slip = seen["shear"], seen["slip"]
        for key in ("fx_n", "fy_n", "torque_nmm", "q_over_p"):
            assert isinstance(shear[key], float), (key, shear)
            assert shear["std"][key] is None or shear["std"][key] >= 0
        assert (shear["mu"] is None) == ("mu" in shear["reasons"])
        assert slip["state"] in ("stick", "partial", "slip")
        assert seen["contacts"][0]["shear"] == shear

        async def slip_events() -> list[dict]:
            async with ws_connect(ws_url) as ws:
                reply = await subscribe(ws, streams=["slip"])
                assert reply["streams"] == ["slip"]
                got = []
                while not any(m["event"] == "onset" for m in got):
                    got.append(await recv_json(ws, 60.0))
                return got

        events = asyncio.run(slip_events())
        assert all(m["type"] == "slip" and m["sensor"] == "xela" for m in events)
        onset = next(m for m in events if m["event"] == "onset")
        assert isinstance(onset["seq"], int) and onset["time"] > 0
        assert onset["state"] == "slip"
        # the same events on Zenoh, under P/<sensor>/slip, the stream's JSON
        wait_for(lambda: any(m["event"] == "onset" and m["seq"] == onset["seq"]
                             for m in bus.of("shear/test", "slip")), 30.0, poll=0.1,
                 what="the onset on Zenoh")
        zmsg = next(m for m in bus.of("shear/test", "slip") if m["seq"] == onset["seq"])
        assert {k: v for k, v in zmsg.items() if k != "_text"} == onset
        assert all(m["sensor"] == "xela" for m in bus.of("shear/test", "slip"))
        bus.close()
        reader.close()
        # `tactiled watch --zenoh --slip` on the slip key alone prints the next event
        import json
        import subprocess

        watch = subprocess.run(
            [sys.executable, "-m", "tactiled.cli", "watch", "--zenoh", "--slip", "--connect",
             f"tcp/127.0.0.1:{port}", "--key", "shear/test/xela/slip", "--count", "1"],
            capture_output=True, text=True, timeout=120,
            env={**os.environ, "TACTILED_ZENOH_MULTICAST_SCOUTING": "false"})
        assert watch.returncode == 0, watch.stderr
        line = json.loads(watch.stdout)
        assert line["prefix"] == "shear/test" and line["type"] == "slip"
        assert line["event"] in ("onset", "end") and line["sensor"] == "xela"
        async def frame_with_taxels() -> dict:
            async with ws_connect(ws_url) as ws:
                await subscribe(ws, streams=["frames"])
                while True:
                    msg = await recv_json(ws, 30.0)
                    if "taxels" in msg:
                        return msg

        frame = asyncio.run(frame_with_taxels())
        assert np.asarray(frame["taxels"]).shape == (4, 4, 3)
        proc.proc.terminate()
        assert proc.proc.wait(15) == 0
        # the live MCAP recording holds the readings as a 3-channel image
        with open(tmp_path / "live.mcap", "rb") as fh:
            reader = make_reader(fh, decoder_factories=[DecoderFactory()])
            images = [dec for _s, ch, _m, dec in reader.iter_decoded_messages()
                      if ch.topic == "/tactiled/xela/taxels"]
        assert images and all(im.encoding == "32FC3" and (im.height, im.width) == (4, 4)
                              for im in images)
        pressed = max(images, key=lambda im: np.frombuffer(bytes(im.data), "<f4")[2::3].max())
        z = np.frombuffer(bytes(pressed.data), "<f4").reshape(4, 4, 3)[..., 2]
        assert z.max() > 50  # readings: a press moves the magnets by tenths of a mm
    finally:
        device.terminate()
        device.wait(30)

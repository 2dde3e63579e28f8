"""What `tactiled run` logs when nothing is wrong: a XELA sensor whose WebSocket is still
connecting at the first health sample is not logged as an ERROR (it is `WARN connecting`),
and Ctrl-C, an asked-for stop, is logged at INFO, not as a warning.  A real daemon process on a
real simulated xela_server (`tactiled simulate --as xela`), stopped with a real SIGINT."""

from __future__ import annotations

import signal

from svc_helpers import http, wait_for
from test_vendor_devices import start_device


def test_a_xela_sensor_starts_quietly_and_ctrl_c_is_no_warning(daemon_process, tmp_path) -> None:
    device, line = start_device("xela", "0")
    with device:
        assert line.startswith("xela: ws://"), line
        (tmp_path / "xela.toml").write_text(
            '[server]\nport = 0\n[[sensor]]\nname = "xela"\ndescription = "xela_uskin_4x4"\n'
            f'url = "xela://{line.removeprefix("xela: ws://")}?sensor=1"\n')
        proc = daemon_process(["--config", str(tmp_path / "xela.toml"), "-v"])  # INFO shown
        url = proc.wait_url()
        wait_for(lambda: http(url, "GET", "/v1/health").json()["sensors"]["xela"]["status"] == "OK",
                 60.0, poll=0.2, what="the xela sensor OK")
        proc.proc.send_signal(signal.SIGINT)
        assert proc.proc.wait(30) == 0
        log = proc.proc.stderr.read().splitlines()
    assert not [l for l in log if "-> ERROR" in l or "None ->" in l], log
    stops = [l for l in log if "SIGINT: shutting down" in l]
    assert len(stops) == 1 and " INFO " in stops[0], log
    assert not [l for l in log if " WARNING " in l], log

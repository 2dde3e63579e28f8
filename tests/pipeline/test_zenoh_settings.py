"""``[zenoh]`` settings: defaults, file < environment < overrides, errors naming the key.

Pure settings (no Zenoh needed): the endpoints' form is checked here, Zenoh's own parser runs
again at start (tests/service/test_zenoh.py).
"""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from tactiled.errors import ConfigError
from tactiled.settings import ZenohSettings, load_settings, settings_to_dict


def test_off_by_default_with_a_prefix_from_the_host_name() -> None:
    z = load_settings(None, {}, {}).zenoh
    assert z.enabled is False and z.mode == "peer"
    assert z.connect == () and z.listen == () and z.frame_rate_hz == 0.0 and z.config is None
    assert z.multicast_scouting is None and z.scouting is True  # on in peer mode
    assert z.prefix.startswith("tactiled/") and "/" not in z.prefix[len("tactiled/"):]
    if socket.gethostname().replace("-", "").isalnum():
        assert z.prefix == f"tactiled/{socket.gethostname()}"
    client = ZenohSettings(mode="client", connect=("tcp/10.0.0.1:7447",))
    assert client.scouting is False  # off in client mode unless asked


def test_file_then_environment_then_overrides(tmp_path: Path) -> None:
    (tmp_path / "zenoh.json5").write_text("{}")
    cfg = tmp_path / "t.toml"
    cfg.write_text('[zenoh]\nenabled = true\nconnect = ["tcp/192.168.1.10:7447"]\n'
                   'prefix = "lab/hand1"\nframe_rate_hz = 30\nconfig = "zenoh.json5"\n'
                   'multicast_scouting = false\n')
    z = load_settings(cfg, {}, {}).zenoh
    assert z.enabled and z.connect == ("tcp/192.168.1.10:7447",) and z.prefix == "lab/hand1"
    assert z.frame_rate_hz == 30.0 and z.config == str(tmp_path / "zenoh.json5")
    assert z.scouting is False
    env = {"TACTILED_ZENOH_CONNECT": "tcp/10.0.0.2:7447, tls/[fe80::1]:7447",
           "TACTILED_ZENOH_MODE": "client", "TACTILED_ZENOH_LISTEN": ""}
    z = load_settings(cfg, env, {}).zenoh
    assert z.connect == ("tcp/10.0.0.2:7447", "tls/[fe80::1]:7447") and z.mode == "client"
    assert z.listen == ()
    z = load_settings(cfg, env, {"zenoh.connect": ["udp/127.0.0.1:7447"],
                                 "zenoh.enabled": False}).zenoh
    assert z.connect == ("udp/127.0.0.1:7447",) and not z.enabled
    assert settings_to_dict(load_settings(cfg, {}, {}))["zenoh"]["prefix"] == "lab/hand1"


@pytest.mark.parametrize("text, env, message", [
    ('[zenoh]\nconnect = "tcp/1.2.3.4:7447"\n', {}, "zenoh.connect: expected a list of endpoints"),
    ('[zenoh]\nconnect = ["tcp/1.2.3.4:7447", "nonsense"]\n', {},
     "zenoh.connect[1]: 'nonsense' is not an endpoint"),
    ('[zenoh]\nlisten = ["http/1.2.3.4:80"]\n', {}, "zenoh.listen[0]: unknown protocol 'http'"),
    ('[zenoh]\nconnect = ["tcp/1.2.3.4"]\n', {}, "zenoh.connect[0]: 'tcp/1.2.3.4': the address"),
    ('[zenoh]\nconnect = ["tcp/1.2.3.4:70000"]\n', {}, "zenoh.connect[0]: 'tcp/1.2.3.4:70000': "
                                                       "port 70000"),
    ('[zenoh]\nconnect = [7447]\n', {}, "zenoh.connect[0]: expected a string"),
    ('[zenoh]\nmode = "router"\n', {}, "zenoh.mode: must be one of peer, client"),
    ('[zenoh]\nprefix = "/tactiled"\n', {}, "zenoh.prefix: must be a Zenoh key"),
    ('[zenoh]\nprefix = "tactiled/**"\n', {}, "zenoh.prefix: must be a plain key"),
    ('[zenoh]\nprefix = "@/admin"\n', {}, "zenoh.prefix: keys starting with '@'"),
    ('[zenoh]\nframe_rate_hz = -1\n', {}, "zenoh.frame_rate_hz: must be a rate in Hz"),
    ('[zenoh]\nenabled = "yes"\n', {}, "zenoh.enabled: expected a boolean"),
    ('[zenoh]\nconfig = "absent.json5"\n', {}, "zenoh.config: no such file"),
    ('[zenoh]\nmode = "client"\n', {}, "zenoh.connect: a client needs a router"),
    ('[zenoh]\nenable = true\n', {}, "zenoh.enable: unknown key (known in [zenoh]: enabled"),
    ("", {"TACTILED_ZENOH_CONNECT": "tcp/a:1,,tcp/b"}, "zenoh.connect[1]: 'tcp/b'"),
    ("", {"TACTILED_ZENOH_MULTICAST_SCOUTING": "sometimes"},
     "zenoh.multicast_scouting: expected a boolean"),
])
def test_bad_values_name_the_key(tmp_path: Path, text: str, env: dict, message: str) -> None:
    cfg = None
    if text:
        cfg = tmp_path / "t.toml"
        cfg.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_settings(cfg, env, {})
    assert str(info.value).startswith(message), str(info.value)

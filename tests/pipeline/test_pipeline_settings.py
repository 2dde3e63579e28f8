"""Settings: defaults, precedence (file < environment < overrides), errors naming the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from tactiled.errors import ConfigError
from tactiled.settings import DEFAULT_PORT, DEFAULT_URL, load_settings, settings_to_dict

REPO = Path(__file__).resolve().parents[2]


def write(tmp_path: Path, text: str, name: str = "tactiled.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_no_configuration_at_all_gives_one_simulated_finger() -> None:
    s = load_settings(None, {}, {})
    assert [x.name for x in s.sensors] == ["finger0"]
    assert s.sensors[0].url == DEFAULT_URL == "sim://?scene=demo&seed=1"
    assert (s.server.host, s.server.port, s.server.token) == ("127.0.0.1", DEFAULT_PORT, None)
    assert s.sensors[0].model == "auto" and s.sensors[0].window == 4
    assert s.record.path is None and s.source is None
    assert s.worker_count() == 1


def test_precedence_file_then_environment_then_overrides(tmp_path: Path) -> None:
    cfg = write(tmp_path, """
[server]
port = 9001
host = "0.0.0.0"
token = "from-file"

[[sensor]]
name = "thumb"
url = "replay://a.tact"
window = 5

[[sensor]]
name = "index"
url = "replay://b.tact"

[fit]
timeout = 0.8
""")
    env = {"TACTILED_SERVER_PORT": "9002", "TACTILED_SENSOR_1_WINDOW": "6",
           "TACTILED_FIT_TIMEOUT": "0.5", "TACTILED_SERVER_TOKEN": "from-env",
           "TACTILED_UNRELATED": "ignored", "PATH": "/bin"}
    overrides = {"server.port": 9003, "sensor[0].model": "sphere"}
    s = load_settings(cfg, env, overrides)
    assert s.server.port == 9003  # overrides beat the environment
    assert s.server.token == "from-env"  # the environment beats the file
    assert s.server.host == "0.0.0.0"  # the file beats the defaults
    assert s.fit.timeout == 0.5
    assert [(x.name, x.window, x.model) for x in s.sensors] == [
        ("thumb", 5, "sphere"), ("index", 6, "auto")]
    assert s.source == str(cfg)
    assert settings_to_dict(s)["server"]["token"] == "***"
    # Without the file, the environment still applies, and TACTILED_CONFIG names the file.
    assert load_settings(None, env, {}).server.port == 9002
    assert load_settings(None, {"TACTILED_CONFIG": str(cfg)}, {}).server.port == 9001


def test_environment_can_add_a_sensor_and_paths_are_relative_to_the_file(tmp_path: Path) -> None:
    (tmp_path / "cal.json").write_text("{}")
    cfg = write(tmp_path, '[[sensor]]\nurl = "replay://x.tact"\ncalibration = "cal.json"\n'
                          '[record]\npath = "rec/{sensor}.tact"\n')
    s = load_settings(cfg, {"TACTILED_SENSOR_1_URL": "replay://y.tact"}, {})
    assert [x.name for x in s.sensors] == ["finger0", "finger1"]
    assert s.sensors[0].calibration == str(tmp_path / "cal.json")
    assert s.record_path("finger1") == tmp_path / "rec" / "finger1.tact"


@pytest.mark.parametrize("text, env, overrides, message", [
    ('[[sensor]]\nurl = "replay://a"\n[[sensor]]\nurl = "foo://bar"\n', {}, {},
     "sensor[1].url: unknown scheme 'foo'"),
    ('[[sensor]]\nurl = "sim://?sed=1"\n', {}, {}, "sensor[0].url: "),
    ('[[sensor]]\nurl = "serial:///dev/ttyUSB0?baud=9600&parity=odd"\n', {}, {},
     "sensor[0].url: "),
    ('[[sensor]]\nurl = "replay://a"\nwindw = 4\n', {}, {}, "sensor[0].windw: unknown key"),
    ('[[sensor]]\nurl = "replay://a"\nmodel = "cone"\n', {}, {},
     "sensor[0].model: must be one of auto, cylinder, sphere, general"),
    ('[[sensor]]\nurl = "replay://a"\nwindow = 1\n', {}, {}, "sensor[0].window: "),
    ('[[sensor]]\nurl = "replay://a"\nnoise_sigma = -0.1\n', {}, {}, "sensor[0].noise_sigma: "),
    ('[[sensor]]\nurl = "replay://a"\nwire_id = 70000\n', {}, {}, "sensor[0].wire_id: "),
    ('[[sensor]]\nname = "a"\nurl = "replay://a"\n[[sensor]]\nname = "a"\nurl = "replay://b"\n',
     {}, {}, "sensor[1].name: 'a' is already"),
    ('[[sensor]]\nname = "bad name"\nurl = "replay://a"\n', {}, {}, "sensor[0].name: "),
    ('[[sensor]]\nurl = "replay://a"\ncalibration = "missing.json"\n', {}, {},
     "sensor[0].calibration: no such file"),
    ('[server]\nport = "80"\n', {}, {}, "server.port: expected an integer"),
    ('[server]\nport = 70000\n', {}, {}, "server.port: must be a TCP port"),
    ('[servr]\nport = 1\n', {}, {}, "servr: unknown section"),
    ('[fit]\nstart_method = "fork"\n', {}, {}, "fit.start_method: must be one of"),
    ('[fit]\ntimeout = 0\n', {}, {}, "fit.timeout: must be a positive"),
    ('[[sensor]]\nurl = "replay://a"\n[[sensor]]\nurl = "replay://b"\n[record]\npath = "r.tact"\n',
     {}, {}, "record.path: must contain '{sensor}'"),
    ("", {"TACTILED_SERVER_PORT": "eighty"}, {}, "server.port: expected an integer"),
    ("", {"TACTILED_SERVER_PROT": "1"}, {}, "server.prot: unknown key"),
    ("", {"TACTILED_SENSOR_3_URL": "replay://a"}, {}, "sensor[3].url: sensor index 3 skips ahead"),
    ("", {}, {"sensor[0].url": "foo://x"}, "sensor[0].url: unknown scheme 'foo'"),
    ("", {}, {"fit.workers": -1}, "fit.workers: "),
    ("", {}, {"fit.workers": "two"}, "fit.workers: expected an integer"),
    ('[[sensor]]\nurl = "replay://a"\nreuse_unchanged = "yes"\n', {}, {},
     "sensor[0].reuse_unchanged: expected a boolean"),
    ("", {}, {"nonsense": 1}, "nonsense: not a configuration key"),
    ('[server]\nallow_origins = "http://a:1"\n', {}, {},
     "server.allow_origins: expected a list of origins"),
    ('[server]\nallow_origins = ["http://a:1/path"]\n', {}, {},
     "server.allow_origins: 'http://a:1/path' is not an origin"),
    ("", {"TACTILED_SERVER_MAX_SUBSCRIBERS": "0"}, {}, "server.max_subscribers: must be"),
    ('[[sensor]]\nurl = "replay://a"\nnoise_sigma = 1e-300\n', {}, {},
     "sensor[0].noise_sigma: must be strain (1 sigma) in 1e-08..0.1"),
])
def test_invalid_configuration_names_the_key(tmp_path: Path, text: str, env: dict,
                                             overrides: dict, message: str) -> None:
    cfg = write(tmp_path, text) if text else None
    with pytest.raises(ConfigError) as info:
        load_settings(cfg, env, overrides)
    assert str(info.value).startswith(message), str(info.value)


def test_server_limits_from_file_and_environment(tmp_path: Path) -> None:
    cfg = write(tmp_path, '[server]\nmax_subscribers = 5\n'
                          'allow_origins = ["http://console.local:8080/", "https://lab.example"]\n')
    s = load_settings(cfg, {}, {})
    assert s.server.max_subscribers == 5
    assert s.server.allow_origins == ("http://console.local:8080", "https://lab.example")
    s = load_settings(cfg, {"TACTILED_SERVER_ALLOW_ORIGINS": "http://a:1, http://b:2"}, {})
    assert s.server.allow_origins == ("http://a:1", "http://b:2")
    assert load_settings(None, {}, {}).server.allow_origins == ()


def test_environment_errors_say_which_variable(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"\(from TACTILED_FIT_TIMEOUT\)"):
        load_settings(None, {"TACTILED_FIT_TIMEOUT": "soon"}, {})


def test_bad_toml_and_missing_file_are_config_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_settings(write(tmp_path, "[server\nport = 1"), {}, {})
    with pytest.raises(ConfigError, match="no such configuration file"):
        load_settings(tmp_path / "absent.toml", {}, {})


def test_the_example_config_is_valid_and_documents_every_key() -> None:
    example = REPO / "deploy" / "tactiled.toml"
    s = load_settings(example, {}, {})
    text = example.read_text(encoding="utf-8")
    data = settings_to_dict(s)
    keys = [k for section in ("server", "fit", "record") for k in data[section]]
    keys += list(data["sensor"][0])
    missing = [k for k in keys if f"{k} =" not in text and f"# {k} =" not in text]
    assert not missing, f"deploy/tactiled.toml does not show {missing}"


def test_a_bad_url_value_is_refused_when_the_daemon_builds_the_source(tmp_path: Path) -> None:
    """The configuration checks a URL's scheme and keys without building its driver; the
    driver checks the values when the daemon builds it, and the error still names the key."""
    from tactiled.pipeline import Daemon

    settings = load_settings(write(tmp_path, '[[sensor]]\nurl = "sim://?seed=x"\n'), {}, {})
    assert settings.sensors[0].url == "sim://?seed=x"
    with pytest.raises(ConfigError) as info:
        Daemon(settings)
    assert str(info.value).startswith("sensor[0].url: "), str(info.value)
    assert "seed" in str(info.value)


def test_loading_settings_imports_no_driver_and_no_pipeline(tmp_path: Path) -> None:
    """A configuration of every shipped driver's URL loads (with each vendor device's own
    description) in a fresh interpreter that never imports a driver module or the pipeline."""
    import subprocess
    import sys

    cfg = write(tmp_path, "".join(f'[[sensor]]\nname = "s{i}"\nurl = "{url}"\n' for i, url in enumerate((
        "serial:///dev/ttyUSB0?baud=115200", "sim://?scene=demo", "replay://r.tact",
        "lines:///dev/ttyACM0?rows=8&cols=8", "flexitac:///dev/ttyUSB1", "robotiq:///dev/ttyUSB2",
        "xela://localhost:5000?rows=4&cols=6", "paxini:///dev/ttyUSB3?rows=4&cols=4"))))
    code = (
        "import sys\n"
        "from tactiled.settings import load_settings\n"
        f"s = load_settings({str(cfg)!r}, {{}}, {{}})\n"
        "print([x.description for x in s.sensors])\n"
        "print(sorted(m for m in sys.modules if m.startswith(('tactiled_drivers', 'tactiled.pipeline',"
        " 'serial', 'websockets'))))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         check=True).stdout.splitlines()
    assert out[0] == str(["fearing1988", "fearing1988", "fearing1988", "fearing1988",
                          "flexitac_12x32", "robotiq_tsf85", "xela_uskin_4x6", "fearing1988"])
    assert out[1] == "[]"

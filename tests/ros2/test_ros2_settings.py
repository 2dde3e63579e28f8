"""The [ros2] section and [record] format: defaults, the environment, errors naming the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from tactiled.errors import ConfigError
from tactiled.settings import Ros2Settings, load_settings


def test_defaults_are_off_and_documented() -> None:
    s = load_settings(None, {}, {})
    assert s.ros2 == Ros2Settings(enabled=False, domain_id=0, namespace="/tactiled",
                                  node_name="tactiled", frame_id="{sensor}")
    assert s.record.format == "tact"


def test_the_environment_and_a_file_set_them(tmp_path: Path) -> None:
    cfg = tmp_path / "t.toml"
    cfg.write_text('[zenoh]\nenabled = true\n[ros2]\nenabled = true\nnamespace = "/hand/left"\n'
                   'frame_id = "left_{sensor}"\n[record]\npath = "rec/{sensor}.tact"\n'
                   'format = "both"\n')
    s = load_settings(cfg, {"TACTILED_ROS2_DOMAIN_ID": "42"}, {})
    assert (s.ros2.enabled, s.ros2.domain_id, s.ros2.namespace, s.ros2.frame_id) == (
        True, 42, "/hand/left", "left_{sensor}")
    assert s.record_path("finger0") == tmp_path / "rec" / "finger0.tact"
    assert s.mcap_record_path("finger0") == tmp_path / "rec" / "finger0.mcap"
    only = load_settings(cfg, {"TACTILED_RECORD_FORMAT": "mcap"}, {})
    assert only.record_path("finger0") is None
    assert only.mcap_record_path("finger0") == tmp_path / "rec" / "finger0.mcap"
    assert load_settings(cfg, {"TACTILED_RECORD_FORMAT": "tact"}, {}).mcap_record_path("x") is None


@pytest.mark.parametrize(("overrides", "message"), [
    ({"ros2.enabled": True, "ros2.middleware": "zenoh"},
     "ros2.middleware: 'zenoh' publishes on the daemon's Zenoh session"),
    ({"ros2.enabled": True, "ros2.middleware": "both"}, "set zenoh.enabled = true as well"),
    ({"ros2.middleware": "rtps"}, "ros2.middleware: must be one of auto, dds, zenoh, both"),
    ({"ros2.distro": "iron"}, "ros2.distro: must be one of humble, jazzy, kilted, rolling"),
    ({"ros2.domain_id": 233}, "ros2.domain_id: must be a ROS domain id in 0..232"),
    ({"ros2.namespace": "tactiled"}, "ros2.namespace: must be '/' or /name"),
    ({"ros2.namespace": "/a//b"}, "ros2.namespace: must be '/' or /name"),
    ({"ros2.namespace": "/a/"}, "ros2.namespace: must be '/' or /name"),
    ({"ros2.node_name": "my-node"}, "ros2.node_name: must be letters, digits and '_'"),
    ({"ros2.node_name": "a__b"}, "without '__'"),
    ({"ros2.bogus": 1}, "ros2.bogus: unknown key (known in [ros2]: enabled, domain_id"),
    ({"record.format": "bag"}, "record.format: must be one of tact, mcap, both"),
])
def test_bad_values_name_the_key(overrides: dict, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_settings(None, {}, overrides)
    assert message in str(err.value)


@pytest.mark.parametrize(("zenoh", "middleware", "expected"), [
    (False, "auto", ("dds",)), (True, "auto", ("zenoh",)), (False, "dds", ("dds",)),
    (True, "dds", ("dds",)), (True, "zenoh", ("zenoh",)), (True, "both", ("dds", "zenoh"))])
def test_the_middleware_defaults_to_zenoh_with_zenoh_else_dds(
        zenoh: bool, middleware: str, expected: tuple[str, ...]) -> None:
    s = load_settings(None, {"TACTILED_ROS2_MIDDLEWARE": middleware},
                      {"ros2.enabled": True, "zenoh.enabled": zenoh})
    assert s.ros2.middlewares(s.zenoh.enabled) == expected


def test_root_namespace_and_valid_names_pass() -> None:
    s = load_settings(None, {}, {"zenoh.enabled": True, "ros2.enabled": True,
                                 "ros2.namespace": "/", "ros2.node_name": "_tactile2"})
    assert (s.ros2.namespace, s.ros2.node_name) == ("/", "_tactile2")


def test_the_example_config_shows_every_ros2_key() -> None:
    from tactiled.settings import settings_to_dict

    example = Path(__file__).resolve().parents[2] / "deploy" / "tactiled.toml"
    text = example.read_text()
    s = load_settings(example, {}, {})
    assert s.ros2 == Ros2Settings() and s.record.format == "tact"
    missing = [k for k in settings_to_dict(s)["ros2"] if f"\n{k} =" not in text]
    assert not missing, missing


def test_an_mcap_recording_never_overwrites_one(tmp_path: Path) -> None:
    from tactiled_service.ros2.mcap_file import fresh_path

    path = tmp_path / "finger0.mcap"
    assert fresh_path(path) == path
    path.write_bytes(b"earlier")
    again = fresh_path(path, now=1795309645.0)
    assert again.parent == tmp_path and again.suffix == ".mcap"
    assert again.name == "finger0-20261122T010725Z.mcap" and not again.exists()

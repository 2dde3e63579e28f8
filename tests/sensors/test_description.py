"""Sensor descriptions: the built-ins, the keys, the wiring, and every bad file refused with
the key it names."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from tactiled.sensors.model import SensorModel
from tactiled.errors import ConfigError
from tactiled.sensors import builtin_names, load_description
from tactiled.sensors.description import parse_description_text

GOOD = """
name = "pad"
rows = 4
cols = 3
pitch_x_mm = 2.0
pitch_y_mm = 3.0
"""


def test_every_builtin_loads_and_says_where_its_numbers_come_from() -> None:
    names = builtin_names()
    assert {"fearing1988", "flat16", "robotiq_tsf85", "flexitac_12x32", "xela_uskin_4x4"} <= set(names)
    for name in names:
        d = load_description(name)
        assert d.name == name
        assert d.sources, f"{name} has no source comment"
        d.sensor_model()  # a valid physics model
        if name != "fearing1988":
            assert d.flat and d.nominal, f"{name}: a vendor array's cover is nominal until identified"


def test_the_default_is_the_papers_finger_exactly() -> None:
    assert load_description().sensor_model() == SensorModel()
    assert load_description("fearing1988").surface_radius_mm == 12.7


def test_a_description_round_trips_through_toml(tmp_path) -> None:
    for name in builtin_names():
        d = load_description(name)
        path = tmp_path / f"{name}.toml"
        path.write_text(d.to_toml())
        again = load_description(str(path))
        assert again == d and again.fingerprint() == d.fingerprint()


@pytest.mark.parametrize("line, key", [
    ("rows = 1", "rows"), ("rows = 4.5", "rows"), ("cols = 99", "cols"),
    ("pitch_x_mm = -1", "pitch_x_mm"), ("pitch_y_mm = nan", "pitch_y_mm"),
    ("surface_radius_mm = 0", "surface_radius_mm"), ("depth_x_mm = 0.1", "depth_x_mm"),
    ("nu_y = 2", "nu_y"), ("modulus_n_mm2 = true", "modulus_n_mm2"),
    ("noise_sigma = 0", "noise_sigma"), ("wire_order = 'zigzag'", "wire_order"),
    ("wire_order = [0, 1, 2]", "wire_order"), ("dead = [[4, 0]]", "dead"),
    ("colour = 'red'", "colour"), ("name = 'a b'", "name"),
])
def test_a_bad_key_is_named(line: str, key: str) -> None:
    # a repeated key is a TOML error: the bad line replaces the good one
    k = line.split("=")[0].strip()
    lines = [x for x in GOOD.strip().splitlines() if not x.startswith(k + " ")]
    text = "\n".join(lines) + "\n" + line + "\n"
    with pytest.raises(ConfigError, match=f"key '{key}'"):
        parse_description_text(text, "test.toml")


def test_missing_required_keys_and_unreadable_files_are_refused(tmp_path) -> None:
    with pytest.raises(ConfigError, match="key 'pitch_y_mm': is missing"):
        parse_description_text('name = "x"\nrows = 4\ncols = 4\npitch_x_mm = 2\n', "t")
    with pytest.raises(ConfigError, match="not valid TOML"):
        parse_description_text("rows = = 4", "t")
    with pytest.raises(ConfigError, match="none.toml: no such file"):
        load_description(str(tmp_path / "none.toml"))
    with pytest.raises(ConfigError, match="is a directory"):
        load_description(str(tmp_path) + "/")
    with pytest.raises(ConfigError, match="no built-in sensor description 'nope'.*flat16"):
        load_description("nope")


def test_flat_is_an_infinite_radius_or_none_at_all() -> None:
    d = parse_description_text(GOOD, "t")
    assert d.flat and d.geometry().flat and math.isinf(d.geometry().finger_radius)
    curved = parse_description_text(GOOD + "surface_radius_mm = 10.0\n", "t")
    assert not curved.flat and curved.geometry().finger_radius == 10.0


def test_wire_orders_put_counts_on_the_grid() -> None:
    grid = np.arange(12).reshape(4, 3)
    row = parse_description_text(GOOD, "t")
    assert np.array_equal(row.to_grid(grid.ravel()), grid)
    col = parse_description_text(GOOD + 'wire_order = "column-major"\n', "t")
    assert np.array_equal(col.to_grid(grid.T.ravel()), grid)  # wire: column by column
    snake = parse_description_text(GOOD + 'wire_order = "serpentine-rows"\n', "t")
    wire = np.array([0, 1, 2, 5, 4, 3, 6, 7, 8, 11, 10, 9])  # odd rows read right to left
    assert np.array_equal(snake.to_grid(wire), grid)
    explicit = parse_description_text(GOOD + f"wire_order = {list(range(11, -1, -1))}\n", "t")
    assert np.array_equal(explicit.to_grid(grid.ravel()[::-1]), grid)
    for d in (row, col, snake, explicit):
        assert np.array_equal(d.to_grid(d.to_wire(grid)), grid)


def test_dead_tactels_make_a_mask() -> None:
    d = parse_description_text(GOOD + "dead = [[0, 1], [3, 2]]\n", "t")
    mask = d.dead_mask()
    assert mask.sum() == 10 and not mask[0, 1] and not mask[3, 2]
    assert parse_description_text(GOOD, "t").dead_mask() is None


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tactiled.cli", *args], capture_output=True,
                          text=True, timeout=60)


def test_the_sensors_command_lists_shows_and_checks(tmp_path) -> None:
    out = _cli("sensors")
    assert out.returncode == 0 and "flat16" in out.stdout and "robotiq_tsf85" in out.stdout
    shown = _cli("sensors", "show", "xela_uskin_4x4")
    assert shown.returncode == 0
    path = tmp_path / "x.toml"
    path.write_text(shown.stdout)
    assert load_description(str(path)) == load_description("xela_uskin_4x4")
    ok = _cli("sensors", "check", str(path))
    assert ok.returncode == 0 and "4x4" in ok.stdout
    bad = tmp_path / "bad.toml"
    bad.write_text(GOOD.replace("pitch_x_mm = 2.0", "pitch_x_mm = -2.0"))
    for args in (("sensors", "check", str(bad)), ("sensors", "show", "nope"), ("sensors", "check")):
        res = _cli(*args)
        assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
        assert res.stderr.startswith("tactiled sensors: error:")
    assert "key 'pitch_x_mm'" in _cli("sensors", "check", str(bad)).stderr


def test_the_cramer_rao_window_rule_gives_the_papers_4x4_on_its_finger() -> None:
    from tactiled.sensors.window import information, recommended

    sensor = load_description("fearing1988").sensor_model()
    info = information(sensor)
    assert min(info[8].values()) == pytest.approx(1.0)
    assert min(info[3].values()) < 0.9 <= min(info[4].values())
    assert recommended(sensor) == 4 == load_description("fearing1988").window
    # on a 4x6 array only the whole array keeps 90 % of a line's information
    assert recommended(load_description("xela_uskin_4x6").sensor_model()) == 6

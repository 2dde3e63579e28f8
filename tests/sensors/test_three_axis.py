"""The `axes` key: 3-axis descriptions read, validate, round-trip; 1-axis ones are unchanged."""

import pytest

from tactiled.errors import ConfigError
from tactiled.sensors import load_description
from tactiled.sensors.description import parse_description, parse_description_text

BASE = {"name": "pad", "rows": 4, "cols": 4, "pitch_x_mm": 4.7, "pitch_y_mm": 4.7}


def test_xela_builtins_are_three_axis():
    for name in ("xela_uskin_4x4", "xela_uskin_4x6"):
        d = load_description(name)
        assert d.axes == 3 and d.taxel_depth_mm > 0 and len(d.axis_gain) == 3 and len(d.axis_noise) == 3
        assert parse_description_text(d.to_toml(), "again") == d
        assert d.summary()["axis_gain"] == list(d.axis_gain)


def test_one_axis_default_hides_the_three_axis_keys():
    d = parse_description(dict(BASE))
    assert d.axes == 1
    assert "axes" not in d.to_toml() and "axis_gain" not in d.summary()
    # the fingerprint of a 1-axis description does not see the new keys
    assert d.fingerprint() == parse_description(dict(BASE)).fingerprint()


@pytest.mark.parametrize("extra,key", [
    ({"axes": 2}, "axes"),
    ({"axes": 3}, "taxel_depth_mm"),
    ({"axes": 3, "taxel_depth_mm": 3.0}, "axis_gain"),
    ({"axes": 3, "taxel_depth_mm": 3.0, "axis_gain": [1, 1], "axis_noise": [1, 1, 1]}, "axis_gain"),
    ({"axes": 3, "taxel_depth_mm": 3.0, "axis_gain": [1, 1, 1], "axis_noise": [1, -1, 1]}, "axis_noise"),
    ({"axes": 3, "taxel_depth_mm": 99.0, "axis_gain": [1, 1, 1], "axis_noise": [1, 1, 1]}, "taxel_depth_mm"),
    ({"axis_gain": [1, 1, 1]}, "axis_gain"),
])
def test_bad_three_axis_keys_are_named(extra, key):
    with pytest.raises(ConfigError, match=repr(key)):
        parse_description({**BASE, **extra})

"""``tactiled simulate --as KIND --sensor NAME`` plays the named array on the device: any shape
on a text-lines pad or a FlexiTac mat, XELA's 4x6 patch, and a shape the device cannot have is
refused with one line naming both.  (A daemon fitting a 16x16 pad played this way:
tests/service/test_vendor_devices.py.)"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from tactiled.commands.simulate_as import XELA_MODELS, simulated_array
from tactiled.sensors import load_description

TACTILED = Path(sys.executable).with_name("tactiled")


def array(kind: str, sensor: str | None):
    return simulated_array(argparse.Namespace(as_kind=kind, sensor=sensor))


@pytest.mark.parametrize("kind,sensor", [("lines", "flat16"), ("lines", "flat32"),
                                         ("flexitac", "flat16"), ("xela", "xela_uskin_4x6"),
                                         ("robotiq", "robotiq_tsf85")])
def test_the_named_array_is_played(kind: str, sensor: str) -> None:
    got, desc = array(kind, sensor), load_description(sensor)
    assert got.shape == (desc.rows, desc.cols)
    g = got.model.geometry
    assert (g.dx, g.dy) == (desc.pitch_x_mm, desc.pitch_y_mm)
    assert got.description == desc.name
    # the counts' scaling stays the device's (FlexiTac's 8 bits)
    assert got.counts_per_strain == array(kind, None).counts_per_strain


def test_without_sensor_each_device_plays_its_own_array() -> None:
    assert array("lines", None).shape == (8, 8)
    assert array("xela", None).shape == (4, 4)
    assert XELA_MODELS[array("xela", "xela_uskin_4x6").shape] == "XR1946"


def test_a_shape_the_device_cannot_have_is_refused_with_one_line() -> None:
    done = subprocess.run([str(TACTILED), "simulate", "--as", "robotiq", "--sensor", "flat16",
                           "--device", "/tmp/never-made"], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 2
    assert done.stderr.splitlines() == [
        "tactiled simulate: error: --sensor flat16 is 16x16, but a robotiq device's array is 7x4"]
    assert not Path("/tmp/never-made").exists()

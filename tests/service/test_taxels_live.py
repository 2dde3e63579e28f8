"""A 3-axis array's zeroed readings live on Zenoh and ROS 2: a real `tactiled run --ros2` (a
separate process) on a simulated 3-axis XELA patch (``sim://`` on ``xela_uskin_4x4`` playing
its pull scene at 200 Hz), with a loopback Zenoh port and multicast scouting off.

A plain Zenoh client hears, at once, the JSON frames under ``P/xela/frame`` (the WebSocket
stream's frame message: ``taxels`` ``(rows, cols, 3)``) and the ROS 2 topic
``/tactiled/xela/taxels`` (rmw_zenoh's key expression): every image payload decodes with the
MCAP project's ROS 2 decoder (an implementation that is not ours) as ``sensor_msgs/Image``
``32FC3``, and each equals the JSON frame of the same stamp, x, y, z.  The publisher's
liveliness token names the topic and type.  The fit workers are not awaited (frames and their
readings do not need them), so the test takes seconds; waits have deadlines.
"""

from __future__ import annotations

import functools
import json
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import zenoh
from mcap_ros2._dynamic import generate_dynamic
from test_ros2_node import client, free_port, wait_for

from tactiled_service.ros2 import messages, rmw

PREFIX = "tactiled/taxels-test"
SENSOR = "xela"


@functools.cache
def _decoder() -> Callable[[bytes], Any]:
    typename = messages.TYPES["taxels"]
    name = typename.replace("/msg/", "/")
    return generate_dynamic(name, messages.definition(typename))[name]


def _decode(payload: bytes) -> Any:
    """A taxels payload decoded by the MCAP project's ROS 2 decoder."""
    return _decoder()(payload)


def _z(payload: bytes) -> np.ndarray:
    """The z channel of a taxels image's payload."""
    return np.frombuffer(bytes(_decode(payload).data), "<f4")[2::3]


@pytest.fixture(scope="module")
def heard(daemon_process: Callable[..., Any]) -> dict[str, Any]:
    """Some seconds of a 3-axis daemon's JSON frames and ROS 2 taxels images, and its tokens."""
    port = free_port()
    env = {"TACTILED_ZENOH_MULTICAST_SCOUTING": "false", "TACTILED_ZENOH_PREFIX": PREFIX,
           "TACTILED_ZENOH_LISTEN": f"tcp/127.0.0.1:{port}", "TACTILED_ZENOH_FRAME_RATE_HZ": "1000",
           "TACTILED_FIT_WORKERS": "1", "TACTILED_FIT_STARTUP_TIMEOUT": "0.5",
           "TACTILED_SENSOR_0_NAME": SENSOR, "TACTILED_SENSOR_0_DESCRIPTION": "xela_uskin_4x4",
           "TACTILED_SENSOR_0_URL": "sim://?sensor=xela_uskin_4x4&scene=pull&seed=2&rate=200"}
    proc = daemon_process(["--port", "0", "--ros2"], env=env)
    try:
        proc.wait_url()
        raw = client(f"tcp/127.0.0.1:{port}")
        try:
            images = raw.declare_subscriber(f"0/tactiled/{SENSOR}/taxels/**",
                                            zenoh.handlers.FifoChannel(100_000))
            frames = raw.declare_subscriber(f"{PREFIX}/{SENSOR}/frame",
                                            zenoh.handlers.FifoChannel(100_000))
            got: dict[str, list[Any]] = {"images": [], "frames": []}

            def drain() -> bool:
                while (s := images.try_recv()) is not None:
                    got["images"].append((str(s.key_expr), s.payload.to_bytes()))
                while (s := frames.try_recv()) is not None:
                    got["frames"].append(json.loads(s.payload.to_bytes()))
                pressed = [f for f in got["frames"] if "taxels" in f
                           and np.asarray(f["taxels"])[..., 2].max() > 50]
                pressed_images = [p for _k, p in got["images"] if _z(p).max() > 50]
                return len(got["images"]) >= 40 and min(len(pressed), len(pressed_images)) >= 5

            wait_for(drain, 120, "taxels images and JSON frames of a press")
            tokens = [str(r.ok.key_expr) for r in raw.liveliness().get("@ros2_lv/0/**", timeout=3)
                      if r.ok is not None]
        finally:
            raw.close()
    finally:
        proc.terminate()
    return {**got, "tokens": tokens}


def test_the_json_frames_carry_the_readings(heard: dict[str, Any]) -> None:
    with_taxels = [f for f in heard["frames"] if "taxels" in f]
    assert with_taxels, "no JSON frame carried taxels"
    for f in with_taxels:
        assert (f["rows"], f["cols"]) == (4, 4)
        assert np.asarray(f["taxels"]).shape == (4, 4, 3)


def test_the_ros2_taxels_image_is_the_frames_readings(heard: dict[str, Any]) -> None:
    typename = messages.TYPES["taxels"]
    frames = sorted((f["time"], np.asarray(f["taxels"])) for f in heard["frames"] if "taxels" in f)
    times = np.array([t for t, _ in frames])
    matched = 0
    for key, payload in heard["images"]:
        parts = key.split("/")
        assert parts[-2] == rmw.dds_type(typename) and parts[-1] == messages.type_hash(typename)
        im = _decode(payload)
        assert (im.encoding, im.height, im.width, im.step, im.is_bigendian) == ("32FC3", 4, 4, 48, 0)
        assert im.header.frame_id == SENSOR
        data = np.frombuffer(bytes(im.data), "<f4").reshape(4, 4, 3)
        stamp = im.header.stamp.sec + im.header.stamp.nanosec * 1e-9
        k = int(np.argmin(np.abs(times - stamp)))
        if abs(times[k] - stamp) < 2e-6:  # the JSON rounds to 3 decimals; the image is float32
            np.testing.assert_allclose(data, frames[k][1], rtol=1e-6, atol=6e-4)
            matched += 1
    assert matched >= 20, f"{matched} of {len(heard['images'])} images matched a JSON frame"
    # a press: z (into the cover) well past the noise on some image, near zero on others
    zs = [_z(p) for _k, p in heard["images"]]
    assert max(z.max() for z in zs) > 50 and min(np.abs(z).max() for z in zs) < 20


def test_the_taxels_publisher_is_announced(heard: dict[str, Any]) -> None:
    from test_ros2_rmw import parse_token

    pubs = {parse_token(t).get("topic"): parse_token(t).get("type") for t in heard["tokens"]
            if parse_token(t)["entity"] == "MP" and parse_token(t)["node"] == "tactiled"}
    assert pubs[f"/tactiled/{SENSOR}/taxels"] == "sensor_msgs::msg::dds_::Image_"
    assert pubs[f"/tactiled/{SENSOR}/strain"] == "sensor_msgs::msg::dds_::Image_"

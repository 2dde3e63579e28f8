"""The core and the Python reference publish the same estimates and count the same frames for
hypothesis-drawn streams: contacts pressed, held, rolled and lifted at drawn places, radii and
forces, with hostile frames among them (saturated and empty arrays, a spike, frames of another
shape or another sensor, seq numbers repeated or jumping, the device clock running back).

Both run in child processes (tests/native/published.py; the core cannot be unloaded from this
one), one with ``TACTILED_CORE=native`` and one with ``TACTILED_CORE=python``, with their
numerics pinned to baseline x86-64 as the golden replays are (``regen_golden.PINNED_ENV``):
every frame and fit of one stream runs in each, and the answers are compared as the golden
replays compare theirs (``regen_golden.compare``: strings, integers, booleans and nulls exactly),
floats within a relative 1e-6 or 1e-6 of their sigma (``REL_TOL``).  The core's fit stages agree with their
references to rtol 1e-9 (tests/native/test_core_stages.py), its tracker's to 1e-9 or bit for
bit (test_tracker_core.py), so a difference past that is a core that computes something else.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from tactiled import native
from tactiled.frames import Frame
from tactiled.physics.contact import Contact

TESTS = Path(__file__).resolve().parents[1]
for _where in ("native", "pipeline", "reliability"):  # the helpers beside their tests
    if str(TESTS / _where) not in sys.path:
        sys.path.insert(0, str(TESTS / _where))
import regen_golden as g  # noqa: E402
from pipeline_helpers import make_frames  # noqa: E402
from published import save_frames  # noqa: E402

pytestmark = pytest.mark.skipif(native.core is None,
                                reason="TACTILED_CORE=python: no core to compare")

SERVER = Path(__file__).with_name("published.py")
#: floats agree within this, relative (or this much of their sigma): the fits agree to 1e-9
#: (test_core_stages.py), and the tracker's filters carry such differences from frame to frame
#: through a stream (2e-9 seen after 80 frames); a fit that took another path differs in its
#: iterations, verdicts and values far beyond it
REL_TOL = 1e-6
ROOT = TESTS.parent
#: the sensor's settings in both (the defaults: tracking and hysteresis on; wire id 0, so a
#: frame of another sensor is counted and dropped)
SETTINGS = {"name": "f", "url": "sim://", "wire_id": 0}


class Server:
    """One child serving :mod:`published` requests under ``TACTILED_CORE=core``."""

    def __init__(self, core: str) -> None:
        env = {**os.environ, **g.PINNED_ENV, "TACTILED_CORE": core}
        self.proc = subprocess.Popen([sys.executable, str(SERVER)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True, env=env, cwd=ROOT)

    def ask(self, frames_path: Path) -> dict:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps({"settings": SETTINGS, "frames": str(frames_path)})
                              + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        assert line, f"the server under {self.proc.args} ended ({self.proc.poll()})"
        out = json.loads(line)
        assert "error" not in out, out["error"]
        return out

    def close(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        self.proc.wait(timeout=30)


@pytest.fixture(scope="module")
def servers() -> Iterator[tuple[Server, Server]]:
    pair = Server("native"), Server("python")
    yield pair
    for s in pair:
        s.close()


# --- streams -------------------------------------------------------------------------------

@st.composite
def contact(draw: st.DrawFn) -> Contact:
    r1 = draw(st.floats(3.0, 30.0))
    shape = draw(st.sampled_from(["cylinder", "sphere", "general"]))
    r2 = {"cylinder": math.inf, "sphere": r1}.get(shape) or r1 * draw(st.floats(1.2, 4.0))
    return Contact(r1, r2, draw(st.floats(30.0, 150.0)), draw(st.floats(0.2, 3.0)),
                   draw(st.floats(6.0, 17.0)), draw(st.floats(7.0, 20.0)))


@st.composite
def scene(draw: st.DrawFn) -> list[Contact | None]:
    """Pieces of no contact, a held contact, or one that moves (a drawn step per frame)."""
    out: list[Contact | None] = []
    for _ in range(draw(st.integers(1, 3))):
        n = draw(st.integers(3, 25))
        kind = draw(st.sampled_from(["none", "held", "moving"]))
        if kind == "none":
            out += [None] * n
            continue
        c = draw(contact())
        dx, df = (draw(st.floats(-0.1, 0.1)), draw(st.floats(-0.02, 0.02))) \
            if kind == "moving" else (0.0, 0.0)
        out += [Contact(c.r1, c.r2, c.psi_deg, max(0.1, c.force + k * df),
                        min(18.0, max(5.0, c.x0 + k * dx)), c.y0) for k in range(n)]
    return out


HOSTILE = ("saturated", "empty", "spike", "shape", "sensor", "seq_repeat", "seq_jump",
           "clock_back")


def spoil(frames: list[Frame], edits: list[tuple[int, str]]) -> list[Frame]:
    """``frames`` with hostile frames put in after the settling frames (index, kind)."""
    out = list(frames)
    for index, kind in edits:
        i = min(index, len(out) - 1)
        f = out[i]
        raw = f.raw.copy()
        if kind == "saturated":
            raw[:] = 65535
        elif kind == "empty":
            raw[:] = 0
        elif kind == "spike":
            raw[i % raw.shape[0], (3 * i) % raw.shape[1]] = 65535
        elif kind == "shape":
            raw = raw[:, :-1].copy()
        new = Frame(seq=f.seq, device_time_us=f.device_time_us, raw=raw, sensor_id=f.sensor_id)
        if kind == "sensor":
            new.sensor_id = 3
        elif kind == "seq_repeat" and i > 0:
            new.seq = out[i - 1].seq
        elif kind == "seq_jump":
            new.seq = f.seq + 1000
        elif kind == "clock_back" and i > 0:
            new.device_time_us = max(0, out[i - 1].device_time_us - 20_000)
        out[i] = new
    return out


@settings(max_examples=10, deadline=None, derandomize=True, phases=[Phase.generate],
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                 HealthCheck.function_scoped_fixture])
@given(contacts=scene(), seed=st.integers(0, 2**16),
       sigma=st.sampled_from([0.0003, 0.0005, 0.001]),
       edits=st.lists(st.tuples(st.integers(60, 140), st.sampled_from(HOSTILE)), max_size=4))
def test_the_core_publishes_what_the_reference_does(servers, tmp_path_factory, contacts, seed,
                                                    sigma, edits) -> None:
    frames = spoil(make_frames(contacts, seed=seed, tail=8, sigma=sigma), edits)
    path = save_frames(tmp_path_factory.mktemp("stream") / "frames.npz", frames)
    core, reference = (s.ask(path) for s in servers)
    assert reference["counters"]["frames"] == len(frames)
    assert len(reference["estimates"]) == reference["counters"]["published"]
    diffs = g.compare(reference, core, rel_tol=REL_TOL)
    assert not diffs, (f"{len(diffs)} difference(s), first: {diffs[:8]} (seed {seed}, sigma "
                       f"{sigma}, edits {edits}, scene {contacts})")

"""The compiled core is built by the package install and agrees with the Python reference."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from tactiled import native
from tactiled.physics.impulse import line_response


def test_the_install_built_the_core() -> None:
    from tactiled import _core

    assert _core.ABI == native.ABI
    assert native.name() == ("python" if os.environ.get("TACTILED_CORE") == "python" else "native")


def test_tactiled_core_python_selects_the_reference_in_a_child() -> None:
    code = "from tactiled import native; print(native.name(), native.core)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "TACTILED_CORE": "python"}).stdout.split()
    assert out == ["python", "None"]


def test_an_unknown_choice_is_refused_naming_it() -> None:
    run = subprocess.run([sys.executable, "-c", "import tactiled.native"], capture_output=True,
                         text=True, env={**os.environ, "TACTILED_CORE": "fast"})
    assert run.returncode != 0 and "TACTILED_CORE='fast'" in run.stderr


@settings(max_examples=200, deadline=None)
@given(u=arrays(np.float64, st.integers(0, 40),
                elements=st.floats(-1e3, 1e3, allow_nan=False)),
       depth=st.floats(0.5, 20.0), nu=st.floats(0.0, 0.9))
def test_line_response_equals_the_reference(u: np.ndarray, depth: float, nu: float) -> None:
    from tactiled import _core

    got = _core.line_response(u, depth, nu)
    want = line_response(u, depth, nu)
    assert got.shape == u.shape
    np.testing.assert_allclose(got, want, rtol=1e-14, atol=1e-300)

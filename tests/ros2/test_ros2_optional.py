"""The ros2 extra stays optional: the core never imports it (nor Zenoh), and without it the
commands that need it refuse with one line naming the extra."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RECORDING = ROOT / "tests" / "data" / "golden" / "press.tact"


def run(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)


def test_the_core_imports_neither_rosbags_mcap_nor_zenoh() -> None:
    done = run("import importlib, pkgutil, sys, tactiled\n"
               "for m in pkgutil.walk_packages(tactiled.__path__, 'tactiled.'):\n"
               "    importlib.import_module(m.name)\n"
               "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
               "('rosbags', 'mcap', 'mcap_ros2', 'zenoh', 'xxhash', 'tactiled_service'))\n"
               "print(bad); sys.exit(1 if bad else 0)")
    assert done.returncode == 0, done.stdout + done.stderr


def test_export_without_the_extra_names_it(tmp_path: Path) -> None:
    out = tmp_path / "x.mcap"
    done = run("import sys; sys.modules['rosbags'] = None\n"
               "from tactiled.cli import main\n"
               f"sys.exit(main(['export', {str(RECORDING)!r}, '-o', {str(out)!r}]))")
    assert done.returncode == 2, done.stderr
    assert "writing MCAP needs the ros2 extra: pip install 'tactiled[ros2]'" in done.stderr
    assert "Traceback" not in done.stderr and not out.exists()
    npz = tmp_path / "x.npz"  # the arrays need nothing optional
    done = run("import sys; sys.modules['rosbags'] = None; sys.modules['zenoh'] = None\n"
               "from tactiled.cli import main\n"
               f"sys.exit(main(['export', {str(RECORDING)!r}, '-o', {str(npz)!r}]))")
    assert done.returncode == 0 and npz.stat().st_size > 0, done.stderr


def test_run_with_ros2_but_without_the_extra_is_a_config_error() -> None:
    done = run("import sys; sys.modules['rosbags'] = None\n"
               "from tactiled.settings import load_settings\n"
               "from tactiled_service.server import load_ros2\n"
               "s = load_settings(None, {}, {'zenoh.enabled': True, 'ros2.enabled': True})\n"
               "try:\n    load_ros2(s)\nexcept Exception as e:\n    print(e); sys.exit(3)")
    assert done.returncode == 3, done.stderr
    assert done.stdout.startswith("ros2.enabled: ROS 2 messages need the ros2 extra: pip "
                                  "install 'tactiled[ros2]'"), done.stdout

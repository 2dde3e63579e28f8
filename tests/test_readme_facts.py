"""The README's facts about the code: what its example commands say they do is what they do."""

import re
from pathlib import Path

from tactiled.settings import load_settings

ROOT = Path(__file__).resolve().parents[1]
NUMBERS = {"one": 1, "two": 2, "three": 3, "four": 4, "five": 5, "six": 6}


def test_the_example_config_runs_the_fingers_the_readme_says() -> None:
    readme = (ROOT / "README.md").read_text()
    claim = re.search(r"tactiled run --config deploy/tactiled\.toml\s+# (\w+) simulated fingers?",
                      readme)
    assert claim, "the README no longer says what deploy/tactiled.toml runs"
    settings = load_settings(ROOT / "deploy" / "tactiled.toml", {}, {})
    assert all(s.url.startswith("sim://") for s in settings.sensors)
    assert NUMBERS[claim.group(1)] == len(settings.sensors), (claim.group(0), len(settings.sensors))

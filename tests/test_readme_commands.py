"""The README's two commands are the project's contract: CI must run exactly the second."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    section = text.split("## Two commands", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```sh\n(.*?)```", section, re.S)
    return [next(l for l in b.splitlines() if l and not l.startswith("#")) for b in blocks]


def test_readme_has_exactly_two_commands():
    assert len(readme_commands()) == 2


def test_ci_runs_the_second_command():
    ci = [l for l in (ROOT / ".ci" / "run").read_text().splitlines() if l and not l.startswith(("#", "set ", "cd "))]
    assert ci == [readme_commands()[1]]

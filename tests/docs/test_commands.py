"""Every ``tactiled ...`` command shown in a code block of the docs or the README is one the
real parser accepts, with its flags: each line is given to ``tactiled.cli.build_parser()`` as a
user would type it.  Nothing is skipped silently: the test counts the commands it read per
file, and a block that names ``tactiled`` in a way it cannot parse fails."""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

from tactiled.cli import COMMANDS, build_parser

ROOT = Path(__file__).resolve().parents[2]
FENCE = re.compile(r"(?ms)^([ \t]*)```([\w-]*)[^\n]*\n(.*?)^\1```")
#: Where a shell command line may call the program: plain, from a venv, through python -m.
PROGRAM = re.compile(r"^(?:\S*/)?tactiled$")
#: Shell words that end one command (the rest of the line is another command or a redirection).
SEPARATORS = {"|", "||", "&&", ";", "&"}
#: A line that may call the program (others, e.g. a tree listing of ``tactiled/``, are not shell).
WRAPPERS = {"sudo", "env", "nice", "timeout", "exec", "time"}
MENTION = re.compile(r"(?:^|[\s/])tactiled(?:\s|$)")


def documents() -> list[Path]:
    return sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]


def shell_lines(block: str) -> list[str]:
    """The block's lines, continuation lines joined, prompts (``$ ``) removed."""
    lines, current = [], ""
    for raw in block.splitlines():
        line = raw.rstrip()
        if line.endswith("\\"):
            current += line[:-1] + " "
            continue
        lines.append((current + line).strip())
        current = ""
    return [l[2:] if l.startswith("$ ") else l for l in lines if l]


def commands_in(line: str) -> list[list[str]]:
    """Each ``tactiled`` invocation in one shell line, as argv after the program name."""
    if not MENTION.search(line):
        return []
    try:
        words = shlex.split(line, comments=True)
    except ValueError as err:
        raise AssertionError(f"cannot read the shell line {line!r}: {err}") from err
    found: list[list[str]] = []
    segment: list[str] = []
    for word in words + [";"]:
        if word not in SEPARATORS:
            segment.append(word)
            continue
        argv = program_arguments(segment)
        if argv is not None:
            found.append(argv)
        segment = []
    return found


def program_arguments(words: list[str]) -> list[str] | None:
    """The arguments of ``tactiled`` if this simple command runs it (after environment
    assignments and ``sudo``/``env``/``nice``/``timeout`` wrappers), else None; redirections
    are dropped."""
    i = 0
    while i < len(words) and not PROGRAM.match(words[i]):
        word = words[i]
        if re.match(r"^[A-Za-z_][A-Za-z0-9_]*=", word) or word in WRAPPERS or (
                i > 0 and words[i - 1] in WRAPPERS and (word.startswith("-") or word[0].isdigit())):
            i += 1 + (word in ("-u", "-n", "-g"))
            continue
        return None
    if i == len(words):
        return None
    argv = []
    for word in words[i + 1:]:
        if word.startswith((">", "<", "2>")):
            break
        argv.append(word)
    return argv


def documented_commands() -> list[tuple[str, str, list[str]]]:
    """(file, line, argv) for every tactiled command in a shell code block."""
    out = []
    for path in documents():
        for m in FENCE.finditer(path.read_text()):
            if m.group(2) not in ("", "sh", "bash", "console", "shell"):
                continue
            for line in shell_lines(m.group(3)):
                for argv in commands_in(line):
                    out.append((str(path.relative_to(ROOT)), line, argv))
    return out


def parse_error(argv: list[str]) -> str | None:
    """None if the parser accepts ``argv``, else what it printed."""
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            build_parser().parse_args(argv)
    except SystemExit as stop:
        if stop.code not in (0, None):
            return err.getvalue().strip() or f"exit {stop.code}"
    return None


COMMANDS_SHOWN = documented_commands()


def test_the_docs_show_commands_and_every_command_is_counted() -> None:
    per_file: dict[str, int] = {}
    for path, _, _ in COMMANDS_SHOWN:
        per_file[path] = per_file.get(path, 0) + 1
    print("FIGURES docs_commands:", {"commands": len(COMMANDS_SHOWN), "files": per_file})
    assert len(COMMANDS_SHOWN) >= 60
    shown = {argv[0] for _, _, argv in COMMANDS_SHOWN if argv and not argv[0].startswith("-")}
    assert shown == set(COMMANDS), f"commands never shown in a docs code block: {set(COMMANDS) - shown}"


@pytest.mark.parametrize("path,line,argv", COMMANDS_SHOWN,
                         ids=[f"{p}:{' '.join(a)[:60]}" for p, _, a in COMMANDS_SHOWN])
def test_the_documented_command_parses(path: str, line: str, argv: list[str]) -> None:
    assert parse_error(argv) is None, f"{path}: `{line}`: {parse_error(argv)}"


def test_the_check_catches_a_flag_that_does_not_exist() -> None:
    assert parse_error(["fit", "frames.npz", "--no-such-flag"])
    assert parse_error(["bench", "--suite", "nonsense"])
    assert parse_error(["fit", "frames.npz", "--window", "6"]) is None
    assert commands_in("tactiled fit a.npz --jobs 2 > out.jsonl  # comment") == [
        ["fit", "a.npz", "--jobs", "2"]]
    assert commands_in("sudo -u x /opt/tactiled/.venv/bin/tactiled --version | head") == [["--version"]]
    assert commands_in("A=1 tactiled watch --zenoh && curl x") == [["watch", "--zenoh"]]
    assert commands_in("journalctl -u tactiled -f") == []

"""The ``tactiled`` command line.

Each sub-command lives in ``tactiled/commands/<name>.py`` and exposes ``HELP`` (one line),
``add_arguments(parser)`` and ``run(args) -> int``.  Modules are imported only when their command
runs, so ``tactiled fit`` never pays for FastAPI and a missing optional dependency breaks only its
own command.  At this edge every :class:`~tactiled.errors.TactiledError` becomes one clear
error line and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from tactiled import __version__
from tactiled.errors import TactiledError

#: name -> one-line help.  Kept here (not discovered) so ``--help`` is instant and ordered.
COMMANDS: dict[str, str] = {
    "run": "run the daemon: acquisition, fitting, REST/WebSocket API and dashboard",
    "fit": "fit contact parameters to frames in an .npz file, one JSON line per frame",
    "simulate": "write simulated frames with known contact parameters (or act as a serial device)",
    "bench": "benchmark run time against error over a seeded suite of simulated scenes",
    "calibrate": "build per-tactel lookup tables from recorded presses with known loads",
    "presses": "make a press file from a recorded session and the known contacts pressed",
    "record": "record raw frames from a frame source to a file",
    "replay": "replay a recording through the pipeline",
    "export": "export a recording: its ROS 2 messages to MCAP, or its raw frames to npz",
    "sensors": "list the built-in sensor descriptions, print one as TOML, or check a description file",
    "watch": "subscribe to a running daemon (or every daemon on Zenoh) and print estimates live",
}


def _load(name: str):  # -> module
    return importlib.import_module(f"tactiled.commands.{name}")


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tactiled",
        description="Real-time tactile sensing for robot hands: contact curvature, force and "
        "location from any taxel array under an elastic cover (text lines, FlexiTac, Robotiq "
        "TSF-85, XELA uSkin, or the simulated finger), by the Fearing & Binford 1988 contact "
        "model. Units: mm, N, degrees.",
    )
    parser.add_argument("--version", action="version", version=f"tactiled {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, help_text in COMMANDS.items():
        if only is not None and name != only:
            sub.add_parser(name, help=help_text, add_help=False)
            continue
        try:
            module = _load(name)
        except ImportError as err:
            p = sub.add_parser(name, help=f"{help_text} [unavailable: {err}]")
            p.set_defaults(_unavailable=str(err))
            continue
        p = sub.add_parser(
            name,
            help=help_text,
            description=(module.__doc__ or help_text).strip(),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def _parser_of(parser: argparse.ArgumentParser, command: str | None) -> argparse.ArgumentParser:
    """The sub-command's parser (``parser`` itself when no command was given)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and command in action.choices:
            return action.choices[command]
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    # Import only the command being run (fast start, isolated optional dependencies).
    chosen = next((a for a in argv if a in COMMANDS), None)
    parser = build_parser(only=chosen)
    args, extra = parser.parse_known_args(argv)
    if extra:  # said by the command's own parser, with its usage, not the top level's
        _parser_of(parser, getattr(args, "command", None)).error(
            f"unrecognized arguments: {' '.join(extra)}")
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    if getattr(args, "_unavailable", None):
        print(f"tactiled {args.command}: unavailable: {args._unavailable}", file=sys.stderr)
        return 2
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except TactiledError as err:
        print(f"tactiled {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # e.g. `tactiled fit ... | head`: the reader left, not an error
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())

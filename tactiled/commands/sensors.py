"""List the built-in sensor descriptions, print one as TOML, or check a description file.

A sensor description says what a taxel array is: its grid (rows, cols, pitch), its surface
(a finger's radius, or flat), its cover (the impulse response's depths and ratios, the modulus),
its noise and its wiring (docs/howto/sensors.md).  The daemon takes one per sensor
(`[[sensor]] description = "NAME or FILE.toml"`); `fit`, `simulate` and `bench` take
`--sensor NAME|FILE.toml`.

examples:
  tactiled sensors                          list the built-ins
  tactiled sensors show flat16              print one as TOML (a start for your own)
  tactiled sensors show flat16 > mypad.toml
  tactiled sensors check mypad.toml         read and check a file: one line per problem, exit 2
"""

from __future__ import annotations

import argparse
import json
import sys

from tactiled.errors import ConfigError

HELP = "list the built-in sensor descriptions, print one as TOML, or check a description file"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("action", nargs="?", choices=("list", "show", "check", "windows"), default="list",
                   help="list (default): the built-ins; show NAME|FILE: print as TOML; "
                   "check FILE: read and check a description; windows NAME|FILE: the share of "
                   "the Fisher information each fit window keeps, and the smallest keeping 90 %%")
    p.add_argument("name", nargs="?", metavar="NAME|FILE.toml", help="a built-in's name or a .toml file")
    p.add_argument("--json", action="store_true", help="machine-readable output (list, show)")


def _error(message: str) -> int:
    print(f"tactiled sensors: error: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    from tactiled.sensors import builtin_names, load_description

    try:
        if args.action == "list":
            if args.name:
                return _error("'list' takes no name (did you mean 'show NAME'?)")
            descs = [load_description(n) for n in builtin_names()]
            if args.json:
                print(json.dumps([d.summary() for d in descs]))
                return 0
            print(f"{'name':<16} {'array':>7} {'pitch mm':>10} {'surface':>12}  description")
            for d in descs:
                surface = "flat" if d.flat else f"R {d.surface_radius_mm:g} mm"
                pitch = f"{d.pitch_x_mm:g}x{d.pitch_y_mm:g}"
                print(f"{d.name:<16} {d.rows:>3}x{d.cols:<3} {pitch:>10} {surface:>12}  {d.description}")
            print("\n`tactiled sensors show NAME` prints one as TOML; docs/howto/sensors.md describes the keys.")
            return 0
        if not args.name:
            return _error(f"'{args.action}' needs a built-in's name or a .toml file")
        d = load_description(args.name)
    except ConfigError as err:
        return _error(str(err))
    if args.action == "windows":
        from tactiled.sensors.window import KEEP, information, recommended

        sensor = d.sensor_model()
        info = information(sensor)
        keys = list(next(iter(info.values())))
        if args.json:
            print(json.dumps({"information": {str(n): row for n, row in info.items()},
                              "recommended": recommended(sensor)}))
            return 0
        print(f"{d.name}: share of the {max(info)}x{max(info)} window's Fisher information each "
              "window keeps (reference contacts: docs/howto/sensors.md, 'The fit window')")
        print(f"{'window':>7} " + " ".join(f"{k:>20}" for k in keys))
        for n, row in info.items():
            print(f"{n:>4}x{n:<2} " + " ".join(f"{row[k]:>20.2f}" for k in keys))
        print(f"\nsmallest keeping {100 * KEEP:.0f} % of every parameter's: {recommended(sensor)} "
              f"(the description's window: {d.window})")
        return 0
    if args.action == "show":
        print(json.dumps(d.summary()) if args.json else d.to_toml(), end="" if not args.json else "\n")
        return 0
    print(f"{args.name}: ok: {d.name}, {d.rows}x{d.cols} tactels at {d.pitch_x_mm:g} x "
          f"{d.pitch_y_mm:g} mm, {'flat' if d.flat else f'radius {d.surface_radius_mm:g} mm'}, "
          f"cover depth {d.depth_x_mm:g}/{d.depth_y_mm:g} mm, modulus {d.modulus_n_mm2:g} N/mm^2")
    return 0

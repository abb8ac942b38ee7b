"""The ``cellsight`` command line: :data:`COMMANDS`, one module per sub-command, each with a
``register(sub)`` (:mod:`cellsight.commands`).

Commands: ``show`` (pictures of the cell and each camera's view), ``visibility`` (which feature
points each camera sees, and why not), ``run`` (the paper's experiments), ``compare`` (two runs'
metrics side by side), ``cells`` (the built-in cells: ``--cell`` takes a name or a file),
``sweep``, ``realism``, ``place-cameras``, ``export``, ``view``, ``cameras``. Every error on bad
input is printed as one line naming its source (exit status 2); a crash as one line too (exit
status 1; ``CELLSIGHT_DEBUG=1`` shows the traceback); a run ended by SIGINT or SIGTERM exits
with 130 or 143 after writing its partial results.
"""

from __future__ import annotations

import argparse
import sys

from cellsight import threads
from cellsight.commands import (
    calibrate,
    cameras,
    cells,
    check,
    compare,
    design_crossing,
    diagnose,
    ik,
    run,
    show,
    track,
    visibility,
)
from cellsight.commands import export as export_command
from cellsight.commands.text import debug, one_line
from cellsight.errors import CellsightError
from cellsight.placement import command as placement_command
from cellsight.realism import command as realism_command
from cellsight.sweep import command as sweep_command
from cellsight.view import command as view_command

COMMANDS = (show, visibility, run, cells, compare, sweep_command, realism_command,
            placement_command, export_command, view_command, cameras, ik, check, diagnose,
            design_crossing, track, calibrate)
"""Every sub-command's module, in ``--help`` order."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cellsight", description="Which feature points each fixed camera of a robot cell "
        "sees, and tracking and grasping workpieces with it.")
    sub = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        threads.apply()
        return args.func(args)
    except (CellsightError, KeyError) as exc:
        print(f"cellsight: error: {one_line(exc, 500)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("cellsight: interrupted (SIGINT)", file=sys.stderr)
        return 130
    except Exception as exc:
        if debug():
            raise
        print(f"cellsight: error: {one_line(f'{type(exc).__name__}: {exc}')} "
              f"(CELLSIGHT_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())

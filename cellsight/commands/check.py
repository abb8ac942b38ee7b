"""``cellsight check [--cell FILE]``: every problem of a cell file, one line each, before
anything runs (:mod:`cellsight.experiments.cellcheck`); exit status 1 when there is an error."""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from cellsight.commands.text import CELL_HELP

STYLE = {"error": "[red]error  [/red]", "warning": "[yellow]warning[/yellow]",
         "ok": "[green]ok     [/green]"}


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight check`` to the sub-commands."""
    check = sub.add_parser("check", help="check a cell file: units, joint limits, key poses in "
                                         "view, experiment 3's crossing")
    check.add_argument("--cell", help=CELL_HELP)
    check.add_argument("--margin-px", type=float, default=20.0,
                       help="a key pose closer than this to an image's border is a warning (20)")
    check.add_argument("--along-task", action="store_true",
                       help="check experiment 3's crossing against the part and the grasping "
                            "robot along the task: runs experiment 2 (ideal sensor) first, "
                            "about 15 s")
    check.add_argument("--path", metavar="RUN_DIR",
                       help="as --along-task, with this run of experiment 2 instead")
    check.add_argument("--quiet", action="store_true", help="print only the problems")
    check.set_defaults(func=cmd_check)


def cmd_check(args: argparse.Namespace) -> int:
    from rich.console import Console

    from cellsight.errors import CellsightError
    from cellsight.experiments.cellcheck import check_cell
    from cellsight.experiments.task_path import TaskPath
    from cellsight.model.loader import load_cell

    if not args.margin_px >= 0:
        raise CellsightError(f"--margin-px: expected a number >= 0, got {args.margin_px}")
    cell = load_cell(args.cell)
    with tempfile.TemporaryDirectory() as tmp:
        path = (TaskPath.of_task(args.cell, args.path, Path(tmp), "check")
                if args.along_task or args.path else None)
        findings = check_cell(cell, margin_px=args.margin_px, path=path)
    console = Console(width=200, highlight=False)
    for f in findings:
        if f.level != "ok" or not args.quiet:
            console.print(f"{STYLE[f.level]} {f.line}")
    errors = sum(f.level == "error" for f in findings)
    warnings = sum(f.level == "warning" for f in findings)
    console.print(f"{cell.source}: {errors} error(s), {warnings} warning(s)")
    return 1 if errors else 0


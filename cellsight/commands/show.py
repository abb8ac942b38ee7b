"""``cellsight show``: pictures of the cell in one state and of each camera's projected view,
the feature points coloured by the predicted visibility."""

from __future__ import annotations

import argparse
from pathlib import Path

from cellsight.commands.text import add_state_args
from cellsight.errors import CellsightError
from cellsight.model.arguments import parse_joints, parse_openings, parse_part_poses


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight show`` to the sub-commands."""
    show = sub.add_parser("show", help="picture of the cell and each camera's projected view")
    add_state_args(show)
    show.add_argument("--out", default="out/show", help="output folder (default out/show)")
    show.add_argument("--overwrite", action="store_true",
                      help="replace the pictures of an earlier 'show' in --out")
    show.set_defaults(func=cmd_show)


def cmd_show(args: argparse.Namespace) -> int:
    from rich.console import Console

    from cellsight.model.loader import load_cell
    from cellsight.occlusion.backends import visibility_predictor
    from cellsight.report.show import show_cell, show_files
    from cellsight.runfolder.folder import check_new_files
    from cellsight.runfolder.writes import WriteError

    cell = load_cell(args.cell)
    snapshot = cell.snapshot(parse_joints(args.joints), parse_part_poses(args.part_pose),
                             parse_openings(args.openings))
    out = Path(args.out)
    check_new_files(out, show_files(cell), args.overwrite, "--out")
    visibility = visibility_predictor(cell).predict_snapshot(snapshot)
    try:
        paths = show_cell(snapshot, out, visibility)
    except (OSError, WriteError) as exc:  # a WriteError names the staged file: say why only
        why = exc.reason if isinstance(exc, WriteError) else exc.strerror or exc
        raise CellsightError(f"--out: {str(out)!r}: cannot write the pictures ({why})") from exc
    console = Console()
    for path in paths:
        console.print(f"wrote [bold]{path}[/bold]")
    return 0

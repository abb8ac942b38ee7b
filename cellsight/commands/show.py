"""``cellsight show``: pictures of the cell in one state and of each camera's projected view,
the feature points coloured by the predicted visibility."""

from __future__ import annotations

import argparse
from pathlib import Path

from cellsight.commands.text import add_state_args
from cellsight.model.arguments import parse_joints, parse_part_poses


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight show`` to the sub-commands."""
    show = sub.add_parser("show", help="picture of the cell and each camera's projected view")
    add_state_args(show)
    show.add_argument("--out", default="out/show", help="output folder (default out/show)")
    show.set_defaults(func=cmd_show)


def cmd_show(args: argparse.Namespace) -> int:
    from rich.console import Console

    from cellsight.model.loader import load_cell
    from cellsight.occlusion.predictor import VisibilityPredictor
    from cellsight.report.show import show_cell

    cell = load_cell(args.cell)
    snapshot = cell.snapshot(parse_joints(args.joints), parse_part_poses(args.part_pose))
    visibility = VisibilityPredictor(cell).predict_snapshot(snapshot)
    paths = show_cell(snapshot, Path(args.out), visibility)
    console = Console()
    for path in paths:
        console.print(f"wrote [bold]{path}[/bold]")
    return 0

"""``cellsight show``: pictures of the cell in one state and of each camera's projected view,
the feature points coloured by the predicted visibility."""

from __future__ import annotations

import argparse
from pathlib import Path

from cellsight.commands.text import add_state_args
from cellsight.errors import CellsightError
from cellsight.model.arguments import parse_joints, parse_part_poses


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight show`` to the sub-commands."""
    show = sub.add_parser("show", help="picture of the cell and each camera's projected view")
    add_state_args(show)
    show.add_argument("--out", default="out/show", help="output folder (default out/show)")
    show.add_argument("--overwrite", action="store_true",
                      help="replace the pictures of an earlier 'show' in --out")
    show.set_defaults(func=cmd_show)


def _check_out(out: Path, names: list[str], overwrite: bool) -> None:
    """``--out`` can take the pictures ``names``: a folder or creatable (not under a file),
    holding none of them unless ``overwrite``; checked before anything is written."""
    existing = next((p for p in (out, *out.parents) if p.exists()), None)
    if existing is not None and not existing.is_dir():
        where = "is a file" if existing == out else f"is under {str(existing)!r}, a file"
        raise CellsightError(f"--out: {str(out)!r} {where}; expected a folder")
    there = [n for n in names if (out / n).exists()]
    if there and not overwrite:
        raise CellsightError(f"--out: {str(out)!r} already holds {', '.join(there)}; pass "
                             f"--overwrite to replace them")


def cmd_show(args: argparse.Namespace) -> int:
    from rich.console import Console

    from cellsight.model.loader import load_cell
    from cellsight.occlusion.predictor import VisibilityPredictor
    from cellsight.report.show import show_cell, show_files

    cell = load_cell(args.cell)
    snapshot = cell.snapshot(parse_joints(args.joints), parse_part_poses(args.part_pose))
    out = Path(args.out)
    _check_out(out, show_files(cell), args.overwrite)
    visibility = VisibilityPredictor(cell).predict_snapshot(snapshot)
    try:
        paths = show_cell(snapshot, out, visibility)
    except OSError as exc:
        raise CellsightError(f"--out: {str(out)!r}: cannot write the pictures "
                             f"({exc.strerror or exc})") from exc
    console = Console()
    for path in paths:
        console.print(f"wrote [bold]{path}[/bold]")
    return 0

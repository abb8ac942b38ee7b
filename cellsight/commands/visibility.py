"""``cellsight visibility``: which feature points each camera sees in one state of the cell,
and why the others are hidden (tables, or ``--json``)."""

from __future__ import annotations

import argparse
import json

import numpy as np

from cellsight.commands.text import add_state_args
from cellsight.model.arguments import parse_joints, parse_openings, parse_part_poses


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight visibility`` to the sub-commands."""
    vis = sub.add_parser("visibility", help="which feature points each camera sees, and why not")
    add_state_args(vis)
    vis.add_argument("--json", action="store_true", help="print JSON instead of tables")
    vis.set_defaults(func=cmd_visibility)


def cmd_visibility(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from cellsight.model.loader import load_cell
    from cellsight.occlusion.backends import visibility_predictor

    cell = load_cell(args.cell)
    result = visibility_predictor(cell).predict(parse_joints(args.joints),
                                               parse_part_poses(args.part_pose),
                                               parse_openings(args.openings))
    if args.json:
        out = {
            part: [
                {
                    "camera": v.camera,
                    "features": [
                        {"name": name, "visible": bool(v.visible[j]),
                         "pixel": None if not np.isfinite(v.pixels[j]).all()
                         else [round(float(x), 3) for x in v.pixels[j]],
                         "reason": v.reason[j] or None}
                        for j, name in enumerate(cell.workpiece(part).feature_names)
                    ],
                }
                for v in views
            ]
            for part, views in result.items()
        }
        print(json.dumps(out, indent=2))
        return 0
    console = Console()
    for part, views in result.items():
        names = cell.workpiece(part).feature_names
        for v in views:
            table = Table(title=f"{part} seen by {v.camera}: {v.count} of {len(names)} visible")
            for col in ("feature", "visible", "u (px)", "v (px)", "hidden by"):
                table.add_column(col, justify="right" if col.endswith(")") else "left")
            for j, name in enumerate(names):
                u, w = v.pixels[j]
                table.add_row(name, "[green]yes[/green]" if v.visible[j] else "[red]no[/red]",
                              f"{u:.1f}", f"{w:.1f}", v.reason[j])
            console.print(table)
    return 0

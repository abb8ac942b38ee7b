"""``cellsight diagnose RUN_DIR``: where a run's wrong corners come from, by camera, feature and
span of time, most accepted first (:mod:`cellsight.runfolder.wrong_corners`)."""

from __future__ import annotations

import argparse
import json


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight diagnose`` to the sub-commands."""
    diag = sub.add_parser("diagnose", help="a run's wrong corners: camera, feature, when, "
                                           "accepted or rejected, and what hid the feature")
    diag.add_argument("run_dir", metavar="RUN_DIR", help="a run folder (cellsight run --out)")
    diag.add_argument("--json", action="store_true", help="print JSON instead of a table")
    diag.set_defaults(func=cmd_diagnose)


def cmd_diagnose(args: argparse.Namespace) -> int:
    from pathlib import Path

    from rich.console import Console
    from rich.table import Table

    from cellsight.runfolder import read_metrics
    from cellsight.runfolder.replay import run_cell
    from cellsight.runfolder.wrong_corners import WRONG_PX, wrong_corner_spans

    folder = Path(args.run_dir)
    metrics = read_metrics(folder)
    cell = run_cell(metrics, folder)
    part = cell.workpiece(metrics["workpiece"])
    spans = wrong_corner_spans(folder, [c.name for c in cell.cameras],
                               list(part.feature_names))
    if args.json:
        print(json.dumps([s.as_dict() for s in spans], indent=2))
        return 0
    accepted = sum(s.accepted for s in spans)
    console = Console(width=160)
    console.print(f"{folder}: {sum(s.frames for s in spans)} wrong corners (more than "
                  f"{WRONG_PX:g} px off), {accepted} accepted by the gate, in {len(spans)} "
                  f"spans", soft_wrap=True)
    table = Table()
    for col in ("camera", "feature", "t (s)", "phase", "frames", "accepted", "rejected",
                "unused", "truly", "predicted"):
        table.add_column(col, justify="right" if col in ("frames", "accepted", "rejected",
                                                         "unused") else "left")
    for s in spans:
        when = f"{s.t_start:.2f}" if s.t_end == s.t_start else f"{s.t_start:.2f}-{s.t_end:.2f}"
        table.add_row(s.camera, s.feature, when, s.phase, str(s.frames), str(s.accepted),
                      str(s.rejected), str(s.unused), s.truth, s.predicted)
    console.print(table)
    return 0

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
    diag.add_argument("--top", type=int, metavar="N",
                      help="only the N spans with the most accepted wrong corners")
    diag.set_defaults(func=cmd_diagnose)


def cmd_diagnose(args: argparse.Namespace) -> int:
    from pathlib import Path

    from rich.console import Console
    from rich.table import Table

    from cellsight.errors import CellsightError
    from cellsight.runfolder.checked import checked_run
    from cellsight.runfolder.replay import run_cell
    from cellsight.runfolder.wrong_corners import WRONG_PX, wrong_corner_spans

    if args.top is not None and args.top < 1:
        raise CellsightError(f"--top: expected a whole number >= 1, got {args.top}")
    folder = Path(args.run_dir)
    metrics = checked_run(folder, "RUN_DIR", whole=False)
    cell = run_cell(metrics, folder)
    part = cell.workpiece(metrics["workpiece"])
    every = wrong_corner_spans(folder, [c.name for c in cell.cameras], list(part.feature_names))
    spans = every[:args.top] if args.top is not None else every
    if args.json:
        print(json.dumps([s.as_dict() for s in spans], indent=2))
        return 0
    accepted = sum(s.accepted for s in every)
    console = Console(width=160)
    shown = f"; the first {len(spans)}:" if len(spans) < len(every) else ""
    console.print(f"{folder}: {sum(s.frames for s in every)} wrong corners (more than "
                  f"{WRONG_PX:g} px off), {accepted} accepted by the gate, in {len(every)} "
                  f"spans{shown}", soft_wrap=True)
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

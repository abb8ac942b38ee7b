"""``cellsight compare A B``: two runs' metrics side by side, with their ratio B / A."""

from __future__ import annotations

import argparse
from pathlib import Path

from cellsight.commands.metric_rows import metric_rows
from cellsight.commands.text import one_line


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight compare`` to the sub-commands."""
    compare = sub.add_parser("compare", help="two runs' metrics side by side")
    compare.add_argument("run_a", help="output folder of a run")
    compare.add_argument("run_b", help="output folder of another run")
    compare.set_defaults(func=cmd_compare)


def _ratio(a, b) -> str:
    """``b / a`` to 3 digits for two numbers (not bools), else empty."""
    numeric = all(isinstance(v, int | float) and not isinstance(v, bool) for v in (a, b))
    try:
        return f"{b / a:.3g}" if numeric and a else ""
    except (OverflowError, ZeroDivisionError):
        return ""


SETTING = {"cell_sha256": "cell", "experiment": "experiment", "t_end_s": "duration (s)",
           "realism": "realism profile", "structure": "structure"}
"""metrics.json fields that say what was run (not how well): runs differing in one of them are
not like for like, and compare says so above its table."""


def differences(a: dict, b: dict) -> list[str]:
    """What two runs' metrics say was run differently: ``"duration (s) 12.3 vs 48.5"`` per
    :data:`SETTING` field present in both and different; the cells by their files (the same
    file: changed between the runs)."""
    out = []
    for key, name in SETTING.items():
        if key not in a or key not in b or a[key] == b[key]:
            continue
        if key == "cell_sha256":
            files = [one_line(Path(str(m.get("cell"))).name, 60) for m in (a, b)]
            out.append(f"cell {files[0]} vs {files[1]}" if files[0] != files[1] else
                       f"cell {files[0]}, changed between the runs")
        else:
            out.append(f"{name} {one_line(a[key], 20)} vs {one_line(b[key], 20)}")
    return out


def cmd_compare(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from cellsight.report.run_report import format_value
    from cellsight.runfolder import read_metrics

    def cell(value) -> str:  # a metric as text, its brackets shown, not read as rich markup
        try:
            return escape(one_line(format_value(value), 80))
        except ValueError:  # an integer too long to print
            return "?"

    a, b = read_metrics(args.run_a), read_metrics(args.run_b)
    rows_a, rows_b = metric_rows(a), metric_rows(b)
    table = Table(title="cellsight compare")
    table.add_column("metric")
    table.add_column(escape(args.run_a), justify="right")
    table.add_column(escape(args.run_b), justify="right")
    table.add_column("B / A", justify="right")
    for key in list(rows_a) + [k for k in rows_b if k not in rows_a]:
        va, vb = rows_a.get(key), rows_b.get(key)
        table.add_row(escape(one_line(key, 80)), cell(va), cell(vb), _ratio(va, vb))
    console = Console()
    if unlike := differences(a, b):
        console.print(escape(f"note: the runs are not like for like: {'; '.join(unlike)}"),
                      style="yellow")
    console.print(table)
    return 0

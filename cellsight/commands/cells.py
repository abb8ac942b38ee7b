"""``cellsight cells``: the built-in cells, the names ``--cell`` takes besides a file."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight cells`` to the sub-commands."""
    cells = sub.add_parser("cells", help="list the built-in cells (names for --cell)")
    cells.set_defaults(func=cmd_cells)


def cmd_cells(args: argparse.Namespace) -> int:
    """One line per built-in cell: name, file, robots, cameras, description."""
    from cellsight.model.loader import BUILTIN_CELLS, parse_cell_text
    from cellsight.model.yaml_input import read_cell_text

    rows = []
    for cell in BUILTIN_CELLS.values():
        spec, _ = parse_cell_text(read_cell_text(cell.path), str(cell.path), cell.path.parent)
        rows.append((cell.name, str(cell.path), "robots: " + ", ".join(r.name for r in spec.robots),
                     "cameras: " + ", ".join(c.name for c in spec.cameras), cell.description))
    widths = [max(len(row[k]) for row in rows) for k in range(4)]
    for row in rows:
        print("  ".join([*(v.ljust(w) for v, w in zip(row[:4], widths, strict=True)), row[4]]))
    return 0

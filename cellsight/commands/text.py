"""Text shared by the commands: one-line messages, and the ``--cell`` / state arguments that
several commands take."""

from __future__ import annotations

import argparse
import os

CELL_HELP = ("a built-in cell's name (dual-arm, the default; ur-cell, kr16-cell, iiwa-cell, "
             "line-cell: see 'cellsight cells') or a YAML cell file")


def debug() -> bool:
    """``CELLSIGHT_DEBUG`` is set (and not 0): crashes show their traceback."""
    return os.environ.get("CELLSIGHT_DEBUG", "0") not in ("", "0")


def one_line(text: object, limit: int = 300) -> str:
    """``text`` on one line (whitespace runs collapsed), cut to ``limit`` characters."""
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def add_state_args(parser: argparse.ArgumentParser) -> None:
    """``--cell``, ``--joints``, ``--part-pose`` and ``--openings``: a cell in one state."""
    parser.add_argument("--cell", help=CELL_HELP)
    parser.add_argument("--joints", help='JSON (or a JSON file): {"R7AX": [q1, ...], ...}; '
                                         "robots left out stay at HOME")
    parser.add_argument("--part-pose",
                        help='JSON (or file): {"part": {"xyz": [..], "rpy": [..]}}')
    parser.add_argument("--openings", help='JSON (or file): {"R7AX": 0.03}: jaw openings (m); '
                                           "grippers left out are open")

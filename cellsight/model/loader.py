"""Load a cell: find its file, read and validate the YAML, build the :class:`Cell`.

The entry point of the cell file: :func:`load_cell` takes a file or a built-in cell's name
(:mod:`cellsight.model.registry`), reads the text (:mod:`cellsight.model.yaml_input`), validates
it against the schema (:mod:`cellsight.model.schema`) and builds the cell
(:mod:`cellsight.model.builders`). Any error becomes a :class:`CellFileError` naming the file,
the path of the bad field (``robots[1].links[2].qlim``), the value and what was expected.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import ValidationError

from cellsight.errors import CellFileError
from cellsight.model.builders import build_cell
from cellsight.model.cell import Cell
from cellsight.model.registry import BUILTIN_CELLS, builtin_cell_path, cell_path
from cellsight.model.schema import CellSpec
from cellsight.model.yaml_input import load_yaml, read_cell_text

__all__ = [
    "BUILTIN_CELLS",
    "build_cell",
    "builtin_cell_path",
    "cell_path",
    "load_cell",
    "parse_cell_text",
]


def _loc(parts: tuple[int | str, ...]) -> str:
    """A pydantic error's location as a field path: ``robots[1].links[2].qlim``."""
    out = ""
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out or "<root>"


def parse_cell_text(text: str, file: str, folder: Path) -> tuple[CellSpec, dict]:
    """Parse and validate YAML text (a repeated key is an error); returns the spec and the raw
    mapping."""
    raw = load_yaml(text, file)
    if not isinstance(raw, dict):
        raise CellFileError(file, "<root>", raw, "a mapping with robots, workpieces, cameras")
    try:
        spec = CellSpec.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        raise CellFileError(file, _loc(err["loc"]), err.get("input"),
                            err["msg"].removeprefix("Value error, ")) from exc
    return spec, raw


def load_cell(path: str | Path | None = None) -> Cell:
    """Load a cell from a YAML file, or a built-in cell by name (``"dual-arm"``, ``"ur-cell"``:
    :data:`BUILTIN_CELLS`); the built-in dual-arm cell when ``path`` is None. A file of a
    built-in cell's name in the working folder wins over the built-in cell."""
    path = cell_path(path)
    spec, _ = parse_cell_text(read_cell_text(path), str(path), path.parent)
    return build_cell(spec, str(path), path.parent)

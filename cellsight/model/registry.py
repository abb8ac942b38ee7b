"""The built-in cells: the cell files shipped in ``cellsight/data``, their names and descriptions
(what ``cellsight cells`` lists), and finding a cell's file from a file name or a built-in name.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from cellsight.errors import CellFileError


@dataclass(frozen=True)
class BuiltinCell:
    """A cell file shipped with cellsight, loaded by name (``load_cell("ur-cell")``)."""

    name: str
    file: str  # in ``cellsight/data``
    description: str

    @property
    def path(self) -> Path:
        """The cell file's absolute path."""
        return Path(__file__).resolve().parent.parent / "data" / self.file


BUILTIN_CELLS: dict[str, BuiltinCell] = {cell.name: cell for cell in (
    BuiltinCell("dual-arm", "dual_arm_cell.yaml",
                "the paper's cell: R7AX on a track and R6AX (SmartSix-like DH surrogates), "
                "two cameras, a conveyor"),
    BuiltinCell("ur-cell", "ur_cell.yaml",
                "two UR5 (example-robot-data URDF, collision meshes), three cameras, a conveyor"),
    BuiltinCell("kr16-cell", "kr16_cell.yaml",
                "two KUKA KR16-2 (rtb-data URDF, collision meshes), three cameras, a conveyor"),
    BuiltinCell("iiwa-cell", "iiwa_cell.yaml",
                "two KUKA LBR iiwa 14 R820, 7 axes (rtb-data URDF, collision meshes), three "
                "cameras, a conveyor"),
    BuiltinCell("line-cell", "line_cell.yaml",
                "a line: the dual-arm cell's arms, a conveyor carrying four parts of two shapes "
                "that R7AX picks in turn, six cameras"),
)}
DEFAULT_CELL = "dual-arm"


def builtin_cell_path(name: str = DEFAULT_CELL) -> Path:
    """Path of a built-in cell's file (default: the dual-arm cell)."""
    return BUILTIN_CELLS[name].path


def cell_path(cell: str | Path | None = None) -> Path:
    """The file of ``cell``: an existing file, else a built-in cell's name (None: the default
    built-in cell); a :class:`CellFileError` listing the built-in cells' names otherwise."""
    if cell is None:
        return builtin_cell_path()
    path = Path(cell)
    try:
        if path.is_file():
            return path
    except (OSError, ValueError):  # not a usable path (too long, a NUL byte)
        pass
    if isinstance(cell, str) and cell in BUILTIN_CELLS:
        return BUILTIN_CELLS[cell].path
    raise CellFileError(str(cell), "<file>", str(cell), "an existing YAML cell file or the name "
                        f"of a built-in cell ({', '.join(BUILTIN_CELLS)})")

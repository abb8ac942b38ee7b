"""The cell a run ran, kept in its folder: ``run_cell.yaml`` (:data:`CELL_FILE`), the cell file with
every file it points to named by its absolute path, and in ``metrics.json`` the SHA-256 of each
of those files (``cell_files``). A replay (:func:`kept_cell`) loads that copy, so it needs
neither the original cell file nor the folder it was run from, and refuses, in one line, when
a file the cell points to (a mesh, a URDF, a calibration file), or the copy itself, has changed
since the run."""

from __future__ import annotations

from pathlib import Path

import yaml

from cellsight.errors import CellsightError
from cellsight.model.cell import Cell
from cellsight.model.loader import load_cell
from cellsight.model.yaml_input import load_yaml, read_cell_text, with_absolute_paths
from cellsight.runfolder.digest import file_digest
from cellsight.runfolder.metrics import RunDataError
from cellsight.runfolder.writes import write_file

CELL_FILE = "run_cell.yaml"  # not cell.yaml: a user's own cell file may be called that


def keep_cell(folder: Path, cell: Cell) -> dict[str, str | None]:
    """Write ``cell``'s file into ``folder`` as :data:`CELL_FILE` (its files named absolute);
    returns file -> SHA-256 of every file it points to (``cell.files``) and of the copy itself
    (under its name :data:`CELL_FILE`, relative to the run folder, which may move), for
    ``metrics.json``.
    A cell not read from a file (``cell.source`` is not one) is not kept: ``{}``. A failed
    write is a :class:`~cellsight.runfolder.writes.WriteError` naming the file."""
    source = Path(cell.source)
    if not source.is_file():
        return {}
    raw = load_yaml(read_cell_text(source), str(source))
    text = (f"# the cell of this run, from {source}\n"
            + yaml.safe_dump(with_absolute_paths(raw, source.parent), sort_keys=False))
    copy = write_file(Path(folder) / CELL_FILE, text)
    return {CELL_FILE: file_digest(copy), **{f: file_digest(f) for f in cell.files}}


def kept_cell(folder: Path, metrics: dict) -> Cell | None:
    """The cell kept in the run ``folder`` (None for a run from before cells were kept), after
    checking that every file it points to is as it was (``metrics["cell_files"]``); a
    :class:`RunDataError` naming the file that changed or is gone."""
    path = Path(folder) / CELL_FILE
    files = metrics.get("cell_files") or {}
    if not path.is_file() and CELL_FILE not in files:
        return None
    for file, digest in files.items():
        what = f"{file}, which the run's cell points to," if file != CELL_FILE else "it"
        file = path if file == CELL_FILE else file
        if file_digest(file) != digest:
            now = "is gone" if not Path(file).exists() else "has changed"
            raise RunDataError(f"{path}: {what} {now} since the run; replaying it would show "
                               f"another cell (pass --cell NAME|FILE to replay with another "
                               f"cell)")
    try:
        return load_cell(path)
    except CellsightError as exc:
        raise RunDataError(f"{path}: the run's cell cannot be loaded ({exc})") from exc

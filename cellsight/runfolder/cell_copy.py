"""The cell a run ran, kept in its folder: ``run_cell.yaml`` (:data:`CELL_FILE`), the cell file with
every file it points to named by its absolute path, and in ``metrics.json`` the SHA-256 of each
of those files (``cell_files``). A replay (:func:`kept_cell`) loads that copy, so it needs
neither the original cell file nor the folder it was run from, and refuses, in one line, when
a file the cell points to (a mesh, a URDF, a calibration file) has changed since the run."""

from __future__ import annotations

from pathlib import Path

import yaml

from cellsight.errors import CellsightError
from cellsight.model.cell import Cell
from cellsight.model.loader import load_cell
from cellsight.model.yaml_input import load_yaml, read_cell_text, with_absolute_paths
from cellsight.runfolder.digest import file_digest
from cellsight.runfolder.metrics import RunDataError

CELL_FILE = "run_cell.yaml"  # not cell.yaml: a user's own cell file may be called that


def keep_cell(folder: Path, cell: Cell) -> dict[str, str | None]:
    """Write ``cell``'s file into ``folder`` as :data:`CELL_FILE` (its files named absolute);
    returns file -> SHA-256 of every file it points to (``cell.files``), for ``metrics.json``.
    A cell not read from a file (``cell.source`` is not one) is not kept: ``{}``."""
    source = Path(cell.source)
    if not source.is_file():
        return {}
    raw = load_yaml(read_cell_text(source), str(source))
    text = (f"# the cell of this run, from {source}\n"
            + yaml.safe_dump(with_absolute_paths(raw, source.parent), sort_keys=False))
    (Path(folder) / CELL_FILE).write_text(text, encoding="utf-8")
    return {f: file_digest(f) for f in cell.files}


def kept_cell(folder: Path, metrics: dict) -> Cell | None:
    """The cell kept in the run ``folder`` (None for a run from before cells were kept), after
    checking that every file it points to is as it was (``metrics["cell_files"]``); a
    :class:`RunDataError` naming the file that changed or is gone."""
    path = Path(folder) / CELL_FILE
    if not path.is_file():
        return None
    for file, digest in (metrics.get("cell_files") or {}).items():
        if file_digest(file) != digest:
            now = "is gone" if not Path(file).exists() else "has changed"
            raise RunDataError(f"{path}: {file}, which the run's cell points to, {now} since "
                               f"the run; replaying it would show another cell (pass --cell "
                               f"NAME|FILE to replay with another cell)")
    try:
        return load_cell(path)
    except CellsightError as exc:
        raise RunDataError(f"{path}: the run's cell cannot be loaded ({exc})") from exc

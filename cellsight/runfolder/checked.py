"""A run folder checked for what reads it back (``check --path``, ``design-crossing --path``,
``diagnose``, ``export``, ``place-cameras``, ``view``): its ``metrics.json`` there (a run
killed before its end wrote none), the run finished (not interrupted, no failed write) where
the reader needs the whole run, its ``frames.csv`` the one the run wrote (``frames_sha256``,
written by :func:`~cellsight.runfolder.metrics.write_metrics`; a run from before that field
is taken as it is), a run of an experiment the reader takes, and of the reader's cell (the
same file, unchanged: ``cell_sha256``). Each refusal is a
:class:`~cellsight.runfolder.metrics.RunDataError` naming the folder, the field and the value.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from cellsight.model.cell import Cell
from cellsight.runfolder.digest import cell_digest, file_digest
from cellsight.runfolder.metrics import RunDataError, read_metrics


def checked_run(folder: str | Path, option: str, *, whole: bool = True,
                experiments: Sequence[int] | None = None, cell: Cell | None = None) -> dict:
    """The run's metrics after the module docstring's checks; ``option`` names the argument
    that gave the folder; ``whole``: the run must have finished; ``experiments``: the ones
    the reader takes (None: any, a tracked recording too); ``cell``: the reader's cell."""
    folder = Path(folder)
    if not (folder / "metrics.json").exists() and (folder / "frames.csv").exists():
        raise RunDataError(f"{option}: {folder} has frames.csv but no metrics.json: the run "
                           f"did not finish (killed?); run it again")
    metrics = read_metrics(folder)
    frames_digest(folder, metrics)
    path = folder / "metrics.json"
    if whole and (metrics.get("interrupted") or metrics.get("error")):
        why = (f"error {metrics['error']!r}" if metrics.get("error") else
               f"interrupted at t = {metrics.get('t_end_s', '?')} s")
        raise RunDataError(f"{option}: {path}: the run did not finish ({why}); this needs a "
                           f"whole run: run it again")
    number = metrics.get("experiment")
    if experiments is not None and number not in experiments:
        what = "a tracked recording" if number is None else f"a run of experiment {number}"
        raise RunDataError(f"{option}: {path}: field 'experiment' = {number!r}: {what}; this "
                           f"needs experiment {' or '.join(map(str, experiments))}")
    if cell is not None:
        recorded, now = metrics.get("cell_sha256"), cell_digest(cell)
        if recorded is not None and now is not None and recorded != now:
            raise RunDataError(f"{option}: {path}: field 'cell_sha256': the run was of "
                               f"{metrics.get('cell')!r}, not of {cell.source!r} as it is now "
                               f"(another cell, or the file changed since the run)")
    return metrics


def frames_digest(folder: Path, metrics: dict) -> None:
    """A :class:`RunDataError` when the folder's ``frames.csv`` is not the one its run wrote
    (``frames_sha256`` of ``metrics.json``; nothing to check without it)."""
    recorded = metrics.get("frames_sha256")
    if recorded is None:
        return
    now = file_digest(folder / "frames.csv")
    if now != recorded:
        what = "missing or unreadable" if now is None else "changed since the run wrote it"
        raise RunDataError(f"{folder / 'frames.csv'}: {what} (its SHA-256 differs from "
                           f"metrics.json's frames_sha256): edited by hand, or another run's?")

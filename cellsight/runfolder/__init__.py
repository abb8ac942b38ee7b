"""A run's output folder, in one place: what a run writes there and how it is read back.

- :mod:`.folder`: the files a run writes (:data:`RUN_FILES`) and the check that a folder can
  take a new run (:func:`check_out_folder`, :func:`make_out_folder`);
- :mod:`.framelog`: ``frames.csv``, one row per vision frame (:class:`FrameWriter`,
  :class:`FrameLog`);
- :mod:`.metrics`: ``metrics.json``, its schema, its one writer and its one reader;
- :mod:`.digest`: which cell a run used (the cell file and the files it points to);
- :mod:`.cell_copy`: the run's cell kept in its folder (``run_cell.yaml``), replayed from there;
- :mod:`.replay`: a whole run read back and checked (:func:`load_run`), for the view, the
  export and camera placement;
- :mod:`.writes`: every file written through one place: whole files atomically
  (:func:`write_file`), a failed write one :class:`WriteError` naming the file, a run's
  failed writes recorded for its ``metrics.json`` (:class:`RunWrites`).

``run.log``, ``report.html``, ``keyframes.json`` + ``keyframes/*.png`` and ``views.mp4`` are
written by the run loop and the report; they are for people, and nothing reads them back.
"""

from cellsight.runfolder.cell_copy import CELL_FILE, keep_cell, kept_cell
from cellsight.runfolder.digest import cell_digest
from cellsight.runfolder.folder import RUN_FILES, RunFolderError, check_out_folder, make_out_folder
from cellsight.runfolder.framelog import FrameLog, FrameWriter
from cellsight.runfolder.metrics import (
    METRICS_VERSION,
    RunDataError,
    RunMetrics,
    checked_metrics,
    finished_metrics,
    read_metrics,
    write_metrics,
)
from cellsight.runfolder.replay import RunData, load_run
from cellsight.runfolder.writes import RunWrites, WriteError, write_file

__all__ = [
    "CELL_FILE", "METRICS_VERSION", "RUN_FILES", "FrameLog", "FrameWriter", "RunData",
    "RunDataError", "RunFolderError", "RunMetrics", "RunWrites", "WriteError", "cell_digest",
    "check_out_folder", "checked_metrics", "finished_metrics", "keep_cell", "kept_cell",
    "load_run", "make_out_folder", "read_metrics", "write_file", "write_metrics",
]

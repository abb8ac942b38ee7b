"""A run's path through the task: the part's pose and every robot's joints over the frames of
a whole run of experiment 2 or 3, as ``check --path`` and ``design-crossing`` take it (or one
run now with the ideal sensor)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cellsight.errors import CellsightError
from cellsight.geometry.transforms import pose_from_xyz_rpy
from cellsight.model.cell import Cell
from cellsight.model.loader import load_cell
from cellsight.runfolder.checked import checked_run
from cellsight.runfolder.framelog import FrameLog


class TaskPath:
    """The part's pose and every robot's joints over a run's frames (``frames.csv``): a whole
    run of experiment 2 or 3 of ``cell`` (:func:`~cellsight.runfolder.checked.checked_run`;
    ``option`` names the argument that gave the folder)."""

    def __init__(self, run_dir: str | Path, cell: Cell | None = None,
                 option: str = "--path") -> None:
        checked_run(run_dir, option, experiments=(2, 3), cell=cell)
        log = FrameLog.read(Path(run_dir) / "frames.csv")
        self.t = log.floats("t")
        self._part = log.poses("true")
        self._joints = {name: log.joints(name) for name in log.robots}
        if len(self.t) == 0 or not self._joints:
            raise CellsightError(f"{run_dir}: its frames.csv has no frames with the robots' "
                                 f"joints (a run of this version of cellsight is needed)")

    @classmethod
    def of_task(cls, cell: str | Path | None, run_dir: str | Path | None, scratch: Path,
                who: str) -> TaskPath:
        """The path of the run ``run_dir``, else of experiment 2 run now on ``cell`` with the
        ideal sensor into ``scratch`` (``who`` says so on the console first)."""
        if run_dir is not None:
            return cls(run_dir, load_cell(cell))
        from cellsight.experiments.config import RunConfig
        from cellsight.experiments.runner import run_experiment

        print(f"{who}: running experiment 2 (ideal sensor) for the part's path")
        run_experiment(RunConfig(2, scratch / "experiment2", cell=cell, sensor="ideal",
                                 progress=False, video_every=0))
        return cls(scratch / "experiment2", load_cell(cell))

    def check_span(self, t0: float, t1: float, what: str) -> None:
        """A :class:`CellsightError` naming ``what`` unless ``t0``..``t1`` (s) lies within the
        run's frames."""
        if t0 < self.t[0] or t1 > self.t[-1]:
            raise CellsightError(f"{what}: {t0:g}-{t1:g} s is outside the run's frames "
                                 f"({self.t[0]:g}-{self.t[-1]:g} s)")

    def at(self, t: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The part's pose and the robots' joints at the frame nearest ``t`` (s)."""
        k = int(np.argmin(np.abs(self.t - t)))
        return (pose_from_xyz_rpy(self._part[k, :3], self._part[k, 3:]),
                {name: q[k] for name, q in self._joints.items()})

"""The frames of a task to place cameras for: every robot's joints, the workpiece's true pose
and the task phase at each vision frame, from a run folder read back
(:mod:`cellsight.runfolder`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cellsight.runfolder import RunData, load_run


@dataclass(frozen=True)
class TaskFrames:
    """``t`` (N,) s; ``phase`` (N,) str; ``joints`` robot -> (N, n) rad/m; ``part`` the
    workpiece's name and ``part_poses`` (N, 4, 4) its true ``T_base_part``; ``openings``
    robot -> (N,) jaw opening (m) of the grasping robot; ``cell`` the cell file the run used;
    ``run`` the run folder."""

    t: np.ndarray
    phase: np.ndarray
    joints: dict[str, np.ndarray]
    part: str
    part_poses: np.ndarray
    openings: dict[str, np.ndarray]
    cell: str
    run: Path

    @classmethod
    def of(cls, run: RunData, every: int = 1) -> TaskFrames:
        """The task of a run read back (:func:`cellsight.runfolder.load_run`), every
        ``every``-th vision frame."""
        rows = np.arange(0, run.n, max(int(every), 1))
        openings = {run.robot: run.opening[rows]} if run.robot else {}
        return cls(run.t[rows], np.asarray(run.frames.text("phase"), dtype=object)[rows],
                   {r: q[rows] for r, q in run.joints.items()}, run.part.name,
                   run.T_true[rows], openings, run.cell.source, run.folder)

    @classmethod
    def read(cls, folder: Path, every: int = 1) -> TaskFrames:
        """The task of the run in ``folder`` (its own cell), every ``every``-th frame."""
        return cls.of(load_run(folder), every)

    @property
    def n(self) -> int:
        """Number of frames."""
        return len(self.t)

    def state(self, k: int) -> tuple[dict, dict, dict]:
        """Frame ``k``'s joints, part poses and jaw openings, as :meth:`Cell.snapshot` takes
        them."""
        return ({r: q[k] for r, q in self.joints.items()}, {self.part: self.part_poses[k]},
                {r: float(o[k]) for r, o in self.openings.items() if np.isfinite(o[k])})

    def chunks(self, size: int) -> list[np.ndarray]:
        """The frame indices cut into pieces of at most ``size``."""
        return np.array_split(np.arange(self.n), max(1, -(-self.n // size)))

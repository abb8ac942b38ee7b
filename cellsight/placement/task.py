"""The frames of a task to place cameras for: every robot's joints, the workpiece's true pose
and the task phase at each vision frame, read from a run folder (``frames.csv`` with the
joint columns, ``metrics.json``)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cellsight.errors import CellsightError
from cellsight.framelog import FrameLog
from cellsight.geometry.transforms import pose_from_xyz_rpy


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
    def read(cls, run: Path, every: int = 1) -> TaskFrames:
        """The task of the run in folder ``run``, every ``every``-th vision frame."""
        run = Path(run)
        try:
            metrics = json.loads((run / "metrics.json").read_text())
            part, robot, cell = metrics["workpiece"], metrics["robot"], metrics["cell"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise CellsightError(f"--task: {run / 'metrics.json'}: not a finished run's metrics "
                                 f"({type(exc).__name__}: {exc})") from exc
        log = FrameLog.read(run / "frames.csv")
        if not log.robots:
            raise CellsightError(f"--task: {run / 'frames.csv'}: no joint columns q_<robot>_<j> "
                                 f"(a run logged before they were added); run it again")
        rows = np.arange(0, log.n, max(int(every), 1))
        poses = log.poses("true")[rows]
        keep = np.all(np.isfinite(poses), axis=1)
        if not keep.any():
            raise CellsightError(f"--task: {run / 'frames.csv'}: no frame with the part's pose")
        rows = rows[keep]
        return cls(log.floats("t")[rows], np.asarray(log.text("phase"), dtype=object)[rows],
                   {r: log.joints(r)[rows] for r in log.robots}, part,
                   np.stack([pose_from_xyz_rpy(p[:3], p[3:]) for p in poses[keep]]),
                   {robot: log.floats("jaw_opening")[rows]}, cell, run)

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

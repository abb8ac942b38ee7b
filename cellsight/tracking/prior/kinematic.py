"""The kinematic prior's poses of one workpiece (beyond the paper): where the gripper holds it,
or what it lies on.

What the tracker's :meth:`~cellsight.tracking.tracker.Tracker.step` takes as ``holders`` and
``supports``, from what the robot cell knows without the cameras:

- while the gripper holds the part, the part as the gripper holds it: the TCP times the
  inverse of the grasp (``T_part_tcp``) it was taken at;
- until the gripper first holds it, the part lying on its support: the cell file's pose of it;
- once the gripper lets it go, the part where it falls to from where it was last held (straight
  down onto the cell file's static objects, :class:`~cellsight.model.landing.Landing`); none
  when nothing lies below it.

:class:`KinematicPrior` keeps that state for a caller that knows, frame by frame, whether the
part is held and where (the simulated run: the task's grasp and the jaws' check).
:class:`RecordedGrasp` decides both from a recording's joints and jaw openings alone (``cellsight
track``, the default tracker): the part is held while the jaws stand at the opening its grasp
closes them to, within a tolerance, and it is held at the one of the grasp and its half-turn
twin about the TCP's approach axis whose orientation is nearer the TCP's when they close (the
choice the task's planner makes, :func:`~cellsight.model.grasp.nearer_grasp`).
"""

from __future__ import annotations

import numpy as np

from cellsight.geometry.transforms import invert_pose
from cellsight.model.cell import Workpiece
from cellsight.model.grasp import nearer_grasp
from cellsight.model.landing import Landing
from cellsight.model.robot import Robot


class KinematicPrior:
    """The prior's state for workpiece ``part`` (module docstring); ``landing``: the cell's
    static objects to let it fall on."""

    def __init__(self, part: Workpiece, landing: Landing) -> None:
        self.part, self.landing = part, landing
        self.held_at: np.ndarray | None = None  # T_base_part where it was last held
        self.rest_at: np.ndarray | None = None  # where it came to rest after that

    def update(self, held_at: np.ndarray | None) -> tuple[dict | None, dict | None]:
        """This frame's ``holders`` and ``supports`` for :meth:`Tracker.step`, given where the
        gripper holds the part now (``T_base_part``; None: it does not hold it)."""
        name = self.part.name
        if held_at is not None:
            self.held_at, self.rest_at = held_at, None
            return {name: held_at}, None
        if self.held_at is None:
            return None, {name: self.part.T_base_part}
        if self.rest_at is None:
            self.rest_at = self.landing.rest_pose(self.part.solid.vertices, self.held_at)
        return None, (None if self.rest_at is None else {name: self.rest_at})


class RecordedGrasp:
    """Whether, and where, ``robot``'s gripper holds ``part``, from its measured joints and jaw
    opening alone (module docstring). ``T_part_tcp``: the part's grasp; ``opening`` (m): the
    jaws' opening when closed on it at that grasp; ``tolerance`` (m): how far from it a reading
    still holds the part."""

    def __init__(self, robot: Robot, part: Workpiece, T_part_tcp: np.ndarray, opening: float,
                 tolerance: float) -> None:
        self.robot, self.part = robot, part
        self.T_part_tcp = np.asarray(T_part_tcp, dtype=float)
        self.opening, self.tolerance = float(opening), float(tolerance)
        self.chosen: np.ndarray | None = None  # T_part_tcp of the grasp held, while held

    def held_at(self, q: np.ndarray, opening: float | None,
                estimate: np.ndarray | None) -> np.ndarray | None:
        """``T_base_part`` as the gripper holds the part at joints ``q`` and jaw ``opening``
        (m; None: no reading), or None when it does not hold it; ``estimate``: the tracker's
        last ``T_base_part`` (None: the cell file's), whose orientation picks the grasp when
        the jaws close."""
        if opening is None or not abs(opening - self.opening) <= self.tolerance:
            self.chosen = None
            return None
        tcp = self.robot.tcp_pose(q)
        if self.chosen is None:
            part = self.part.T_base_part if estimate is None else estimate
            self.chosen = nearer_grasp(self.T_part_tcp, part, tcp)
        return tcp @ invert_pose(self.chosen)

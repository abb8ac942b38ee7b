"""The paper's three experiments (Section V) on a cell, from its file's ``experiments`` section.

1. The part still at its nominal pose; the other robots stay at HOME (out of the cameras' view).
2. The part moves on the conveyor during Approach and Grasp (until it is grasped).
3. As 2, and a second robot runs its own task that crosses the cameras' views.

The grasping robot defaults to the first robot with a tool and a FINAL pose, the workpiece to
the cell's first one. On a line (the cell file's ``experiments.picks``) the robot picks several
parts in turn; in experiments 2 and 3 the conveyor carries them all, the first along the cell
file's path and each other one along the same path moved to its own place on the belt (so
that they all keep their spacing); it also carries the line's passing parts (the cell file's
``experiments.passing``), not picked, each from its own place by the same travel, into the
views and out of them. A realism profile's seed may shift the scenario
(:class:`~cellsight.realism.ScenarioShift`): the conveyor's path moves with the part's start and
turns about it, its speed scales, and the crossing robot's waypoints move in time and in joint
space, all together (so that the crossing keeps its meaning).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cellsight.errors import CellFileError
from cellsight.model.cell import Cell, ExperimentSetup, Workpiece
from cellsight.model.robot import Robot
from cellsight.realism import ScenarioShift
from cellsight.world import ConveyorPath, Waypoint

DESCRIPTIONS = {
    1: "part still, second robot out of the cameras' view",
    2: "part moving on the conveyor during Approach and Grasp",
    3: "part moving, second robot crossing the cameras' views",
}


@dataclass(frozen=True)
class Scenario:
    """One experiment on one cell: who grasps what (``picks``, in turn; one part but on a
    line), how the parts move (``conveyors``, one per carried part, the picks' first; none in
    experiment 1), who else moves (``tasks``), and the parts that pass through the views
    without being picked (``passing``; experiments 2 and 3 of a line)."""

    number: int
    robot: Robot
    picks: tuple[Workpiece, ...]
    conveyors: tuple[ConveyorPath, ...]
    tasks: dict[str, list[Waypoint]] = field(default_factory=dict)
    passing: tuple[Workpiece, ...] = ()

    @property
    def description(self) -> str:
        return DESCRIPTIONS[self.number]

    @property
    def workpiece(self) -> Workpiece:
        """The first part picked (the only one but on a line)."""
        return self.picks[0]

    @property
    def conveyor(self) -> ConveyorPath:
        """The first part's conveyor path (still in experiment 1)."""
        return self.conveyors[0] if self.conveyors else ConveyorPath.still(self.picks[0].name)


def scenario(cell: Cell, number: int, shift: ScenarioShift | None = None) -> Scenario:
    """The experiment ``number`` (1, 2 or 3) on ``cell``, shifted by ``shift`` (module
    docstring; None: as the cell file says); raises :class:`CellFileError` naming the missing
    field of the cell file's ``experiments`` section."""
    if number not in DESCRIPTIONS:
        raise ValueError(f"experiment must be one of {sorted(DESCRIPTIONS)}, got {number}")
    setup = cell.experiments
    robot = _grasping_robot(cell)
    if not cell.workpieces:
        raise CellFileError(setup.source, "workpieces", [], "at least one workpiece")
    picks = cell.picked_workpieces()
    conveyors: tuple[ConveyorPath, ...] = ()
    passing: tuple[Workpiece, ...] = ()
    if number >= 2 and setup.passing:
        passing = tuple(cell.workpiece(name) for name in setup.passing)
    if number >= 2:
        if setup.conveyor_points is None:
            raise CellFileError(setup.source, "experiments.conveyor", None,
                                f"a conveyor path for experiment {number}")
        points, speed = setup.conveyor_points, setup.conveyor_speed
        if shift is not None:
            points, speed = _shifted_path(points, shift), speed * shift.speed_scale
        conveyors = tuple(
            ConveyorPath(points + belt_place(picks[0], part, shift), speed,
                         setup.conveyor_t_start, workpiece=part.name) for part in picks)
        conveyors += tuple(passing_path(setup, part, shift) for part in passing)
    tasks = {}
    if number == 3:
        if not setup.crossing_waypoints:
            raise CellFileError(setup.source, "experiments.crossing", None,
                                "a crossing robot's waypoints for experiment 3")
        dt, dq = (0.0, 0.0) if shift is None else (shift.crossing_dt, shift.crossing_dq)
        dq = 0.0 if dq is None else dq
        tasks[setup.crossing_robot] = [Waypoint(t + dt, q + dq)
                                       for t, q in setup.crossing_waypoints]
    return Scenario(number, robot, picks, conveyors, tasks, passing)


def passing_path(setup: ExperimentSetup, part: Workpiece,
                 shift: ScenarioShift | None) -> ConveyorPath:
    """The belt's path of a passing ``part``: from its nominal place (moved by its start shift)
    by the cell file's travel, at its speed (scaled by ``shift.speed_scale``). It keeps its
    lane: the picks' path turn (a few degrees) would move it across the belt and off it over
    a passing part's metres of travel."""
    start = part.T_base_part[:2, 3].copy()
    travel = np.asarray(setup.passing_travel, dtype=float)
    speed = setup.passing_speed
    if shift is not None:
        start = start + shift.part_shifts.get(part.name, shift.shift)
        speed = speed * shift.speed_scale
    return ConveyorPath(np.array([start, start + travel]), speed, setup.passing_t_start,
                        workpiece=part.name)


def belt_place(first: Workpiece, part: Workpiece, shift: ScenarioShift | None) -> np.ndarray:
    """Where ``part`` lies on the belt from the ``first`` pick (x, y, m, base frame): their
    nominal places' difference, turned with the path by ``shift.turn``, and moved by the
    difference of their start shifts (the spacing the seed draws; zero for the first)."""
    if part is first:
        return np.zeros(2)
    gap = part.T_base_part[:2, 3] - first.T_base_part[:2, 3]
    if shift is None:
        return gap
    c, s = np.cos(shift.turn), np.sin(shift.turn)
    moved = shift.part_shifts.get(part.name, shift.shift) - shift.shift
    return gap @ np.array([[c, s], [-s, c]]) + moved


def _shifted_path(points: np.ndarray, shift: ScenarioShift) -> np.ndarray:
    """The conveyor's polyline turned by ``shift.turn`` about its first point, then moved by
    ``shift.shift`` (m); unchanged when both are zero."""
    if shift.turn == 0 and not np.any(shift.shift):
        return points
    c, s = np.cos(shift.turn), np.sin(shift.turn)
    start = points[0]
    return start + shift.shift + (points - start) @ np.array([[c, s], [-s, c]])


def _grasping_robot(cell: Cell) -> Robot:
    setup = cell.experiments
    if setup.robot is not None:
        robot = cell.robot(setup.robot)
        if robot.tool is None or robot.final is None:
            raise CellFileError(setup.source, "experiments.robot", robot.name,
                                "a robot with a tool and a FINAL pose to grasp the part; "
                                f"{robot.name} has no {'tool' if robot.tool is None else 'final'}")
        return robot
    for robot in cell.robots:
        if robot.tool is not None and robot.final is not None:
            return robot
    raise CellFileError(setup.source, "robots", [r.name for r in cell.robots],
                        "a robot with a tool and a FINAL pose to grasp the part")


def place_pose(cell: Cell, robot: Robot, k: int) -> np.ndarray | None:
    """Where pick ``k`` (0-based) of ``cell``'s line is put down: ``robot``'s FINAL TCP pose
    moved by ``k`` times the cell file's ``experiments.place_step`` (None: at FINAL)."""
    step = np.asarray(cell.experiments.place_step, dtype=float)
    if robot.final is None or k == 0 or not step.any():
        return None
    T = robot.tcp_pose(robot.final)
    T[:2, 3] += k * step
    return T

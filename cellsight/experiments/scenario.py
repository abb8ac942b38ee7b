"""The paper's three experiments (Section V) on a cell, from its file's ``experiments`` section.

1. The part still at its nominal pose; the other robots stay at HOME (out of the cameras' view).
2. The part moves on the conveyor during Approach and Grasp (until it is grasped).
3. As 2, and a second robot runs its own task that crosses the cameras' views.

The grasping robot defaults to the first robot with a tool and a FINAL pose, the workpiece to
the cell's first one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from cellsight.errors import CellFileError
from cellsight.model.cell import Cell, Workpiece
from cellsight.model.robot import Robot
from cellsight.world import ConveyorPath, Waypoint

DESCRIPTIONS = {
    1: "part still, second robot out of the cameras' view",
    2: "part moving on the conveyor during Approach and Grasp",
    3: "part moving, second robot crossing the cameras' views",
}


@dataclass(frozen=True)
class Scenario:
    """One experiment on one cell: who grasps what, how the part moves, who else moves."""

    number: int
    robot: Robot
    workpiece: Workpiece
    conveyor: ConveyorPath
    tasks: dict[str, list[Waypoint]] = field(default_factory=dict)

    @property
    def description(self) -> str:
        return DESCRIPTIONS[self.number]


def scenario(cell: Cell, number: int) -> Scenario:
    """The experiment ``number`` (1, 2 or 3) on ``cell``; raises :class:`CellFileError` naming
    the missing field of the cell file's ``experiments`` section."""
    if number not in DESCRIPTIONS:
        raise ValueError(f"experiment must be one of {sorted(DESCRIPTIONS)}, got {number}")
    setup = cell.experiments
    robot = _grasping_robot(cell)
    if not cell.workpieces:
        raise CellFileError(setup.source, "workpieces", [], "at least one workpiece")
    part = cell.workpiece(setup.workpiece) if setup.workpiece else cell.workpieces[0]
    conveyor = ConveyorPath.still(part.name)
    if number >= 2:
        if setup.conveyor_points is None:
            raise CellFileError(setup.source, "experiments.conveyor", None,
                                f"a conveyor path for experiment {number}")
        conveyor = ConveyorPath(setup.conveyor_points, setup.conveyor_speed,
                                setup.conveyor_t_start, workpiece=part.name)
    tasks = {}
    if number == 3:
        if not setup.crossing_waypoints:
            raise CellFileError(setup.source, "experiments.crossing", None,
                                "a crossing robot's waypoints for experiment 3")
        tasks[setup.crossing_robot] = [Waypoint(t, q) for t, q in setup.crossing_waypoints]
    return Scenario(number, robot, part, conveyor, tasks)


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

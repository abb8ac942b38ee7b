"""The cell's TF tree: frame names and the transforms between them, from the cell model.

Root ``base`` (the cell base frame). Per robot ``R``: its chain frames 0..n as ``R/<link>``
(DH robots: ``R/link0`` .. ``R/link<n>``; URDF robots: the URDF's link names), frame 0 at
``T_base_robot`` in ``base``, frame i in frame i-1 from the forward kinematics at the logged
joints; with a gripper, ``R/tool`` (on frame n, ``T_flange_tool``) and ``R/tcp`` (on the tool,
its tool centre point). Per camera ``C``: ``C_optical`` in ``base``, the ROS optical
convention (z forward, x right, y down: cellsight's camera frame). Per static object ``S``:
``S`` in ``base``. Per workpiece ``P``: ``P_true`` (its true pose) and ``P_est`` (the
tracker's estimate) in ``base``; a workpiece that was not logged rests at its nominal pose.
Fixed transforms go on ``/tf_static``, the robots' joints and the parts on ``/tf``.
"""

from __future__ import annotations

import numpy as np

from cellsight.errors import CellsightError
from cellsight.geometry.transforms import invert_pose
from cellsight.model.cell import Cell
from cellsight.model.robot import Robot

ROOT = "base"

Transform = tuple[str, str, np.ndarray]
"""(parent frame, child frame, ``T_parent_child``)."""


def link_frames(robot: Robot) -> list[str]:
    """The TF names of a robot's chain frames 0..n."""
    names = getattr(robot.chain, "link_names", None) or [f"link{i}"
                                                         for i in range(robot.n_joints + 1)]
    return [f"{robot.name}/{name}" for name in names]


def tool_frames(robot: Robot) -> tuple[str, str]:
    """The TF names of a robot's tool frame and tool centre point."""
    return f"{robot.name}/tool", f"{robot.name}/tcp"


def optical_frame(camera_name: str) -> str:
    return f"{camera_name}_optical"


def part_frames(part_name: str) -> tuple[str, str]:
    """The TF names of a workpiece's true pose and of the tracker's estimate."""
    return f"{part_name}_true", f"{part_name}_est"


def static_transforms(cell: Cell, logged_part: str) -> list[Transform]:
    """Every fixed transform of the cell (module docstring), its frame names checked unique."""
    out: list[Transform] = []
    for robot in cell.robots:
        links = link_frames(robot)
        out.append((ROOT, links[0], robot.T_base_robot))
        if robot.tool is not None:
            tool, tcp = tool_frames(robot)
            out += [(links[-1], tool, robot.tool.T_flange_tool),
                    (tool, tcp, robot.tool.T_tool_tcp)]
    out += [(ROOT, optical_frame(c.name), c.T_base_cam) for c in cell.cameras]
    out += [(ROOT, s.name, s.T_base_obj) for s in cell.static]
    out += [(ROOT, part_frames(p.name)[0], p.T_base_part) for p in cell.workpieces
            if p.name != logged_part]
    _check_unique(cell, [child for _, child, _ in out] + link_frames_all(cell)
                  + list(part_frames(logged_part)))
    return out


def link_frames_all(cell: Cell) -> list[str]:
    """The moving chain frames 1..n of every robot."""
    return [name for robot in cell.robots for name in link_frames(robot)[1:]]


def _check_unique(cell: Cell, names: list[str]) -> None:
    seen: set[str] = {ROOT}
    for name in names:
        if name in seen:
            raise CellsightError(f"cell {cell.source}: two TF frames would be named {name!r} "
                                 f"(robot links, tools, '<camera>_optical', static objects, "
                                 f"'<workpiece>_true'/_est' and 'base' share one namespace)")
        seen.add(name)


def robot_transforms(robot: Robot, q: np.ndarray) -> list[Transform]:
    """Frame i of the robot's chain in frame i-1, i = 1..n, at joints ``q``."""
    F = robot.chain.fkine(q)
    names = link_frames(robot)
    return [(names[i - 1], names[i], invert_pose(F[i - 1]) @ F[i])
            for i in range(1, len(F))]

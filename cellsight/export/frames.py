"""The cell's TF tree: frame names and the transforms between them, from the cell model.

Names follow REP 103 and REP 105. Root ``world`` (:data:`ROOT`: the fixed cell, cellsight's
base frame). Per robot ``R`` (``R/`` is the prefix robot_state_publisher's ``frame_prefix``
gives, so that several robots of one URDF keep distinct frames): its chain frames 0..n as
``R/<link>`` (DH robots: ``R/link0`` .. ``R/link<n>``; URDF robots: the URDF's link names,
frame 0 its root link), frame 0 at ``T_base_robot`` in ``world``, frame i in frame i-1 from
the forward kinematics at the logged joints. A URDF robot's links on fixed joints
(``base_link``, ``tool0``, ...) are ``R/<link>`` on their URDF parent link, at the fixed
joint's origin (lengths in metres, the cell file's URDF ``scale`` applied), as
robot_state_publisher publishes them; the URDF is read again from the cell file
(``cell.source``; a cell not read from a file has none of these). With a gripper: ``R/tool``
on the flange (a URDF robot's flange link, ``tool0`` by default; a DH robot's frame n) and
``R/tcp`` on the tool, at its tool centre point; a URDF hand's finger links ``R/<link>``
on ``R/tool`` at the jaw opening (the world's open hand where the run logs none). Per camera
``C``: ``C_optical_frame`` in ``world``, the ROS optical convention (z forward, x right, y
down: cellsight's camera frame). Per static object ``S``: ``S`` in ``world``. Per workpiece
``P``: ``P_true`` (its true pose) and ``P_est`` (the tracker's estimate) in ``world``; a
workpiece that was not logged rests at its nominal pose. Fixed transforms go on
``/tf_static``, the robots' joints and the parts on ``/tf``. Every frame has one parent; the
names are checked unique.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cellsight.errors import CellsightError
from cellsight.geometry.transforms import invert_pose
from cellsight.model.cell import Cell
from cellsight.model.loader import parse_cell_text
from cellsight.model.robot import Robot
from cellsight.model.urdf import fixed_frames
from cellsight.model.urdf_files import package_folder, resolve_uri
from cellsight.model.yaml_input import read_cell_text

ROOT = "world"

Transform = tuple[str, str, np.ndarray]
"""(parent frame, child frame, ``T_parent_child``)."""


@dataclass(frozen=True)
class UrdfFile:
    """A URDF robot's file as its cell file names it: ``path``, ``metres`` per length unit of
    the file, and the ``flange`` link its tool mounts on (None: the model's default)."""

    path: Path
    metres: float
    flange: str | None


def urdf_files(cell: Cell) -> dict[str, UrdfFile]:
    """Robot name -> its URDF file, for every URDF robot of ``cell``, read again from the cell
    file ``cell.source``; none for a cell not read from a file."""
    source = Path(cell.source)
    if not source.is_file():
        return {}
    spec, _ = parse_cell_text(read_cell_text(source), str(source), source.parent)
    packages = {name: package_folder(value, source.parent)
                for name, value in spec.packages.items()}
    return {rs.name: UrdfFile(resolve_uri(rs.urdf.file, packages, source.parent),
                              rs.urdf.metres, rs.urdf.flange)
            for rs in spec.robots if rs.urdf is not None}


def link_frames(robot: Robot) -> list[str]:
    """The TF names of a robot's chain frames 0..n."""
    names = getattr(robot.chain, "link_names", None) or [f"link{i}"
                                                         for i in range(robot.n_joints + 1)]
    return [f"{robot.name}/{name}" for name in names]


def tool_frames(robot: Robot) -> tuple[str, str]:
    """The TF names of a robot's tool frame and tool centre point."""
    return f"{robot.name}/tool", f"{robot.name}/tcp"


def optical_frame(camera_name: str) -> str:
    """The TF name of a camera's optical frame (z forward, x right, y down)."""
    return f"{camera_name}_optical_frame"


def part_frames(part_name: str) -> tuple[str, str]:
    """The TF names of a workpiece's true pose and of the tracker's estimate."""
    return f"{part_name}_true", f"{part_name}_est"


def urdf_fixed_frames(robot: Robot, urdf: UrdfFile) -> tuple[list[Transform], str, np.ndarray]:
    """A URDF robot's fixed links, each on its URDF parent link at the fixed joint's origin
    (m), and its flange: (transforms, the flange's TF name, ``T_flange_tool`` of the robot's
    tool on it). A :class:`CellsightError` when the URDF's chain is no longer the robot's."""
    fixed = fixed_frames(urdf.path, urdf.metres, urdf.flange)
    if fixed.links != tuple(robot.chain.link_names):
        raise CellsightError(f"robot {robot.name}: URDF file {urdf.path} has the links "
                             f"{list(fixed.links)}, the loaded robot "
                             f"{list(robot.chain.link_names)}; the file changed since the cell "
                             f"was loaded")
    out = [(f"{robot.name}/{parent}", f"{robot.name}/{child}", T)
           for parent, child, T in fixed.transforms]
    T_flange_tool = (None if robot.tool is None
                     else invert_pose(fixed.T_last_flange) @ robot.tool.T_flange_tool)
    return out, f"{robot.name}/{fixed.flange}", T_flange_tool


def robot_static_transforms(robot: Robot, urdf: UrdfFile | None) -> list[Transform]:
    """A robot's fixed transforms (module docstring): its base in ``world``, a URDF robot's
    fixed links, and its gripper's tool and TCP."""
    links = link_frames(robot)
    out: list[Transform] = [(ROOT, links[0], robot.T_base_robot)]
    flange = links[-1]
    T_flange_tool = None if robot.tool is None else robot.tool.T_flange_tool
    if urdf is not None:
        fixed, flange, T_flange_tool = urdf_fixed_frames(robot, urdf)
        out += fixed
    if robot.tool is not None:
        tool, tcp = tool_frames(robot)
        out += [(flange, tool, T_flange_tool), (tool, tcp, robot.tool.T_tool_tcp)]
    return out


def static_transforms(cell: Cell, logged_part: str) -> list[Transform]:
    """Every fixed transform of the cell (module docstring), its frame names checked unique."""
    urdfs = urdf_files(cell)
    out: list[Transform] = []
    for robot in cell.robots:
        out += robot_static_transforms(robot, urdfs.get(robot.name))
    out += [(ROOT, optical_frame(c.name), c.T_base_cam) for c in cell.cameras]
    out += [(ROOT, s.name, s.T_base_obj) for s in cell.static]
    out += [(ROOT, part_frames(p.name)[0], p.T_base_part) for p in cell.workpieces
            if p.name != logged_part]
    _check_unique(cell, [child for _, child, _ in out] + link_frames_all(cell)
                  + list(part_frames(logged_part)))
    return out


def finger_frames(robot: Robot) -> list[str]:
    """The TF names of a URDF hand's finger links (none for other grippers)."""
    jaws = () if robot.tool is None else robot.tool.jaws
    return [f"{robot.name}/{jaw.link}" for jaw in jaws if jaw.link]


def link_frames_all(cell: Cell) -> list[str]:
    """The moving frames of every robot: chain frames 1..n and a URDF hand's fingers."""
    return [name for robot in cell.robots
            for name in link_frames(robot)[1:] + finger_frames(robot)]


def _check_unique(cell: Cell, names: list[str]) -> None:
    seen: set[str] = {ROOT}
    for name in names:
        if name in seen:
            raise CellsightError(f"cell {cell.source}: two TF frames would be named {name!r} "
                                 f"(robot links '<robot>/<link>', '<robot>/tool' and "
                                 f"'<robot>/tcp', '<camera>_optical_frame', static objects, "
                                 f"'<workpiece>_true'/'_est' and {ROOT!r} share one "
                                 f"namespace)")
        seen.add(name)


def robot_transforms(robot: Robot, q: np.ndarray,
                     opening: float | None = None) -> list[Transform]:
    """Frame i of the robot's chain in frame i-1, i = 1..n, at joints ``q``; a URDF hand's
    finger links in ``R/tool`` at the jaw ``opening`` (m; None: open, as the world leaves a
    gripper it never commands)."""
    F = robot.chain.fkine(q)
    names = link_frames(robot)
    out = [(names[i - 1], names[i], invert_pose(F[i - 1]) @ F[i]) for i in range(1, len(F))]
    fingers = finger_frames(robot)
    if fingers:
        tool = robot.tool
        poses = tool.jaw_poses(tool.max_opening if opening is None else opening)
        out += [(tool_frames(robot)[0], name, T)
                for name, T in zip(fingers, poses, strict=True)]
    return out

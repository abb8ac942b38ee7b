"""The cell and its snapshot at one sampling time (paper, Section III-A and Fig. 4).

Every solid of the cell is a :class:`CellObject` with a fixed index. A :class:`Snapshot` holds
the pose of each object in the base frame, ``T_base_obj``, computed from the joint values (DH
or URDF kinematics), the jaw openings and the workpiece poses;
``T_cam_obj = T_cam_base @ T_base_obj`` gives them in each camera frame.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np

from cellsight.camera import Camera
from cellsight.errors import CellsightError, short_repr
from cellsight.geometry.polyhedron import Polyhedron
from cellsight.geometry.transforms import is_rigid
from cellsight.model.robot import Robot

ObjectKind = Literal["link", "tool", "workpiece", "static"]


def _suffix(j: int, solids) -> str:
    """Name suffix of the j-th of an object's solids: none for a single solid, else ``.<j+1>``."""
    return "" if len(solids) == 1 else f".{j + 1}"


@dataclass(frozen=True)
class Workpiece:
    """A workpiece: a closed polyhedron with named feature points, its nominal pose and,
    optionally, its grasp ``T_part_grasp``: the pose of a gripper's tool centre point in the
    part frame when it holds the part (the world and the planner both use it)."""

    name: str
    solid: Polyhedron
    T_base_part: np.ndarray
    T_part_grasp: np.ndarray | None = None

    @property
    def feature_points(self) -> np.ndarray:
        """Feature points (F, 3) in the part frame (m)."""
        return self.solid.feature_points

    @property
    def feature_names(self) -> tuple[str, ...]:
        return self.solid.feature_names


@dataclass(frozen=True)
class ExperimentSetup:
    """What the cell file says about the paper's experiments (Section V), all optional.

    ``robot`` grasps ``workpiece``, or on a line each of ``picks`` in turn;
    ``conveyor_points`` (k, 2) x, y (m, base frame) and ``conveyor_speed`` (m/s, from
    ``conveyor_t_start`` s) move the part in experiments 2 and 3 (on a line the first pick
    follows the path and the others move with it, keeping their places on the belt);
    ``crossing_robot`` follows ``crossing_waypoints`` ((t s, q) pairs, absolute times) in
    experiment 3. On a line, pick ``k`` (0-based) is put down at FINAL's TCP pose moved by ``k``
    times ``place_step`` (x, y, m, base frame). In experiments 2 and 3 the belt carries each
    of ``passing`` (parts not picked) from its nominal place by ``passing_travel`` (x, y, m)
    at ``passing_speed`` (m/s) from ``passing_t_start`` (s). ``source`` is the cell file, for
    error messages.
    """

    robot: str | None = None
    workpiece: str | None = None
    picks: tuple[str, ...] = ()
    place_step: tuple[float, float] = (0.0, 0.0)
    conveyor_points: np.ndarray | None = None
    conveyor_speed: float = 0.0
    conveyor_t_start: float = 0.0
    crossing_robot: str | None = None
    crossing_waypoints: tuple[tuple[float, np.ndarray], ...] = ()
    passing: tuple[str, ...] = ()
    passing_travel: tuple[float, float] = (0.0, 0.0)
    passing_speed: float = 0.0
    passing_t_start: float = 0.0
    source: str = "<memory>"


@dataclass(frozen=True)
class StaticObject:
    """A fixed object of the cell (table, conveyor, track, camera stand) at ``T_base_obj``."""

    name: str
    solids: tuple[Polyhedron, ...]
    T_base_obj: np.ndarray


@dataclass(frozen=True)
class CellObject:
    """One solid of the cell: its unique name (``R7AX.link2.1``, ``R7AX.gripper.jaw1``,
    ``table.3``), the object it is part of (``label``: ``R7AX.link2``, ``R7AX.gripper``,
    ``table``; what occlusion reports name), its kind, its robot and workpiece index."""

    name: str
    kind: ObjectKind
    solid: Polyhedron
    label: str
    robot: str | None = None
    workpiece: int | None = None


FrameKind = Literal["link", "palm", "jaw", "part", "static"]


@dataclass(frozen=True)
class ObjectFrame:
    """The frame that carries a cell object (the object's frame is that frame).

    ``kind``: ``link`` (chain frame ``index`` of robot ``owner``, 0 = the robot base), ``palm``
    (the tool frame of robot ``owner``), ``jaw`` (jaw ``index``, 0 or 1, of robot ``owner``'s
    gripper), ``part`` (workpiece ``owner``) or ``static`` (static object ``owner``, at
    ``index`` in ``cell.static``).
    """

    kind: FrameKind
    owner: str
    index: int | None = None


@dataclass
class Snapshot:
    """Poses of every cell object at one sampling time.

    ``poses[i]`` is ``T_base_obj`` of ``cell.objects[i]``; ``joints``, ``openings`` and
    ``part_poses`` are the inputs it was computed from.
    """

    cell: Cell
    poses: np.ndarray
    joints: dict[str, np.ndarray]
    openings: dict[str, float]
    part_poses: dict[str, np.ndarray]

    def in_camera(self, camera: int | str) -> np.ndarray:
        """``T_cam_obj`` of every object for one camera (index or name), (n_objects, 4, 4)."""
        cam = self.cell.camera(camera)
        return cam.T_cam_base @ self.poses

    def pose(self, name: str) -> np.ndarray:
        """``T_base_obj`` of the object with this name."""
        return self.poses[self.cell.object_index(name)]


OPENING_TOL = 1e-4  # m; a jaw opening this far outside [0, max] is numerical noise, clipped
JOINT_LIMIT_TOL = 0.06  # rad or m; a joint reading this far beyond its limit is used as read,
# not an error: a real encoder's offset and noise on a joint at its limit, or the servo's
# overshoot there (a set-point that stops at the limit at once, followed with the velocity fed
# forward, overshoots by up to v / (e w_n): 0.05 rad at 150 deg/s and `harsh`'s 3 Hz)


def _opening(robot: Robot, value: object) -> float:
    """A robot's jaw opening (m), checked: a finite number in ``[0, max_opening]`` (within
    ``OPENING_TOL``, clipped); a :class:`CellsightError` naming the robot and the value."""
    top = robot.tool.max_opening
    try:
        opening = float(value)
    except (TypeError, ValueError):
        opening = math.nan
    if not -OPENING_TOL <= opening <= top + OPENING_TOL:  # also NaN
        raise CellsightError(f"robot {robot.name}: jaw opening {short_repr(value)} m; expected a "
                             f"finite number in [0, {top:g}] m")
    return min(max(opening, 0.0), top)


class Cell:
    """A robot cell: robots with tools, workpieces, static objects and calibrated cameras,
    and the cell file's optional set-up of the paper's experiments (``experiments``).
    ``source`` is the cell file; ``files`` the other files it was built from (meshes, URDFs
    and their meshes, calibration files), in the order the loader read them.

    ``objects`` lists every solid once, in a fixed order: each robot's links (DH frame order),
    gripper palm and two jaws; the workpieces; the static objects' solids. ``frames[i]`` says
    what carries ``objects[i]`` (:class:`ObjectFrame`); :meth:`snapshot` and the MuJoCo model
    both follow it.
    """

    def __init__(
        self,
        name: str,
        robots: list[Robot],
        workpieces: list[Workpiece],
        static: list[StaticObject],
        cameras: list[Camera],
        source: str = "<memory>",
        experiments: ExperimentSetup | None = None,
        files: tuple[str, ...] = (),
    ) -> None:
        self.name = name
        self.files = tuple(files)
        self.experiments = experiments or ExperimentSetup(source=source)
        self.robots = list(robots)
        self.workpieces = list(workpieces)
        self.static = list(static)
        self.cameras = list(cameras)
        self.source = source
        self.objects: list[CellObject] = []
        self.frames: list[ObjectFrame] = []  # per object, what carries it; see snapshot()
        for robot in self.robots:
            self._add_robot(robot)
        for k, part in enumerate(self.workpieces):
            self._add(CellObject(part.name, "workpiece", part.solid, part.name, workpiece=k),
                      ObjectFrame("part", part.name))
        for k, obj in enumerate(self.static):
            for j, solid in enumerate(obj.solids):
                self._add(CellObject(obj.name + _suffix(j, obj.solids), "static", solid, obj.name),
                          ObjectFrame("static", obj.name, k))
        self._index = {o.name: i for i, o in enumerate(self.objects)}
        self._robot = {r.name: r for r in self.robots}
        self._part = {p.name: p for p in self.workpieces}

    def _add_robot(self, robot: Robot) -> None:
        """The robot's link solids (frame order; labelled ``R.link2`` for DH links,
        ``R.upper_arm_link`` for URDF links), then its gripper's palm and two jaws."""
        for i, link, solids in robot.link_groups():
            label = f"{robot.name}.{link}"
            for j, solid in enumerate(solids):
                self._add(CellObject(label + _suffix(j, solids), "link", solid, label, robot.name),
                          ObjectFrame("link", robot.name, i))
        if robot.tool is None:
            return
        label = f"{robot.name}.gripper"
        for j, solid in enumerate(robot.tool.palm):
            self._add(CellObject(label + _suffix(j, robot.tool.palm), "tool", solid, label,
                                 robot.name), ObjectFrame("palm", robot.name))
        for k, jaw in enumerate(robot.tool.jaws):
            self._add(CellObject(f"{label}.jaw{k + 1}", "tool", jaw.solid, label,
                                 robot.name), ObjectFrame("jaw", robot.name, k))

    def _add(self, obj: CellObject, frame: ObjectFrame) -> None:
        if any(o.name == obj.name for o in self.objects):
            raise CellsightError(f"cell {self.name}: two objects are named {obj.name!r}")
        self.objects.append(obj)
        self.frames.append(frame)

    def object_index(self, name: str) -> int:
        try:
            return self._index[name]
        except KeyError:
            raise KeyError(f"cell {self.name} has no object {name!r}") from None

    def robot(self, name: str) -> Robot:
        try:
            return self._robot[name]
        except KeyError:
            raise KeyError(f"cell {self.name} has no robot {name!r}; its robots: "
                           f"{sorted(self._robot)}") from None

    def workpiece(self, name: str) -> Workpiece:
        try:
            return self._part[name]
        except KeyError:
            raise KeyError(f"cell {self.name} has no workpiece {name!r}; its workpieces: "
                           f"{sorted(self._part)}") from None

    def picked_workpieces(self) -> tuple[Workpiece, ...]:
        """The parts the experiments' robot picks, in turn: the cell file's
        ``experiments.picks`` (a line), else its ``experiments.workpiece``, else the first
        workpiece (empty when the cell has none)."""
        setup = self.experiments
        if setup.picks:
            return tuple(self.workpiece(name) for name in setup.picks)
        if setup.workpiece:
            return (self.workpiece(setup.workpiece),)
        return tuple(self.workpieces[:1])

    def camera(self, camera: int | str) -> Camera:
        if isinstance(camera, str):
            for cam in self.cameras:
                if cam.name == camera:
                    return cam
            raise KeyError(f"cell {self.name} has no camera {camera!r}; its cameras: "
                           f"{[c.name for c in self.cameras]}")
        return self.cameras[camera]

    def snapshot(
        self,
        joints: Mapping[str, np.ndarray] | None = None,
        part_poses: Mapping[str, np.ndarray] | None = None,
        openings: Mapping[str, float] | None = None,
    ) -> Snapshot:
        """Pose of every object in the base frame (paper, III-A).

        ``joints``: robot name -> joint vector (a robot left out stays at HOME); checked for
        length, finiteness and limits (within ``JOINT_LIMIT_TOL``: a measured joint at its limit
        reads a little beyond it). ``part_poses``: workpiece name -> ``T_base_part`` (left
        out: its nominal pose). ``openings``: robot name -> jaw opening in metres (default: open), a
        finite number in ``[0, max_opening]`` (within ``OPENING_TOL``); checked.
        """
        for arg, value in (("joints", joints), ("part_poses", part_poses),
                           ("openings", openings)):
            if value is not None and not isinstance(value, Mapping):
                raise CellsightError(f"Cell.snapshot: {arg} must map names to values (a dict), "
                                     f"got {short_repr(value)}")
        joints = dict(joints or {})
        part_poses = dict(part_poses or {})
        openings = dict(openings or {})
        for name in list(joints) + list(openings):
            self.robot(name)
        for name in openings:
            if self.robot(name).tool is None:
                raise CellsightError(f"robot {name}: has no gripper, yet a jaw opening "
                                     f"({short_repr(openings[name])}) was given")
        for name in part_poses:
            self.workpiece(name)
        used_q, used_open, robot_frames = self._robot_frames(joints, openings)
        used_parts = self._part_poses(part_poses)
        poses = np.empty((len(self.objects), 4, 4))
        for k, frame in enumerate(self.frames):
            if frame.kind == "part":
                poses[k] = used_parts[frame.owner]
            elif frame.kind == "static":
                poses[k] = self.static[frame.index].T_base_obj
            else:
                poses[k] = robot_frames[frame.owner][frame.kind, frame.index]
        return Snapshot(self, poses, used_q, used_open, used_parts)

    def _robot_frames(self, joints: dict, openings: dict) -> tuple[dict, dict, dict]:
        """Per robot: the joint vector and jaw opening used, and ``T_base_frame`` of its frames
        keyed by ``(kind, index)`` of :class:`ObjectFrame` (links, palm, jaws)."""
        used_q, used_open, frames = {}, {}, {}
        for robot in self.robots:
            q = robot.chain.check_q(joints.get(robot.name, robot.home), check_limits=True,
                                    tol=JOINT_LIMIT_TOL)
            used_q[robot.name] = q
            links = robot.link_poses(q)
            poses = {("link", i): T for i, T in enumerate(links)}
            if robot.tool is not None:
                tool = links[-1] @ robot.tool.T_flange_tool
                opening = _opening(robot, openings.get(robot.name, robot.tool.max_opening))
                used_open[robot.name] = opening
                poses["palm", None] = tool
                for jaw, T in enumerate(robot.tool.jaw_poses(opening)):
                    poses["jaw", jaw] = tool @ T
            frames[robot.name] = poses
        return used_q, used_open, frames

    def _part_poses(self, part_poses: dict) -> dict[str, np.ndarray]:
        """``T_base_part`` of every workpiece: given, else its nominal pose; checked."""
        used_parts = {}
        for part in self.workpieces:
            T = np.asarray(part_poses.get(part.name, part.T_base_part), dtype=float)
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                raise CellsightError(f"workpiece {part.name}: pose must be a finite 4x4 matrix")
            if not is_rigid(T):
                raise CellsightError(f"workpiece {part.name}: pose must be a rigid transform "
                                     f"(rotation with det +1: no scale, no mirror; last row "
                                     f"0 0 0 1), got {short_repr(T.round(6).tolist())}")
            used_parts[part.name] = T
        return used_parts

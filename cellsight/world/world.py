"""The simulated cell: a kinematic MuJoCo world generated from the cell model.

Stepping (500 Hz, ``dt_control`` = 2 ms) is kinematic, like a cell whose industrial
controllers track their set-points: each step writes the joint values and the workpiece poses
and MuJoCo computes the body, geom and camera poses (``mj_kinematics``); nothing is integrated.

- Robots: ideal position control. A robot driven by the caller reaches each joint set-point
  within the control period (clipped to its joint limits); a robot with a task follows its
  timed waypoints (:class:`~cellsight.world.paths.JointTask`); any other robot holds still.
- Grippers (pneumatic): the jaw opening moves towards the commanded opening at ``jaw_speed``
  (m/s) and stops when both jaws touch a part lying between them (a jaw that touches first
  pushes the part sideways along the jaws' axis, in the horizontal plane, until the other one
  touches, centring it as a real parallel gripper does). The grasp engages only when the
  jaws are closed on the part *and* the TCP is within ``grasp_tolerance`` (m, rad) of the part's
  grasp pose; from then on the part is welded to the TCP at its relative pose of that
  instant. It is released as soon as the jaws open: it then falls straight down (gravity,
  no rotation) onto whatever lies below it (ray casts) and rests there.
- Conveyor: a :class:`~cellsight.world.paths.ConveyorPath` moves its workpiece until the first
  grasp; after a release the conveyor no longer carries it.
- Truth: joint values, jaw openings, part poses and object poses are read from MuJoCo; feature
  visibility comes from MuJoCo ray casts (:mod:`cellsight.world.truth`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np

from cellsight.geometry.transforms import invert_pose, transform_points
from cellsight.model import Cell
from cellsight.world.grasp import JawPads, PartSection, default_grasp_pose, grasp_error
from cellsight.world.mjcf import (
    GROUP_PART,
    GROUP_STATIC,
    body_name,
    cell_mjcf,
    joint_name,
    object_bodies,
    tcp_site_name,
)
from cellsight.world.paths import ConveyorPath, JointTask, Waypoint
from cellsight.world.render import GrayRenderer
from cellsight.world.truth import RayVisibility, cast_visibility

GRAVITY = 9.81  # m/s^2


@dataclass
class _Jaws:
    opening: float
    command: float
    clamped: str | None = None  # part the jaws are closed on
    holding: str | None = None  # part welded to the TCP


@dataclass
class _Part:
    mode: str  # "conveyor", "resting" or "held"
    pose: np.ndarray
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))  # pushes while on the conveyor
    T_tcp_part: np.ndarray | None = None
    fall_left: float = 0.0
    fall_speed: float = 0.0


def _pose(xpos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = xmat.reshape(3, 3)
    T[:3, 3] = xpos
    return T


class World:
    """The simulated cell (see the module docstring).

    ``conveyor``: the conveyor's path (default: still). ``tasks``: robot name -> timed joint
    waypoints, starting from the robot's initial joints at t = 0. ``joint_noise_std``: standard
    deviation of the measured joints (rad or m). ``render_size``: (width, height) of the
    rendered images (default: each camera's own size). ``initial_joints``: robot name -> joint
    vector at t = 0 (default HOME). ``grasp_poses``: workpiece name -> ``T_part_tcp`` of its
    grasp (default: the cell file's ``grasp``, else
    :func:`~cellsight.world.grasp.default_grasp_pose`). ``grasp_tolerance``:
    largest TCP position (m) and rotation (rad) error for a grasp to engage. ``jaw_speed``: rate
    of change of the jaw opening (m/s).
    """

    dt_control = 1.0 / 500.0
    dt_vision = 1.0 / 26.0

    def __init__(
        self,
        cell: Cell,
        *,
        seed: int = 0,
        conveyor: ConveyorPath | None = None,
        tasks: Mapping[str, Sequence[Waypoint]] | None = None,
        joint_noise_std: float = 1e-4,
        render_size: tuple[int, int] | None = None,
        initial_joints: Mapping[str, np.ndarray] | None = None,
        grasp_poses: Mapping[str, np.ndarray] | None = None,
        grasp_tolerance: tuple[float, float] = (0.01, math.radians(10.0)),
        jaw_speed: float = 0.2,
    ) -> None:
        self.cell = cell
        self.joint_noise_std = float(joint_noise_std)
        self.grasp_tolerance = (float(grasp_tolerance[0]), float(grasp_tolerance[1]))
        self.jaw_speed = float(jaw_speed)
        self._rng = np.random.default_rng(seed)
        self.model = mujoco.MjModel.from_xml_string(cell_mjcf(cell, render_size))
        self.data = mujoco.MjData(self.model)
        self._render_size = render_size
        self._renderer: GrayRenderer | None = None
        self._steps = 0
        self._truth: tuple[int, dict[str, list[RayVisibility]]] | None = None

        self._init_robots(initial_joints or {}, tasks or {})
        self._init_parts(grasp_poses or {}, conveyor or ConveyorPath.still())
        m = self.model
        self._object_body = np.array([m.body(b).id for b in object_bodies(cell)])
        self._geom_names = [m.geom(g).name for g in range(m.ngeom)]  # = cell object names
        mujoco.mj_forward(m, self.data)  # also places the fixed cameras and lights
        self._dirty = False

    def _init_robots(self, initial_joints: Mapping, tasks: Mapping) -> None:
        m, cell = self.model, self.cell
        self._qadr = {
            r.name: np.array([m.jnt_qposadr[m.joint(joint_name(r.name, i)).id]
                              for i in range(1, r.n_joints + 1)])
            for r in cell.robots
        }
        self._lims = {r.name: r.chain.qlim for r in cell.robots}
        initial = dict(initial_joints)
        self._q = {}
        for r in cell.robots:
            q = r.chain.check_q(initial.pop(r.name, r.home), check_limits=True)
            self._q[r.name] = q
            self.data.qpos[self._qadr[r.name]] = q
        if initial:
            raise KeyError(f"initial_joints: no robot named {sorted(initial)}")
        self._tasks = {
            name: JointTask(self._q[cell.robot(name).name], waypoints)
            for name, waypoints in tasks.items()
        }
        self._tools = {r.name: r.tool for r in cell.robots if r.tool is not None}
        self._jaws = {name: _Jaws(t.max_opening, t.max_opening) for name, t in self._tools.items()}
        self._pads = {name: JawPads.of(t) for name, t in self._tools.items()}
        self._jaw_adr = {
            name: [m.jnt_qposadr[m.joint(body_name(name, j)).id] for j in ("jaw1", "jaw2")]
            for name in self._tools
        }
        self._tool_body = {name: m.body(body_name(name, "tool")).id for name in self._tools}
        self._tcp_site = {name: m.site(tcp_site_name(name)).id for name in self._tools}
        for name in self._tools:
            self._write_jaws(name)

    def _init_parts(self, grasp_poses: Mapping, conveyor: ConveyorPath) -> None:
        m, cell = self.model, self.cell
        grasp_poses = dict(grasp_poses)
        gripper = next(iter(self._tools.values()), None)
        self._sections, self._grasp, self._mocap, self._part_body = {}, {}, {}, {}
        self._parts: dict[str, _Part] = {}
        for part in cell.workpieces:
            self._sections[part.name] = PartSection(part.solid)
            if part.name in grasp_poses:
                self._grasp[part.name] = np.asarray(grasp_poses.pop(part.name), dtype=float)
            elif part.T_part_grasp is not None:
                self._grasp[part.name] = part.T_part_grasp.copy()
            elif gripper is not None:
                self._grasp[part.name] = default_grasp_pose(part.solid, gripper)
            self._part_body[part.name] = m.body(part.name).id
            self._mocap[part.name] = m.body_mocapid[self._part_body[part.name]]
            self._parts[part.name] = _Part("resting", part.T_base_part.copy())
        if grasp_poses:
            raise KeyError(f"grasp_poses: no workpiece named {sorted(grasp_poses)}")
        self.conveyor = conveyor
        if cell.workpieces and not conveyor.is_still:
            self._carried = cell.workpiece(conveyor.workpiece or cell.workpieces[0].name).name
            self._parts[self._carried].mode = "conveyor"
            self._parts[self._carried].pose = self._conveyor_pose(0.0)
        for name in self._parts:
            self._write_part(name)

    # --- time and stepping -------------------------------------------------------------------

    @property
    def time(self) -> float:
        """Simulated time (s)."""
        return self._steps * self.dt_control

    def step(
        self,
        setpoints: Mapping[str, np.ndarray] | None = None,
        gripper: Mapping[str, float] | None = None,
    ) -> None:
        """Advance one control period (2 ms).

        ``setpoints``: robot name -> joint position set-point (robots the caller drives; not
        those with a task). ``gripper``: robot name -> commanded jaw opening (m); a command
        stays in force until the next one.
        """
        self._steps += 1
        t = self.time
        for name, q in (setpoints or {}).items():
            if name in self._tasks:
                raise ValueError(f"robot {name} follows its own task; do not drive it")
            if name not in self._lims:
                raise KeyError(f"cell {self.cell.name} has no robot {name!r}")
            q = np.asarray(q, dtype=float)
            lim = self._lims[name]
            if q.shape != (len(lim),) or not np.all(np.isfinite(q)):
                raise ValueError(f"robot {name}: set-point needs {len(lim)} finite values, got {q}")
            self._q[name] = np.clip(q, lim[:, 0], lim[:, 1])
            self.data.qpos[self._qadr[name]] = self._q[name]
        for name, task in self._tasks.items():
            lim = self._lims[name]
            self._q[name] = np.clip(task.at(t), lim[:, 0], lim[:, 1])
            self.data.qpos[self._qadr[name]] = self._q[name]
        for name, opening in (gripper or {}).items():
            self._jaws[name].command = float(np.clip(opening, 0.0, self._tools[name].max_opening))
        for name, part in self._parts.items():
            if part.mode == "conveyor":
                part.pose = self._conveyor_pose(t)
                part.pose[:3, 3] += part.offset
                self._write_part(name)
            elif part.fall_left > 0:
                part.fall_speed += GRAVITY * self.dt_control
                drop = min(part.fall_speed * self.dt_control, part.fall_left)
                part.fall_left -= drop
                part.pose[2, 3] -= drop
                self._write_part(name)
        self._dirty = True
        for name in self._jaws:
            self._step_jaws(name)
        for name, part in self._parts.items():
            if part.mode == "held":
                holder = next(r for r, j in self._jaws.items() if j.holding == name)
                part.pose = self._tcp_pose(holder) @ part.T_tcp_part
                self._write_part(name)
        self._dirty = True

    def _step_jaws(self, robot: str) -> None:
        jaws = self._jaws[robot]
        if jaws.command > jaws.opening:  # opening: let go of everything
            jaws.opening = min(jaws.command, jaws.opening + self.jaw_speed * self.dt_control)
            if jaws.holding is not None:
                self._release(robot)
            jaws.clamped = None
            self._write_jaws(robot)
            return
        if jaws.holding is not None or jaws.command == jaws.opening and jaws.clamped is None:
            return
        self._sync()
        body = self._tool_body[robot]
        T_base_tool = _pose(self.data.xpos[body], self.data.xmat[body])
        T_tool_base = invert_pose(T_base_tool)
        old = jaws.opening
        new = max(jaws.command, old - self.jaw_speed * self.dt_control)
        jaws.clamped = None
        pads = self._pads[robot]
        for name, part in self._parts.items():
            if part.mode == "held":
                continue
            section = self._sections[name]
            T_tool_part = T_tool_base @ part.pose
            y_all = transform_points(T_tool_part, section.vertices)[:, 1]
            if y_all.max() <= 0.5 * new and y_all.min() >= -0.5 * new:
                continue  # the jaws cannot reach it yet (or it lies beyond their ends)
            r1 = section.y_range(T_tool_part, pads.jaw1)
            r2 = r1 if pads.jaw2 == pads.jaw1 else section.y_range(T_tool_part, pads.jaw2)
            if r1 is None or r2 is None:
                continue
            hi, lo = r1[1], r2[0]
            if hi > 0.5 * old + 1e-3 or lo < -0.5 * old - 1e-3:
                continue  # material beyond a jaw's face: the part is not between the jaws
            new = max(new, hi - lo)
            push = min(0.5 * new - hi, 0.0) + max(-0.5 * new - lo, 0.0)
            if push:
                shift = push * T_base_tool[:3, 1]
                shift[2] = 0.0
                part.pose[:3, 3] += shift
                part.offset += shift
                self._write_part(name)
            if new <= hi - lo + 1e-9:
                jaws.clamped = name
                T_base_grasp = part.pose @ self._grasp[name]
                dp, da = grasp_error(T_base_tool @ self._tools[robot].T_tool_tcp, T_base_grasp)
                if dp <= self.grasp_tolerance[0] and da <= self.grasp_tolerance[1]:
                    self._engage(robot, name)
        jaws.opening = new
        self._write_jaws(robot)

    def _engage(self, robot: str, name: str) -> None:
        part = self._parts[name]
        part.mode = "held"
        part.T_tcp_part = invert_pose(self._tcp_pose(robot)) @ part.pose
        part.fall_left = part.fall_speed = 0.0
        self._jaws[robot].holding = name

    def _release(self, robot: str) -> None:
        name = self._jaws[robot].holding
        self._jaws[robot].holding = None
        part = self._parts[name]
        part.mode, part.T_tcp_part = "resting", None
        self._sync()
        part.fall_left, part.fall_speed = self._drop_height(name), 0.0

    def _drop_height(self, name: str) -> float:
        """How far the part can fall straight down before it rests on a static object or
        another workpiece (m): the shortest downward ray cast from its vertices."""
        groups = np.zeros(6, dtype=np.uint8)
        groups[[GROUP_STATIC, GROUP_PART]] = 1
        lift, down = 1e-4, np.array([0.0, 0.0, -1.0])  # start just above a touching support
        drops = []
        for v in transform_points(self._parts[name].pose, self.cell.workpiece(name).solid.vertices):
            d = mujoco.mj_ray(self.model, self.data, v + [0.0, 0.0, lift], down, groups, True,
                              self._part_body[name], None)
            if d >= 0:
                drops.append(d - lift)
        return max(min(drops), 0.0) if drops else 0.0

    def _conveyor_pose(self, t: float) -> np.ndarray:
        T = self.cell.workpiece(self._carried).T_base_part.copy()
        T[:2, 3] = self.conveyor.position(t)
        return T

    def _tcp_pose(self, robot: str) -> np.ndarray:
        self._sync()
        site = self._tcp_site[robot]
        return _pose(self.data.site_xpos[site], self.data.site_xmat[site])

    def _write_jaws(self, robot: str) -> None:
        self.data.qpos[self._jaw_adr[robot]] = 0.5 * self._jaws[robot].opening
        self._dirty = True

    def _write_part(self, name: str) -> None:
        pose, mid = self._parts[name].pose, self._mocap[name]
        self.data.mocap_pos[mid] = pose[:3, 3]
        mujoco.mju_mat2Quat(self.data.mocap_quat[mid], np.ascontiguousarray(pose[:3, :3]).ravel())
        self._dirty = True

    def _sync(self) -> None:
        """Bring MuJoCo's poses up to date with the state written so far."""
        if self._dirty:
            mujoco.mj_kinematics(self.model, self.data)
            self._dirty = False

    # --- placing things (set-up, tests) ------------------------------------------------------

    def place_part(self, name: str, T_base_part: np.ndarray) -> None:
        """Put a workpiece at a pose, resting there (off the conveyor, out of any gripper)."""
        part = self._parts[self.cell.workpiece(name).name]
        for jaws in self._jaws.values():
            if jaws.holding == name:
                jaws.holding = None
        part.mode, part.T_tcp_part = "resting", None
        part.pose = np.array(T_base_part, dtype=float)
        part.fall_left = part.fall_speed = 0.0
        self._write_part(name)

    def grasp_pose(self, name: str) -> np.ndarray:
        """``T_part_tcp`` of the grasp that engages for this workpiece."""
        return self._grasp[self.cell.workpiece(name).name].copy()

    # --- truth and measurements --------------------------------------------------------------

    def true_joints(self) -> dict[str, np.ndarray]:
        """Joint values of every robot (rad, m), read from MuJoCo."""
        return {name: self.data.qpos[adr].copy() for name, adr in self._qadr.items()}

    def measured_joints(self) -> dict[str, np.ndarray]:
        """Joint values with Gaussian noise of ``joint_noise_std`` (seeded)."""
        return {
            name: q + self._rng.normal(0.0, self.joint_noise_std, q.shape)
            for name, q in self.true_joints().items()
        }

    def jaw_openings(self) -> dict[str, float]:
        """Jaw opening (m) of every robot with a gripper, read from MuJoCo."""
        return {name: float(self.data.qpos[adr].sum()) for name, adr in self._jaw_adr.items()}

    def jaws_closed_on_part(self, robot: str) -> bool:
        """Whether the robot's jaws are closed on a workpiece (both jaws touch it)."""
        return self._jaws[robot].clamped is not None

    def grasped(self, robot: str) -> bool:
        """Whether the robot holds a workpiece (grasp engaged)."""
        return self._jaws[robot].holding is not None

    def true_part_poses(self) -> dict[str, np.ndarray]:
        """``T_base_part`` of every workpiece, read from MuJoCo."""
        self._sync()
        return {
            name: _pose(self.data.xpos[b], self.data.xmat[b]) for name, b in self._part_body.items()
        }

    def object_poses(self) -> np.ndarray:
        """``T_base_obj`` of every cell object (``cell.objects`` order), read from MuJoCo."""
        self._sync()
        T = np.zeros((len(self._object_body), 4, 4))
        T[:, :3, :3] = self.data.xmat[self._object_body].reshape(-1, 3, 3)
        T[:, :3, 3] = self.data.xpos[self._object_body]
        T[:, 3, 3] = 1.0
        return T

    def render(self) -> list[np.ndarray]:
        """One (H, W) uint8 grayscale image per camera, in ``cell.cameras`` order."""
        self._sync()
        if self._renderer is None:
            self._renderer = GrayRenderer(self.model, self.cell.cameras, self._render_size)
        return self._renderer.render(self.data)

    def _rays(self) -> dict[str, list[RayVisibility]]:
        if self._truth is None or self._truth[0] != self._steps or self._dirty:
            self._sync()
            out = {}
            for name, T in self.true_part_poses().items():
                pts = self.cell.workpiece(name).feature_points @ T[:3, :3].T + T[:3, 3]
                out[name] = [
                    cast_visibility(self.model, self.data, cam, pts, self._geom_names)
                    for cam in self.cell.cameras
                ]
            self._truth = (self._steps, out)
        return self._truth[1]

    def true_visibility(self) -> dict[str, list[np.ndarray]]:
        """Workpiece -> per camera, which features (F,) are visible (MuJoCo ray casts)."""
        return {name: [r.visible.copy() for r in rays] for name, rays in self._rays().items()}

    def true_occluders(self) -> dict[str, list[list[str]]]:
        """Workpiece -> per camera, per feature: the cell object that hides it ('' if visible,
        'outside' if it projects outside the image, 'behind' if behind the camera)."""
        return {name: [list(r.occluders) for r in rays] for name, rays in self._rays().items()}

    def close(self) -> None:
        """Free the renderer's OpenGL context."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

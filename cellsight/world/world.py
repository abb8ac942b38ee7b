"""The simulated cell: a kinematic MuJoCo world generated from the cell model.

Stepping (``CONTROL_HZ`` = 500 Hz, ``dt_control`` = 2 ms) is kinematic, like a cell whose
industrial controllers track their set-points: each step writes the joint values and the
workpiece poses and MuJoCo computes the body, geom and camera poses (``mj_kinematics``);
nothing is integrated. :class:`World` puts together its parts, each in its own module:

- robots (:class:`RobotJoints`, here): ideal position control. A robot driven by the caller
  reaches each joint set-point within the control period (clipped to its joint limits); a
  robot with a task follows its timed waypoints (:class:`~cellsight.world.paths.JointTask`);
  any other robot holds still;
- grippers (:class:`~cellsight.world.grasp.Grippers`): pneumatic parallel jaws that centre,
  clamp and grasp a part, and release it when they open;
- workpieces (:class:`~cellsight.world.paths.PartMotion`): carried by the conveyor
  (:class:`~cellsight.world.paths.ConveyorPath`) until the first grasp, held, falling after a
  release, resting;
- truth (:class:`~cellsight.world.truth.RayTruth`): joint values, jaw openings, part poses and
  object poses are read from MuJoCo; what each camera sees comes from MuJoCo ray casts, in the
  predictors' own type (:meth:`World.true_views`);
- the MuJoCo state they share: :class:`~cellsight.world.scene.Scene`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import mujoco
import numpy as np

from cellsight.model import Cell
from cellsight.rates import CONTROL_HZ, VISION_HZ
from cellsight.visibility import Views
from cellsight.world.grasp import Grippers
from cellsight.world.mjcf import cell_mjcf, joint_name
from cellsight.world.paths import ConveyorPath, JointTask, PartMotion, Waypoint
from cellsight.world.render import GrayRenderer
from cellsight.world.scene import Scene
from cellsight.world.truth import RayTruth


class RobotJoints:
    """Every robot's joint values (rad, m), written into MuJoCo (module docstring).

    ``initial_joints``: robot name -> joint vector at t = 0 (default HOME, checked against the
    joint limits); ``tasks``: robot name -> timed joint waypoints, starting from its initial
    joints at t = 0."""

    def __init__(self, scene: Scene, cell: Cell, initial_joints: Mapping[str, np.ndarray],
                 tasks: Mapping[str, Sequence[Waypoint]]) -> None:
        self.scene, self.cell = scene, cell
        m = scene.model
        self._qadr = {
            r.name: np.array([m.jnt_qposadr[m.joint(joint_name(r.name, i)).id]
                              for i in range(1, r.n_joints + 1)])
            for r in cell.robots
        }
        self._lims = {r.name: r.chain.qlim for r in cell.robots}
        initial = dict(initial_joints)
        for r in cell.robots:
            self._set(r.name, r.chain.check_q(initial.pop(r.name, r.home), check_limits=True))
        if initial:
            raise KeyError(f"initial_joints: no robot named {sorted(initial)}")
        q0 = self.true()
        self._tasks = {name: JointTask(q0[cell.robot(name).name], waypoints)
                       for name, waypoints in tasks.items()}

    def drive(self, setpoints: Mapping[str, np.ndarray]) -> None:
        """Reach joint set-points (robot name -> vector), clipped to the joint limits; a robot
        that follows its own task cannot be driven."""
        for name, q in setpoints.items():
            if name in self._tasks:
                raise ValueError(f"robot {name} follows its own task; do not drive it")
            if name not in self._lims:
                raise KeyError(f"cell {self.cell.name} has no robot {name!r}")
            q = np.asarray(q, dtype=float)
            lim = self._lims[name]
            if q.shape != (len(lim),) or not np.all(np.isfinite(q)):
                raise ValueError(f"robot {name}: set-point needs {len(lim)} finite values, got {q}")
            self._set(name, q)

    def follow_tasks(self, t: float) -> None:
        """Every robot with a task takes its set-point at time ``t`` (s)."""
        for name, task in self._tasks.items():
            self._set(name, task.at(t))

    def true(self) -> dict[str, np.ndarray]:
        """Joint values of every robot, read from MuJoCo."""
        qpos = self.scene.data.qpos
        return {name: qpos[adr].copy() for name, adr in self._qadr.items()}

    def _set(self, name: str, q: np.ndarray) -> None:
        lim = self._lims[name]
        self.scene.set_qpos(self._qadr[name], np.clip(q, lim[:, 0], lim[:, 1]))


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

    Its parts are attributes: ``scene``, ``robots``, ``parts``, ``grippers``, ``truth``.
    """

    dt_control = 1.0 / CONTROL_HZ
    dt_vision = 1.0 / VISION_HZ

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
        self._rng = np.random.default_rng(seed)
        model = mujoco.MjModel.from_xml_string(cell_mjcf(cell, render_size))
        self.scene = Scene(model, mujoco.MjData(model))
        self.robots = RobotJoints(self.scene, cell, initial_joints or {}, tasks or {})
        self.parts = PartMotion(self.scene, cell, conveyor or ConveyorPath.still())
        self.grippers = Grippers(self.scene, cell, self.parts, grasp_poses or {},
                                 grasp_tolerance, jaw_speed, self.dt_control)
        self.truth = RayTruth(self.scene, cell)
        self._render_size = render_size
        self._renderer: GrayRenderer | None = None
        self._steps = 0

    @property
    def time(self) -> float:
        """Simulated time (s)."""
        return self._steps * self.dt_control

    def step(
        self,
        setpoints: Mapping[str, np.ndarray] | None = None,
        gripper: Mapping[str, float] | None = None,
    ) -> None:
        """Advance one control period (``dt_control``).

        ``setpoints``: robot name -> joint position set-point (robots the caller drives; not
        those with a task). ``gripper``: robot name -> commanded jaw opening (m); a command
        stays in force until the next one.
        """
        self._steps += 1
        t = self.time
        self.robots.drive(setpoints or {})
        self.robots.follow_tasks(t)
        self.grippers.command(gripper or {})
        self.parts.step(t, self.dt_control)
        self.grippers.step()

    def place_part(self, name: str, T_base_part: np.ndarray) -> None:
        """Put a workpiece at a pose, resting there (off the conveyor, out of any gripper)."""
        name = self.cell.workpiece(name).name
        self.grippers.let_go(name)
        self.parts.place(name, T_base_part)

    def grasp_pose(self, name: str) -> np.ndarray:
        """``T_part_tcp`` of the grasp that engages for this workpiece."""
        return self.grippers.grasp_pose(self.cell.workpiece(name).name)

    def true_joints(self) -> dict[str, np.ndarray]:
        """Joint values of every robot (rad, m), read from MuJoCo."""
        return self.robots.true()

    def measured_joints(self) -> dict[str, np.ndarray]:
        """Joint values with Gaussian noise of ``joint_noise_std`` (seeded)."""
        return {
            name: q + self._rng.normal(0.0, self.joint_noise_std, q.shape)
            for name, q in self.true_joints().items()
        }

    def jaw_openings(self) -> dict[str, float]:
        """Jaw opening (m) of every robot with a gripper, read from MuJoCo."""
        return self.grippers.openings()

    def jaws_closed_on_part(self, robot: str) -> bool:
        """Whether the robot's jaws are closed on a workpiece (both jaws touch it)."""
        return self.grippers.clamped(robot) is not None

    def grasped(self, robot: str) -> bool:
        """Whether the robot holds a workpiece (grasp engaged)."""
        return self.grippers.holding(robot) is not None

    def grasp_error(self, robot: str) -> tuple[float, float] | None:
        """Position (m) and rotation (rad) error of the robot's TCP from the held workpiece's
        grasp pose at the instant the grasp engaged; None while it holds nothing."""
        return self.grippers.grasp_error(robot)

    def true_part_poses(self) -> dict[str, np.ndarray]:
        """``T_base_part`` of every workpiece, read from MuJoCo."""
        return self.parts.true_poses()

    def true_views(self) -> Views:
        """What each camera truly sees of every workpiece (MuJoCo ray casts at the true state):
        workpiece -> one :class:`~cellsight.visibility.CameraVisibility` per camera
        (``cell.cameras`` order), as the predictors answer (:mod:`cellsight.world.truth`)."""
        return self.truth.views(self.true_part_poses())

    def render(self) -> list[np.ndarray]:
        """One (H, W) uint8 grayscale image per camera, in ``cell.cameras`` order."""
        self.scene.sync()
        if self._renderer is None:
            self._renderer = GrayRenderer(self.scene.model, self.cell.cameras, self._render_size)
        return self._renderer.render(self.scene.data)

    def close(self) -> None:
        """Free the renderer's OpenGL context."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

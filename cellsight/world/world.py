"""The simulated cell: a MuJoCo world generated from its own cell model (the one the world
*is*, which may differ from the cell file the system uses) and its
:class:`~cellsight.world.imperfections.Imperfections`.

Stepping (``CONTROL_HZ`` = 500 Hz, ``dt_control`` = 2 ms): each step moves the joints through
their servos, writes the joint values and the workpiece and intruder poses, and MuJoCo computes
the body, geom and camera poses (``mj_kinematics``) and the contacts (``mj_collision``); no
contact force acts. With a servo of MuJoCo's actuators (``ServoParams.mujoco``) the joints'
set-points go to MuJoCo's position actuators instead and ``mj_step`` integrates the arms, whose
contacts push back (:mod:`cellsight.world.mjcf`); the jaws keep the openings the grippers give
them. :class:`World` puts together its parts, each in its own module:

- robots (:class:`RobotJoints`, here): position control through each joint's servo
  (:mod:`cellsight.world.servo`; the ideal one reaches each set-point within the control
  period; or MuJoCo's actuators), clipped to the joint limits, in the encoders' terms
  (offsets, resolution, noise); a robot with a task follows its timed waypoints
  (:class:`~cellsight.world.paths.JointTask`); any other robot holds still;
- grippers (:class:`~cellsight.world.grasp.Grippers`): pneumatic parallel jaws that centre,
  clamp and grasp a part, and release it when they open;
- workpieces (:class:`~cellsight.world.paths.PartMotion`): carried by the conveyor
  (:class:`~cellsight.world.paths.ConveyorPath`) until the first grasp, held, falling after a
  release, resting;
- intruders (:mod:`cellsight.world.intruders`) the cell file does not know;
- collisions (:class:`~cellsight.world.contacts.ContactMonitor`), checked every step;
- images (:mod:`cellsight.world.render`, then :mod:`cellsight.world.images`);
- truth (:class:`~cellsight.world.truth.RayTruth`): joint values, jaw openings, part poses and
  object poses are read from MuJoCo; what each camera sees comes from MuJoCo ray casts, in the
  predictors' own type (:meth:`World.true_views`);
- the MuJoCo state they share: :class:`~cellsight.world.scene.Scene`.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import partial

import mujoco
import numpy as np

from cellsight.model import Cell
from cellsight.rates import CONTROL_HZ, VISION_HZ
from cellsight.visibility import Views
from cellsight.world.board_plate import Plate, plate_files
from cellsight.world.contacts import ContactMonitor, mount_bodies
from cellsight.world.exposure_time import ExposureHistory
from cellsight.world.faults import Faults
from cellsight.world.grasp import Grasp, Grippers
from cellsight.world.images import Imager
from cellsight.world.imperfections import IDEAL, Imperfections
from cellsight.world.intruders import Intruders
from cellsight.world.mjcf import body_name, cell_mjcf, excluded_pairs, joint_name, link_inertia
from cellsight.world.paths import ConveyorPath, JointTask, PartMotion, Waypoint
from cellsight.world.render import GrayRenderer
from cellsight.world.scene import Scene
from cellsight.world.servo import JointServo, ServoParams
from cellsight.world.shots import Shot
from cellsight.world.truth import RayTruth


class RobotJoints:
    """Every robot's joints (rad, m): set-points through each robot's servo into MuJoCo, and
    the encoders' readings (module docstring).

    ``initial_joints``: robot name -> joint vector at t = 0 as the encoders read it (default
    HOME, checked against the joint limits); ``tasks``: robot name -> timed joint waypoints,
    starting from its initial joints at t = 0. ``errors``: the encoders' offsets, resolution and
    noise and the servo (:class:`~cellsight.world.imperfections.Imperfections`); set-points and
    readings are in the encoders' terms, the joints move in the true ones."""

    def __init__(self, scene: Scene, cell: Cell, initial_joints: Mapping[str, np.ndarray],
                 tasks: Mapping[str, Sequence[Waypoint]], errors: Imperfections,
                 dt: float) -> None:
        self.scene, self.cell = scene, cell
        m = scene.model
        self._qadr = {
            r.name: np.array([m.jnt_qposadr[m.joint(joint_name(r.name, i)).id]
                              for i in range(1, r.n_joints + 1)])
            for r in cell.robots
        }
        self._lims = {r.name: r.chain.qlim for r in cell.robots}
        self._offset = {r.name: np.asarray(errors.encoder_offsets.get(r.name, np.zeros(r.n_joints)),
                                           dtype=float) for r in cell.robots}
        self._noise = {r.name: np.where(r.chain.prismatic, errors.noise_m, errors.noise_rad)
                       for r in cell.robots}
        self._quantum = {r.name: np.where(r.chain.prismatic, errors.quantum_m, errors.quantum_rad)
                         for r in cell.robots}
        self._quantised = {name: bool(step.any()) for name, step in self._quantum.items()}
        initial = dict(initial_joints)
        q0 = {r.name: r.chain.check_q(initial.pop(r.name, r.home), check_limits=True)
              for r in cell.robots}
        if initial:
            raise KeyError(f"initial_joints: no robot named {sorted(initial)}")
        self._servo = {r.name: JointServo(errors.servo, self._true_target(r.name, q0[r.name]),
                                          dt, r.max_velocity) for r in cell.robots}
        for name in self._servo:
            self._write(name)
        self._tasks = {name: JointTask(q0[cell.robot(name).name], waypoints)
                       for name, waypoints in tasks.items()}
        self._actuators = ({r.name: np.array([m.actuator(f"{r.name}/a{i}").id
                                              for i in range(1, r.n_joints + 1)])
                            for r in cell.robots} if errors.servo.mujoco else None)
        self._dofs = {r.name: np.array([m.jnt_dofadr[m.joint(joint_name(r.name, i)).id]
                                        for i in range(1, r.n_joints + 1)]) for r in cell.robots}
        if self._actuators is not None:
            for name in self._servo:
                scene.data.ctrl[self._actuators[name]] = self._servo[name].q

    def drive(self, setpoints: Mapping[str, np.ndarray]) -> None:
        """Joint set-points (robot name -> vector, as the encoders read), clipped to the joint
        limits; a robot that follows its own task cannot be driven. They are reached by
        :meth:`advance`."""
        for name, q in setpoints.items():
            if name in self._tasks:
                raise ValueError(f"robot {name} follows its own task; do not drive it")
            if name not in self._lims:
                raise KeyError(f"cell {self.cell.name} has no robot {name!r}")
            q = np.asarray(q, dtype=float)
            lim = self._lims[name]
            if q.shape != (len(lim),) or not np.all(np.isfinite(q)):
                raise ValueError(f"robot {name}: set-point needs {len(lim)} finite values, got {q}")
            self._servo[name].target = self._true_target(name, q)

    def follow_tasks(self, t: float) -> None:
        """Every robot with a task takes its set-point at time ``t`` (s)."""
        for name, task in self._tasks.items():
            self._servo[name].target = self._true_target(name, task.at(t))

    def advance(self) -> None:
        """One control period of every robot's servo; with MuJoCo's actuators, their
        set-points (the world integrates them, then calls :meth:`limit_velocity`)."""
        for name in self._servo:
            if self._actuators is not None:
                self.scene.data.ctrl[self._actuators[name]] = self._servo[name].actuator_setpoint()
                continue
            self._servo[name].step()
            self._write(name)

    def limit_velocity(self) -> None:
        """Clip every joint's velocity to the servo's limit (after MuJoCo's step)."""
        qvel = self.scene.data.qvel
        for name, dofs in self._dofs.items():
            limit = self._servo[name].max_velocity
            qvel[dofs] = np.minimum(np.maximum(qvel[dofs], -limit), limit)  # np.clip, faster

    def place(self, joints: Mapping[str, np.ndarray]) -> None:
        """Put robots at joint vectors (as the encoders read) at once, at rest (a replayed
        state, not a motion)."""
        self.drive(joints)
        for name in joints:
            self._servo[name].place(self._servo[name].target)
            self._write(name)
            self.scene.data.qvel[self._dofs[name]] = 0.0
            if self._actuators is not None:
                self.scene.data.ctrl[self._actuators[name]] = self._servo[name].q

    def true(self) -> dict[str, np.ndarray]:
        """Joint values of every robot, read from MuJoCo."""
        qpos = self.scene.data.qpos
        return {name: qpos[adr].copy() for name, adr in self._qadr.items()}

    def measured(self, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """What the encoders read: the true values plus their offsets, rounded to their
        resolution, plus their Gaussian noise (drawn from ``rng``)."""
        qpos, out = self.scene.data.qpos, {}
        for name, adr in self._qadr.items():
            q = qpos[adr] + self._offset[name]
            step = self._quantum[name]
            if self._quantised[name]:
                q = np.where(step > 0, np.round(q / np.where(step > 0, step, 1.0)) * step, q)
            # the draws of rng.normal(0, noise): loc + scale * z, the same numbers
            out[name] = q + self._noise[name] * rng.standard_normal(q.shape)
        return out

    def _true_target(self, name: str, q: np.ndarray) -> np.ndarray:
        lim = self._lims[name]
        return np.minimum(np.maximum(np.asarray(q, dtype=float) - self._offset[name], lim[:, 0]),
                          lim[:, 1])

    def _write(self, name: str) -> None:
        lim = self._lims[name]
        self.scene.set_qpos(self._qadr[name],
                            np.minimum(np.maximum(self._servo[name].q, lim[:, 0]), lim[:, 1]))



def _model(cell: Cell, render_size: tuple[int, int] | None, errors: Imperfections,
           initial_joints: Mapping[str, np.ndarray],
           plates: Mapping[str, Plate]) -> mujoco.MjModel:
    """The world's MuJoCo model (:func:`~cellsight.world.mjcf.cell_mjcf`): kinematic (the
    pairs of :func:`~cellsight.world.mjcf.excluded_pairs` left out of its collisions), or with
    MuJoCo's actuators when the servo asks for them, its contacts pushing back except between
    :func:`~cellsight.world.mjcf.excluded_pairs` (the mounts found in the kinematic model,
    the robots at their initial joints: :func:`~cellsight.world.contacts.mount_bodies`), the
    actuators tuned to each joint's inertia there (:func:`~cellsight.world.mjcf.link_inertia`);
    ``plates`` on the robots' flanges."""
    files = plate_files(plates)
    kinematic = mujoco.MjModel.from_xml_string(
        cell_mjcf(cell, render_size, errors.intruders, exclude=excluded_pairs(cell),
                  plates=plates), files)
    if not errors.servo.mujoco:
        return kinematic
    scene = Scene(kinematic, mujoco.MjData(kinematic))
    RobotJoints(scene, cell, initial_joints, {}, replace(errors, servo=ServoParams()), 0.0)
    exclude = excluded_pairs(cell, mount_bodies(scene, cell))
    links = link_inertia(scene.model, scene.data, cell)
    return mujoco.MjModel.from_xml_string(
        cell_mjcf(cell, render_size, errors.intruders, errors.servo, exclude, plates, links),
        files)


def _jaw_addresses(model: mujoco.MjModel, cell: Cell) -> tuple[np.ndarray, np.ndarray]:
    """``qpos`` and ``qvel`` addresses of every gripper's jaw joints."""
    ids = [model.joint(body_name(r.name, jaw)).id for r in cell.robots if r.tool is not None
           for jaw in ("jaw1", "jaw2")]
    return model.jnt_qposadr[ids], model.jnt_dofadr[ids]


def _in_hand(grippers: Grippers, robot: str) -> str | None:
    """The workpiece the robot holds or has its jaws closed on, or None."""
    grasp = grippers.grasp(robot)
    return grasp.part if grasp is not None else grippers.clamped(robot)

def _knock_camera(scene: Scene, truth: RayTruth, index: int, T_delta: np.ndarray) -> None:
    """Move camera ``index`` of the world by ``T_delta`` in its own frame: MuJoCo's camera
    (what renders) and the truth's (a copy of its cell with the moved camera)."""
    camera = truth.cell.cameras[index]
    moved = replace(camera, T_base_cam=camera.T_base_cam @ np.asarray(T_delta, dtype=float))
    cell = copy.copy(truth.cell)
    cell.cameras = [moved if i == index else c for i, c in enumerate(truth.cell.cameras)]
    truth.cell = cell
    scene.move_camera(camera.name, moved.T_base_cam)


@dataclass(frozen=True)
class Hands:
    """What the robots' hands do in the world: ``grasp_poses``: workpiece name ->
    ``T_part_tcp`` of its grasp (default: the cell file's ``grasp``, else
    :func:`~cellsight.model.grasp.default_grasp_pose`); ``grasp_tolerance``: largest TCP
    position (m) and rotation (rad) error for a grasp to engage; ``jaw_speed``: rate of change
    of the jaw opening (m/s); ``plates``: robot name -> a printed plate on its flange (a
    calibration board: :mod:`~cellsight.world.board_plate`; a robot without a tool)."""

    grasp_poses: Mapping[str, np.ndarray] = field(default_factory=dict)
    grasp_tolerance: tuple[float, float] = (0.01, math.radians(10.0))
    jaw_speed: float = 0.2
    plates: Mapping[str, Plate] = field(default_factory=dict)


class World:
    """The simulated cell (see the module docstring).

    ``conveyor``: the conveyor's path, or one per carried part (a line; default: still).
    ``tasks``: robot name -> timed joint waypoints, starting from the robot's initial joints at
    t = 0. ``errors``: how the world
    departs from an ideal one over time and in its sensors
    (:class:`~cellsight.world.imperfections.Imperfections`; its geometry's errors are in
    ``cell``, the world's own). ``render_size``: (width, height) of the
    rendered images (default: each camera's own size). ``initial_joints``: robot name -> joint
    vector at t = 0 (default HOME). ``hands``: the grasps, how they engage, the jaws' speed and
    the plates on tool-less flanges (:class:`Hands`).

    Its parts are attributes: ``scene``, ``robots``, ``parts``, ``grippers``, ``intruders``,
    ``faults``,
    ``contacts`` (the collisions so far), ``truth``.
    """

    dt_control = 1.0 / CONTROL_HZ
    dt_vision = 1.0 / VISION_HZ

    def __init__(
        self,
        cell: Cell,
        *,
        seed: int = 0,
        conveyor: ConveyorPath | Sequence[ConveyorPath] | None = None,
        tasks: Mapping[str, Sequence[Waypoint]] | None = None,
        errors: Imperfections = IDEAL,
        render_size: tuple[int, int] | None = None,
        initial_joints: Mapping[str, np.ndarray] | None = None,
        hands: Hands | None = None,
    ) -> None:
        self.cell, self.errors = cell, errors
        hands = hands or Hands()
        self._rng = np.random.default_rng(seed)
        model = _model(cell, render_size, errors, initial_joints or {}, dict(hands.plates))
        self.scene = Scene(model, mujoco.MjData(model))
        self._jaws = _jaw_addresses(model, cell) if errors.servo.mujoco else None
        self.robots = RobotJoints(self.scene, cell, initial_joints or {}, tasks or {}, errors,
                                  self.dt_control)
        conveyors = [conveyor] if isinstance(conveyor, ConveyorPath) else list(conveyor or ())
        self.parts = PartMotion(self.scene, cell, conveyors,
                                errors.grasp_seat, errors.slip_m_s)
        self.grippers = Grippers(self.scene, cell, self.parts, dict(hands.grasp_poses),
                                 hands.grasp_tolerance, hands.jaw_speed, self.dt_control)
        self.intruders = Intruders(self.scene, errors.intruders)
        self.truth = RayTruth(self.scene, cell)
        self.faults = Faults(errors.kidnap, errors.knock,
                             partial(_knock_camera, self.scene, self.truth))
        self.contacts = ContactMonitor(
            self.scene, cell, errors.collision_threshold_m,
            partial(_in_hand, self.grippers))
        self._render_size = render_size
        self._renderer: GrayRenderer | None = None
        self._imager = None if errors.images is None else Imager(errors.images, [seed, 2])
        im = errors.images
        self._history = (ExposureHistory(self.scene, im.exposure_s, im.interlaced,
                                         self.dt_control)
                         if im is not None and (im.exposure_s > 0 or im.interlaced) else None)
        self._steps = 0
        self.time = 0.0
        """Simulated time (s)."""

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
        self.time = t = self._steps * self.dt_control
        self.robots.drive(setpoints or {})
        self.robots.follow_tasks(t)
        self.robots.advance()
        if self._jaws is not None:  # MuJoCo's dynamics; the jaws keep their openings
            qpos, qvel = self.scene.data.qpos, self.scene.data.qvel
            openings = qpos[self._jaws[0]].copy()
            self.scene.step()
            qpos[self._jaws[0]], qvel[self._jaws[1]] = openings, 0.0
            self.robots.limit_velocity()
        self.intruders.step(t)
        self.grippers.command(gripper or {})
        self.faults.step(t, self.parts)
        self.parts.step(t, self.dt_control)
        self.grippers.step()
        self.contacts.check(t)
        if self._history is not None:  # joint positions and mocap poses, no kinematics
            self._history.record(t)

    def place_part(self, name: str, T_base_part: np.ndarray) -> None:
        """Put a workpiece at a pose, resting there (off the conveyor, out of any gripper)."""
        name = self.cell.workpiece(name).name
        self.grippers.let_go(name)
        self.parts.place(name, T_base_part)

    def true_joints(self) -> dict[str, np.ndarray]:
        """Joint values of every robot (rad, m), read from MuJoCo."""
        return self.robots.true()

    def measured_joints(self) -> dict[str, np.ndarray]:
        """Joint values as the encoders read them (offsets, resolution and seeded noise of
        ``errors``)."""
        return self.robots.measured(self._rng)

    def jaw_openings(self) -> dict[str, float]:
        """Jaw opening (m) of every robot with a gripper, read from MuJoCo."""
        return self.grippers.openings()

    def jaws_closed_on_part(self, robot: str) -> bool:
        """Whether the robot's jaws are closed on a workpiece (both jaws touch it)."""
        return self.grippers.clamped(robot) is not None

    def grasp(self, robot: str) -> Grasp | None:
        """The robot's engaged grasp: the workpiece it holds and its TCP's error from that
        workpiece's grasp pose at the instant the grasp engaged; None while it holds nothing."""
        return self.grippers.grasp(robot)

    def true_part_poses(self) -> dict[str, np.ndarray]:
        """``T_base_part`` of every workpiece, read from MuJoCo."""
        return self.parts.true_poses()

    def true_views(self) -> Views:
        """What each camera truly sees of every workpiece (MuJoCo ray casts at the true state):
        workpiece -> one :class:`~cellsight.visibility.CameraVisibility` per camera
        (``cell.cameras`` order), as the predictors answer (:mod:`cellsight.world.truth`)."""
        return self.truth.views(self.true_part_poses())

    def true_corners(self) -> list[np.ndarray]:
        """Per camera (``cell.cameras`` order), the pixels (N, 2) of every solid's vertices in
        front of it, as it truly sees them: where a corner extractor could latch on
        (:meth:`RayTruth.corner_pixels <cellsight.world.truth.RayTruth.corner_pixels>`)."""
        return self.truth.corner_pixels(self.intruders)

    def collisions(self) -> list[dict]:
        """Every collision so far (:mod:`cellsight.world.contacts`), as plain data."""
        return self.contacts.report()

    def render(self, cameras: Sequence[int] | None = None, *, on_demand: bool = False,
               picture: bool = False) -> list[np.ndarray | Shot | None]:
        """One (H, W) uint8 grayscale image per camera, in ``cell.cameras`` order, as the
        cameras grab it (``errors.images``); with ``cameras`` (indices), only theirs (None for
        the others: a camera triggered at another time). ``on_demand``: each image is a
        :class:`~cellsight.world.shots.Shot` of the state now, rendered when it is read (only
        the region read). ``picture``: for a picture only (a video frame of a dropped frame):
        its noise is the pattern of offset 0, not drawn from the world's random stream, so
        that drawing it changes nothing that the cameras take later."""
        self.scene.sync()
        if self._renderer is None:
            self._renderer = GrayRenderer(self.scene.model, self.cell.cameras, self._render_size)
        data = copy.copy(self.scene.data)
        fields = [[data]] if self._history is None else self._history.fields(self.time, data)
        shots = [Shot(self._renderer, self._imager, fields, c, self.time,
                      0 if self._imager is None or picture else self._imager.exposure())
                 if cameras is None or c in cameras else None
                 for c in range(len(self.cell.cameras))]
        return shots if on_demand else [None if s is None else s.whole() for s in shots]

    def close(self) -> None:
        """Free the renderer's OpenGL context."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

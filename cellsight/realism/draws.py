"""One run's draws from a realism profile: the world's cell, its imperfections, the scenario.

Every knob draws from its own random stream, seeded by the run's seed and the knob's name, so
that a knob draws the same values for a seed whichever other knobs are on (a fault alone and
in the whole profile are the same fault). Same seed and profile, same draws. Every draw is
recorded (:attr:`WorldDraws.record`, in the knobs' own units) for ``metrics.json``.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field

import numpy as np

from cellsight.model import Cell, Robot
from cellsight.rates import CONTROL_HZ, VISION_HZ
from cellsight.realism.perturb import (
    CameraError,
    PartError,
    RobotError,
    cell_as_built,
    size_scale,
    small_pose,
)
from cellsight.realism.profile import Distribution, Profile, load_profile
from cellsight.realism.unknown import forearm, table_box
from cellsight.world.faults import Kidnap, Knock
from cellsight.world.images import ImageEffects
from cellsight.world.imperfections import Imperfections
from cellsight.world.servo import ServoParams

KIDNAP_MARGIN_PX = 60.0
"""How far inside a camera's image (px) a kidnapped part's centre is put back."""


@dataclass(frozen=True)
class ScenarioShift:
    """What the seed changes in an experiment: the part's start ``shift`` (2,) m and ``yaw``
    (rad), the conveyor's ``speed_scale`` and ``turn`` (rad, its path turned about its first
    point), the crossing robot's waypoints' ``crossing_dt`` (s) and ``crossing_dq`` (rad per
    joint, None: no crossing robot); ``part_shifts``: every workpiece's start shift (2,) m, by
    name (a line's spacing)."""

    shift: np.ndarray
    yaw: float = 0.0
    speed_scale: float = 1.0
    turn: float = 0.0
    crossing_dt: float = 0.0
    crossing_dq: np.ndarray | None = None
    part_shifts: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True)
class WorldDraws:
    """The profile, the world's ``cell``, its ``errors``, the ``scenario`` shift, each camera's
    ``trigger_skew_s`` (s before the frame's time, >= 0) and the ``record`` of every draw."""

    profile: Profile
    cell: Cell
    errors: Imperfections
    scenario: ScenarioShift
    trigger_skew_s: np.ndarray
    record: dict

    def tcp_error(self, robot: Robot, q: np.ndarray) -> np.ndarray:
        """Where ``robot``'s TCP truly stands when its encoders read ``q`` (rad, m) less where
        its model (the cell file's ``robot``) puts it there: the world's as-built arm (base,
        links, tool) at the joints the encoders' offsets leave it at (m, base frame; the
        world's truth, which no sensor of the cell measures)."""
        built = self.cell.robot(robot.name)
        q = np.asarray(q, dtype=float)
        true_q = q - self.errors.encoder_offsets.get(robot.name, np.zeros_like(q))
        return built.tcp_pose(true_q)[:3, 3] - robot.tcp_pose(q)[:3, 3]


class _Knobs:
    """Draws knobs from per-knob streams (module docstring) and records them."""

    def __init__(self, seed: int) -> None:
        self.seed, self.record = int(seed), {}

    def draw(self, name: str, knob: Distribution, size: int | tuple = (), scale: float = 1.0,
             key: str | None = None) -> np.ndarray:
        """``knob`` drawn for ``name`` (a dotted knob path; ``key`` distinguishes its uses),
        recorded, and returned times ``scale`` (to SI units)."""
        label = name if key is None else f"{name}[{key}]"
        rng = np.random.default_rng([self.seed, zlib.crc32(label.encode())])
        value = np.asarray(knob.draw(rng, size), dtype=float)
        if not knob.zero:
            self.record[label] = np.round(value, 6).tolist()
        return value * scale

    def event(self, name: str, probability: float) -> bool:
        rng = np.random.default_rng([self.seed, zlib.crc32(name.encode())])
        happens = bool(rng.random() < probability)
        if probability > 0:
            self.record[name] = happens
        return happens


def draw_world(profile: Profile | str, cell: Cell, seed: int) -> WorldDraws:
    """The world of run ``seed`` on the nominal ``cell`` under ``profile`` (module doc)."""
    profile = load_profile(profile)
    k = _Knobs(seed)
    work = cell.workpieces[0].T_base_part[:3, 3] if cell.workpieces else None
    cameras = {c.name: _camera_error(k, profile, c, work) for c in cell.cameras}
    robots = {r.name: _robot_error(k, profile, r) for r in cell.robots}
    parts = {p.name: _part_error(k, profile, p) for p in cell.workpieces}
    support = profile.geometry.support_height_mm
    heights = {s.name: float(k.draw("geometry.support_height_mm", support, (), 1e-3, s.name))
               for s in cell.static}
    world_cell = cell_as_built(cell, cameras, robots, parts, heights)
    errors = _imperfections(k, profile, cell, world_cell)
    shift = _scenario(k, profile, cell, parts)
    latest = 1.0 / VISION_HZ - 1.0 / CONTROL_HZ
    skew = np.array([min(abs(float(k.draw("timing.trigger_skew_ms", profile.timing.trigger_skew_ms,
                                           (), 1e-3, c.name))), latest) for c in cell.cameras])
    return WorldDraws(profile, world_cell, errors, shift, skew, k.record)


def _camera_error(k: _Knobs, p: Profile, camera, work: np.ndarray | None) -> CameraError:
    """The camera's errors; its work point is the part's start (else 1 m ahead of it)."""
    c, name = p.cameras, camera.name
    if work is None:
        work = camera.T_base_cam[:3, 3] + camera.T_base_cam[:3, 2]
    return CameraError(k.draw("cameras.position_mm", c.position_mm, 3, 1e-3, name),
                       k.draw("cameras.rotation_deg", c.rotation_deg, 3, math.pi / 180, name),
                       np.asarray(work, dtype=float),
                       float(k.draw("cameras.focal_percent", c.focal_percent, (), 0.01, name)),
                       k.draw("cameras.principal_point_px", c.principal_point_px, 2, 1.0, name),
                       float(k.draw("cameras.distortion_k1", c.distortion_k1, (), 1.0, name)))


def _robot_error(k: _Knobs, p: Profile, robot) -> RobotError:
    r, n = p.robots, robot.n_joints
    base = small_pose(k.draw("robots.base_position_mm", r.base_position_mm, 3, 1e-3, robot.name),
                      k.draw("robots.base_rotation_deg", r.base_rotation_deg, 3, math.pi / 180,
                             robot.name))
    links = k.draw("robots.link_length_mm", r.link_length_mm, (n, 3), 1e-3, robot.name)
    grip = np.ones(3)
    if robot.tool is not None:
        change = k.draw("geometry.gripper_size_mm", p.geometry.gripper_size_mm, 3, 1e-3,
                        robot.name)
        grip = size_scale(robot.tool.jaws[0].solid, change)
    return RobotError(base, links, grip)


def _part_error(k: _Knobs, p: Profile, part) -> PartError:
    s = p.scenario
    return PartError(k.draw("geometry.part_size_mm", p.geometry.part_size_mm, 3, 1e-3, part.name),
                     k.draw("scenario.part_position_mm", s.part_position_mm, 2, 1e-3, part.name),
                     float(k.draw("scenario.part_yaw_deg", s.part_yaw_deg, (), math.pi / 180,
                                  part.name)))


def _encoder_offsets(k: _Knobs, p: Profile, cell: Cell) -> dict[str, np.ndarray]:
    out = {}
    for robot in cell.robots:
        deg = k.draw("robots.encoder_offset_deg", p.robots.encoder_offset_deg, robot.n_joints,
                     math.pi / 180, robot.name)
        mm = k.draw("robots.encoder_offset_mm", p.robots.encoder_offset_mm, robot.n_joints,
                    1e-3, robot.name)
        out[robot.name] = np.where(robot.chain.prismatic, mm, deg)
    return out


def _imperfections(k: _Knobs, p: Profile, cell: Cell, world_cell: Cell) -> Imperfections:
    g, r, s, im = p.geometry, p.robots, p.servo, p.images
    seat = small_pose(k.draw("geometry.grasp_seat_mm", g.grasp_seat_mm, 3, 1e-3),
                      k.draw("geometry.grasp_seat_deg", g.grasp_seat_deg, 3, math.pi / 180))
    slip = abs(float(k.draw("geometry.slip_mm_s", g.slip_mm_s, (), 1e-3)))
    images = None
    if im != type(im)():
        images = ImageEffects(im.read_noise_dn, im.shot_dn_per_e, im.gain_drift_percent / 100,
                              im.gain_period_s,
                              float(k.draw("images.gain_phase",
                                           Distribution(dist="uniform", high=2 * math.pi))),
                              im.defocus_px, im.vignetting, im.jpeg_quality,
                              im.exposure_ms / 1e3, im.interlaced)
    servo = ServoParams(s.bandwidth_hz, s.damping, math.radians(s.max_velocity_deg_s),
                        math.radians(s.max_acceleration_deg_s2), s.actuators == "mujoco",
                        s.velocity_feedforward)
    return Imperfections(
        encoder_offsets=_encoder_offsets(k, p, cell),
        quantum_rad=math.radians(r.encoder_resolution_deg), quantum_m=r.encoder_resolution_mm / 1e3,
        noise_rad=r.joint_noise_rad, noise_m=r.joint_noise_m, servo=servo,
        grasp_seat=seat, slip_m_s=slip, intruders=_intruders(k, p, world_cell), images=images,
        kidnap=_kidnap(k, p, cell), knock=_knock(k, p, cell))


def _knock(k: _Knobs, p: Profile, cell: Cell) -> Knock | None:
    """The knocked camera, if the seed draws one: which, when, and its move in its own frame
    (directions uniform on the sphere)."""
    f = p.faults
    if not cell.cameras or not k.event("faults.knock", f.knock_probability):
        return None
    cams = len(cell.cameras)
    which = int(k.draw("faults.knock_camera", Distribution(dist="uniform", high=cams)))
    which = f.knock_camera if f.knock_camera >= 0 else which
    axes = k.draw("faults.knock_axes", Distribution(dist="normal", sigma=1.0), (2, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    shift = float(k.draw("faults.knock_shift_mm", f.knock_shift_mm, (), 1e-3)) * axes[0]
    angle = float(k.draw("faults.knock_rotation_deg", f.knock_rotation_deg, (), math.pi / 180))
    return Knock(min(which, cams - 1), float(k.draw("faults.knock_time_s", f.knock_time_s)),
                 small_pose(shift, angle * axes[1]))


def _kidnap(k: _Knobs, p: Profile, cell: Cell) -> Kidnap | None:
    """The kidnapping of the experiment's workpiece, if the seed draws one. The part is put
    back where a camera sees it: the drawn direction turned by 30 deg steps until the part's
    start moved that way is inside some camera's view by ``KIDNAP_MARGIN_PX`` (the last step
    tried, 330 deg on, when none is)."""
    f = p.faults
    if not cell.workpieces or not k.event("faults.kidnap", f.kidnap_probability):
        return None
    part = cell.picked_workpieces()[0]
    distance = float(k.draw("faults.kidnap_distance_mm", f.kidnap_distance_mm, (), 1e-3))
    heading = float(k.draw("faults.kidnap_direction_deg", f.kidnap_direction_deg, (),
                           math.pi / 180))
    start = part.T_base_part[:3, 3] + part.T_base_part[:3, :3] @ part.feature_points.mean(0)
    for turn in np.radians(np.arange(0.0, 360.0, 30.0)):
        shift = distance * np.array([math.cos(heading + turn), math.sin(heading + turn)])
        there = start + [*shift, 0.0]
        if any(c.sees(there[None], KIDNAP_MARGIN_PX)[0] for c in cell.cameras):
            break
    return Kidnap(part.name, float(k.draw("faults.kidnap_time_s", f.kidnap_time_s)),
                  f.kidnap_blind_s, shift,
                  float(k.draw("faults.kidnap_turn_deg", f.kidnap_turn_deg, (), math.pi / 180)))


def _intruders(k: _Knobs, p: Profile, cell: Cell) -> tuple:
    u, out = p.unmodelled, []
    if not cell.workpieces or not cell.cameras:
        return ()
    part = cell.workpieces[0]
    cams = len(cell.cameras)
    if k.event("unmodelled.box", u.box_probability):
        size = k.draw("unmodelled.box_size_mm", u.box_size_mm, 3, 1e-3)
        which = int(k.draw("unmodelled.box_camera", Distribution(dist="uniform", high=cams)))
        tools = [r.tool for r in cell.robots if r.tool is not None and (
            cell.experiments.robot in (None, r.name))]
        out.append(table_box(part, cell.cameras[min(which, cams - 1)], size,
                             k.draw("unmodelled.box_place", Distribution(dist="uniform", high=1),
                                    2), cell.experiments.conveyor_points,
                             tools[0].reach_across() if tools else 0.0))
    if k.event("unmodelled.forearm", u.forearm_probability):
        which = int(k.draw("unmodelled.forearm_camera", Distribution(dist="uniform", high=cams)))
        which = u.forearm_camera if u.forearm_camera >= 0 else which
        t_in = float(k.draw("unmodelled.forearm_start_s", u.forearm_start_s))
        stay = float(k.draw("unmodelled.forearm_duration_s", u.forearm_duration_s))
        where = float(k.draw("unmodelled.forearm_place", Distribution(dist="uniform", high=1)))
        out.append(forearm(part, cell.cameras[min(which, cams - 1)], t_in, t_in + stay, where))
    return tuple(out)


def _scenario(k: _Knobs, p: Profile, cell: Cell, parts: dict[str, PartError]) -> ScenarioShift:
    s = p.scenario
    setup = cell.experiments
    picks = cell.picked_workpieces()
    moved = parts.get(picks[0].name) if picks else None
    dq = None
    if setup.crossing_robot is not None:
        n = cell.robot(setup.crossing_robot).n_joints
        dq = k.draw("scenario.crossing_joint_deg", s.crossing_joint_deg, n, math.pi / 180)
    return ScenarioShift(
        shift=moved.shift if moved is not None else np.zeros(2),
        yaw=moved.yaw if moved is not None else 0.0,
        speed_scale=1.0 + float(k.draw("scenario.conveyor_speed_percent",
                                       s.conveyor_speed_percent, (), 0.01)),
        turn=float(k.draw("scenario.conveyor_direction_deg", s.conveyor_direction_deg, (),
                          math.pi / 180)),
        crossing_dt=float(k.draw("scenario.crossing_time_s", s.crossing_time_s)),
        crossing_dq=dq,
        part_shifts={name: error.shift for name, error in parts.items()})

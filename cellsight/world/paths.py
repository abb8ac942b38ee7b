"""How things move in the world: the conveyor's path, a robot's own joint-space task, and the
workpieces' motion (:class:`PartMotion`: carried by the conveyor, resting, falling when
released, held by a gripper)."""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np

from cellsight.geometry.transforms import invert_pose, rotation_z, transform_points
from cellsight.model import Cell
from cellsight.model.landing import PRESSED_M
from cellsight.world.mjcf import GROUP_PART, GROUP_STATIC
from cellsight.world.scene import Scene

GRAVITY = 9.81  # m/s^2


@dataclass(frozen=True)
class ConveyorPath:
    """The conveyor's motion of a workpiece in the horizontal plane.

    The part frame's origin runs along the polyline ``points`` ((k, 2) x, y in the base frame,
    m) at ``speed`` (m/s), starting at ``t_start`` and stopping at ``t_stop`` (s) or at the end
    of the polyline, whichever comes first. Before ``t_start`` it waits at ``points[0]``. Height
    and orientation keep the workpiece's nominal values (the part translates, it does not turn).
    ``workpiece`` names the part it carries (default: the cell's first workpiece). A path with
    no points (:meth:`still`) leaves the part at its nominal pose.
    """

    points: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    speed: float = 0.0
    t_start: float = 0.0
    t_stop: float = math.inf
    workpiece: str | None = None
    _arc: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, dtype=float).reshape(-1, 2)
        if not np.all(np.isfinite(pts)):
            raise ValueError(f"ConveyorPath: points must be finite, got {pts.tolist()}")
        if not (np.isfinite(self.speed) and self.speed >= 0):
            raise ValueError(f"ConveyorPath: speed must be a finite number >= 0, got {self.speed}")
        if not (np.isfinite(self.t_start) and self.t_stop >= self.t_start):
            raise ValueError(
                f"ConveyorPath: need a finite t_start <= t_stop, got {self.t_start}, {self.t_stop}"
            )
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "_arc", np.concatenate([[0.0], np.cumsum(seg)]))

    @classmethod
    def still(cls, workpiece: str | None = None) -> ConveyorPath:
        """A conveyor that does not move the part."""
        return cls(workpiece=workpiece)

    @property
    def is_still(self) -> bool:
        return len(self.points) == 0

    @property
    def length(self) -> float:
        """Length of the polyline (m)."""
        return float(self._arc[-1]) if len(self.points) else 0.0

    def position(self, t: float) -> np.ndarray:
        """(x, y) of the part frame's origin at time ``t`` (s); only for a path with points."""
        if self.is_still:
            raise ValueError("ConveyorPath.still() has no position of its own")
        run = min(max(t, self.t_start), self.t_stop) - self.t_start
        s = min(self.speed * run, self.length)
        k = min(max(bisect.bisect_right(self._arc, s) - 1, 0), len(self.points) - 1)
        if k == len(self.points) - 1:
            return self.points[-1].copy()
        frac = (s - self._arc[k]) / max(self._arc[k + 1] - self._arc[k], 1e-15)
        return self.points[k] + frac * (self.points[k + 1] - self.points[k])


@dataclass(frozen=True)
class Waypoint:
    """A joint-space waypoint: reach the joint vector ``q`` at time ``t`` (s).

    The segment arriving at this waypoint is interpolated with a quintic smooth step (zero
    velocity and acceleration at both ends) when ``smooth``, linearly otherwise.
    """

    t: float
    q: np.ndarray
    smooth: bool = True

    def __post_init__(self) -> None:
        q = np.asarray(self.q, dtype=float).ravel()
        if not (np.isfinite(self.t) and np.all(np.isfinite(q))):
            raise ValueError(f"Waypoint: t and q must be finite, got t={self.t}, q={q.tolist()}")
        object.__setattr__(self, "q", q)


class JointTask:
    """A robot's own timed task: from ``q0`` at t = 0 through the waypoints, then holding the
    last one. Waypoint times must increase strictly and be > 0."""

    def __init__(self, q0: np.ndarray, waypoints: Sequence[Waypoint]) -> None:
        q0 = np.asarray(q0, dtype=float).ravel()
        self._t = np.array([0.0] + [w.t for w in waypoints])
        if np.any(np.diff(self._t) <= 0):
            raise ValueError(f"JointTask: waypoint times must increase from > 0, got {self._t[1:]}")
        for w in waypoints:
            if w.q.shape != q0.shape:
                raise ValueError(f"JointTask: waypoint q needs {q0.size} values, got {w.q.size}")
        self._q = np.vstack([q0] + [w.q for w in waypoints])
        self._smooth = [True] + [w.smooth for w in waypoints]

    def at(self, t: float) -> np.ndarray:
        """Joint set-point at time ``t`` (s)."""
        if t >= self._t[-1]:
            return self._q[-1].copy()
        k = int(np.searchsorted(self._t, max(t, 0.0), side="right"))  # segment k-1 -> k
        tau = (t - self._t[k - 1]) / (self._t[k] - self._t[k - 1])
        if self._smooth[k]:
            tau = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
        return self._q[k - 1] + tau * (self._q[k] - self._q[k - 1])


@dataclass
class _Part:
    """One workpiece's motion state: ``mode`` "conveyor", "resting" or "held"; ``pose``
    ``T_base_part``; ``offset`` (m): the jaws' pushes while on the conveyor; ``T_tcp_part``
    while held; ``fall_left`` (m) and ``fall_speed`` (m/s) while falling."""

    mode: str
    pose: np.ndarray
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    T_tcp_part: np.ndarray | None = None
    fall_left: float = 0.0
    fall_speed: float = 0.0
    turn: float = 0.0


class PartMotion:
    """The workpieces' poses, written into MuJoCo's mocap bodies as they move.

    A workpiece rests at its nominal pose, except those the ``conveyors`` carry (one path per
    carried part, until it is first grasped). One that is held follows its holder's TCP at the
    relative pose of the grasp, settled in the jaws by ``seat`` (a pose in the TCP frame
    applied when the grasp engages) and sliding along the tool's approach axis (+z) at
    ``slip`` (m/s). One that is released falls straight down (gravity, no rotation) onto
    whatever lies below it (static objects, other workpieces: ray casts) and rests there.
    """

    def __init__(self, scene: Scene, cell: Cell, conveyors: Sequence[ConveyorPath],
                 seat: np.ndarray | None = None, slip: float = 0.0) -> None:
        self.scene = scene
        self.cell = cell
        self.seat = np.eye(4) if seat is None else np.asarray(seat, dtype=float)
        self.slip = float(slip)
        self._dt = 0.0
        model = scene.model
        self._body = {p.name: model.body(p.name).id for p in cell.workpieces}
        self._mocap = {name: model.body_mocapid[b] for name, b in self._body.items()}
        self._parts = {p.name: _Part("resting", p.T_base_part.copy()) for p in cell.workpieces}
        self._nominal = {p.name: p.T_base_part for p in cell.workpieces}
        self._paths: dict[str, ConveyorPath] = {}  # carried part -> its path
        for path in conveyors:
            if cell.workpieces and not path.is_still:
                name = cell.workpiece(path.workpiece or cell.workpieces[0].name).name
                if name in self._paths:
                    raise ValueError(f"PartMotion: two conveyor paths carry workpiece {name!r}")
                self._paths[name] = path
                self._parts[name].mode = "conveyor"
                self._parts[name].pose = self._conveyor_pose(name, 0.0)
        for name in self._parts:
            self._write(name)

    def step(self, t: float, dt: float) -> None:
        """Move the conveyor's workpiece to its place at time ``t`` (s) and let the falling
        ones fall for ``dt`` (s)."""
        self._dt = dt
        for name, part in self._parts.items():
            if part.mode == "conveyor":
                part.pose = self._conveyor_pose(name, t)
                if part.turn:  # (rotation_z(0) is the identity, exactly)
                    part.pose[:3, :3] = rotation_z(part.turn) @ part.pose[:3, :3]
                part.pose[:3, 3] += part.offset
                self._write(name)
            elif part.fall_left > 0:
                part.fall_speed += GRAVITY * dt
                drop = min(part.fall_speed * dt, part.fall_left)
                part.fall_left -= drop
                part.pose[2, 3] -= drop
                self._write(name)

    def free(self) -> list[str]:
        """The workpieces no gripper holds."""
        return [name for name, part in self._parts.items() if part.mode != "held"]

    def pose(self, name: str) -> np.ndarray:
        """``T_base_part`` of a workpiece as last written (a copy)."""
        return self._parts[name].pose.copy()

    def push(self, name: str, shift: np.ndarray) -> None:
        """Shift a workpiece by ``shift`` (3,) m (a jaw pushing it); the conveyor keeps the
        shift."""
        part = self._parts[name]
        part.pose[:3, 3] += shift
        part.offset += shift
        self._write(name)

    def displace(self, name: str, shift: np.ndarray, turn: float) -> bool:
        """Move a workpiece no gripper holds by ``shift`` (2,) m in the horizontal plane and
        turn it by ``turn`` (rad) about the vertical through its origin (a kidnapping); the
        conveyor keeps both. False (nothing moved) when a gripper holds it."""
        part = self._parts[name]
        if part.mode == "held":
            return False
        part.pose[:2, 3] += np.asarray(shift, dtype=float)
        part.pose[:3, :3] = rotation_z(turn) @ part.pose[:3, :3]
        part.offset[:2] += np.asarray(shift, dtype=float)
        part.turn += float(turn)
        self._write(name)
        return True

    def hold(self, name: str, T_base_tcp: np.ndarray) -> None:
        """Weld a workpiece to a TCP at its current relative pose (the grasp engages)."""
        part = self._parts[name]
        part.mode = "held"
        part.T_tcp_part = self.seat @ invert_pose(T_base_tcp) @ part.pose
        part.fall_left = part.fall_speed = 0.0

    def carry(self, name: str, T_base_tcp: np.ndarray) -> None:
        """Move a held workpiece with its holder's TCP."""
        part = self._parts[name]
        part.T_tcp_part[2, 3] += self.slip * self._dt
        part.pose = T_base_tcp @ part.T_tcp_part
        self._write(name)

    def release(self, name: str) -> None:
        """Let go of a held workpiece: it starts falling (it rests where it is if nothing lies
        below it or it already touches a support; one pressed into a support rises onto its
        top, :data:`PRESSED_M`)."""
        part = self._parts[name]
        part.mode, part.T_tcp_part = "resting", None
        self.scene.sync()
        drop = self._drop_height(name)
        if drop < 0:
            part.pose[2, 3] -= drop
            self._write(name)
        part.fall_left, part.fall_speed = max(drop, 0.0), 0.0

    def place(self, name: str, T_base_part: np.ndarray) -> None:
        """Put a workpiece at a pose, resting there (off the conveyor, out of any gripper)."""
        part = self._parts[name]
        part.mode, part.T_tcp_part = "resting", None
        part.pose = np.array(T_base_part, dtype=float)
        part.fall_left = part.fall_speed = 0.0
        self._write(name)

    def true_poses(self) -> dict[str, np.ndarray]:
        """``T_base_part`` of every workpiece, read from MuJoCo."""
        return {name: self.scene.body_pose(b) for name, b in self._body.items()}

    def _drop_height(self, name: str) -> float:
        """How far the part can fall straight down before it rests on a static object or
        another workpiece (m; negative: it is pressed that far into one): the shortest
        downward ray cast from :data:`PRESSED_M` above its vertices, less that lift; 0 when
        nothing lies below it."""
        groups = np.zeros(6, dtype=np.uint8)
        groups[[GROUP_STATIC, GROUP_PART]] = 1
        down = np.array([0.0, 0.0, -1.0])
        drops = []
        solid = self.cell.workpiece(name).solid
        for v in transform_points(self._parts[name].pose, solid.vertices):
            d = mujoco.mj_ray(self.scene.model, self.scene.data, v + [0.0, 0.0, PRESSED_M],
                              down, groups, True, self._body[name], None)
            if d >= 0:
                drops.append(d - PRESSED_M)
        return min(drops) if drops else 0.0

    def _conveyor_pose(self, name: str, t: float) -> np.ndarray:
        T = self._nominal[name].copy()
        T[:2, 3] = self._paths[name].position(t)
        return T

    def _write(self, name: str) -> None:
        self.scene.set_mocap(self._mocap[name], self._parts[name].pose)


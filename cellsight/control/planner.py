"""Dynamic trajectory planner (vision rate, 26 Hz): the TCP target from the task and the part.

The planner holds one *segment* at a time: from the target it had when the segment started to a
*goal*, which is either a pose moving at a constant linear velocity (:class:`PoseGoal`, HOME,
FINAL, a hold) or the grasp pose of the tracked part raised by a height (:class:`PartGoal`,
which moves with the part estimate). The start is stored as an offset from the goal at the
start time, and the target is the goal plus that offset shrunk by a minimum-jerk profile::

    p(t) = g(t) + (1 - s) (p0 - g(t0))        R(t) = exp((1 - s) r0) R_g(t)
    s = 10 tau^3 - 15 tau^4 + 6 tau^5,  tau = (t - t0) / D,  r0 = rotvec(R0 R_g(t0)^T)

so the target follows a moving part from the first instant, starts and ends the relative motion
with zero velocity and acceleration, and equals the goal once ``tau >= 1``. The target comes
with its twist and acceleration (goals move at constant velocity and do not turn, so these are
exact), which the interpolating filter uses as feed-forward. The segment duration
``D`` is the requested one, lengthened when needed so that the relative motion stays under the
speed limits (peak speed of the profile: 1.875 distance / D).

The part's pose and velocity come from the estimator when it provides a velocity, else from a
least-squares fit over a sliding window of estimates (:class:`PartMotion`); a part estimate that
stops coming is extrapolated for at most ``max_extrapolation`` seconds, then held. Orientation
rates of the part are not estimated (the target's angular velocity follows the segment only).

Frames and units: poses ``T_base_tcp`` / ``T_base_part`` (4x4, base frame), metres, radians,
seconds; twists (linear m/s, angular rad/s) in the base frame; heights along base +z.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from cellsight.control.clik import rotation_error
from cellsight.geometry.transforms import make_pose
from cellsight.model.grasp import HALF_TURN_Z, nearer_grasp

MIN_JERK_PEAK = 1.875  # peak of ds/dtau for the minimum-jerk profile
REGRASP_MARGIN = np.radians(40.0)
"""How much nearer (rad) the twin grasp must be to the TCP's orientation than the chosen one
before a segment towards the part switches to it (:meth:`TrajectoryPlanner.keep_grasp_near`)."""


def min_jerk(tau: float) -> tuple[float, float, float]:
    """Minimum-jerk profile ``s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5`` and its first and second
    derivatives with respect to ``tau``, with ``tau`` clamped to [0, 1]."""
    tau = min(max(tau, 0.0), 1.0)
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    ds = 30.0 * tau**2 * (1.0 - tau) ** 2
    dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau)
    return s, ds, dds


@dataclass(frozen=True)
class PoseGoal:
    """A goal pose ``T`` (base frame) at time ``t_ref`` (s), moving at the constant linear
    ``velocity`` (m/s, base frame; zero for a fixed pose)."""

    T: np.ndarray
    t_ref: float = 0.0
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass(frozen=True)
class PartGoal:
    """The grasp pose of the tracked part raised by ``height`` (m) along base +z."""

    height: float = 0.0


class PartMotion:
    """The part's pose and linear velocity (m/s, base frame) as the planner uses them.

    With a velocity from the estimator (an EKF's), the estimate is used as it is. Without one,
    the estimates of the last ``window`` seconds are smoothed: a least-squares line through the
    positions gives the velocity and the position at the latest time, and the orientation is
    their mean rotation (parts on the conveyor translate; a turning part would be followed with
    a lag of about half the window). ``window = 0`` uses the raw latest estimate, velocity zero.
    """

    def __init__(self, window: float = 0.5, max_extrapolation: float = 0.5) -> None:
        self.window = float(window)
        self.max_extrapolation = float(max_extrapolation)
        self._samples: deque[tuple[float, np.ndarray]] = deque()
        self.T_base_part: np.ndarray | None = None
        self.t = 0.0
        self.velocity = np.zeros(3)

    @property
    def known(self) -> bool:
        """Whether the part has been localised at least once."""
        return self.T_base_part is not None

    def update(self, t: float, T_base_part: np.ndarray | None,
               velocity: np.ndarray | None = None) -> None:
        """New estimate at time ``t`` (None: no estimate this frame); ``velocity`` optional."""
        if T_base_part is None:
            return
        self.t = float(t)
        T = np.array(T_base_part, dtype=float)
        self._samples.append((self.t, T))
        while self._samples[0][0] < self.t - self.window:
            self._samples.popleft()
        if velocity is not None or len(self._samples) < 2:
            self.T_base_part = T
            self.velocity = np.zeros(3) if velocity is None else np.array(velocity, dtype=float)
            return
        times = np.array([s[0] for s in self._samples])
        poses = np.array([s[1] for s in self._samples])
        dt = times - times.mean()
        mean = poses[:, :3, 3].mean(axis=0)
        self.velocity = dt @ (poses[:, :3, 3] - mean) / (dt @ dt)
        self.T_base_part = make_pose(Rotation.from_matrix(poses[:, :3, :3]).mean().as_matrix(),
                                     mean + self.velocity * dt[-1])

    def predict(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Part pose extrapolated to ``t`` and its velocity (zero once the estimate is older than
        ``max_extrapolation``)."""
        if self.T_base_part is None:
            raise RuntimeError("PartMotion.predict: the part has not been localised yet")
        age = t - self.t
        T = self.T_base_part.copy()
        T[:3, 3] += self.velocity * min(max(age, 0.0), self.max_extrapolation)
        moving = age <= self.max_extrapolation
        return T, (self.velocity.copy() if moving else np.zeros(3))


@dataclass
class _Segment:
    t0: float
    duration: float
    goal: PoseGoal | PartGoal
    offset_position: np.ndarray
    offset_rotation: np.ndarray


class TrajectoryPlanner:
    """The dynamic trajectory planner of Fig. 7 (run at the vision rate).

    ``T_part_tcp``: grasp pose of the TCP in the part frame
    (:func:`~cellsight.model.grasp.grasp_pose`); ``max_speed`` (m/s) and ``max_angular_speed``
    (rad/s) bound the relative motion of a segment; ``part_window`` and ``max_extrapolation``
    (s) configure :class:`PartMotion`.
    """

    def __init__(self, T_part_tcp: np.ndarray, *, max_speed: float = 0.25,
                 max_angular_speed: float = 0.8, part_window: float = 0.5,
                 max_extrapolation: float = 0.5) -> None:
        self.T_part_tcp = np.array(T_part_tcp, dtype=float)
        self.max_speed = float(max_speed)
        self.max_angular_speed = float(max_angular_speed)
        self.part = PartMotion(part_window, max_extrapolation)
        self._T_part_tcp_chosen = self.T_part_tcp
        self._segment: _Segment | None = None

    @property
    def chosen_grasp(self) -> np.ndarray:
        """``T_part_tcp`` of the grasp the last segment towards the part chose (of the two
        symmetric ones; ``T_part_tcp`` before any): how a gripper that closed holds the part."""
        return self._T_part_tcp_chosen.copy()

    def grasp_pose(self, T_base_part: np.ndarray, T_near: np.ndarray) -> np.ndarray:
        """Grasp pose of the TCP (base frame) for a part pose: of the two symmetric grasps, the
        one whose orientation is nearer to ``T_near``."""
        return T_base_part @ self._nearer_grasp(T_base_part, T_near)

    def _nearer_grasp(self, T_base_part: np.ndarray, T_near: np.ndarray) -> np.ndarray:
        return nearer_grasp(self.T_part_tcp, T_base_part, T_near)

    def keep_grasp_near(self, t: float, T_tcp: np.ndarray) -> bool:
        """In a segment towards the part, switch to the twin grasp when, at the part's latest
        estimate, it is nearer to the TCP's pose ``T_tcp`` (base frame) than the chosen one by
        more than :data:`REGRASP_MARGIN` (an estimate that has turned since the choice: a part
        acquired with a wrong yaw, or as its turned twin, then corrected; the target, which
        follows the estimate, would turn the wrist half a turn); the segment starts again from
        ``T_tcp`` over the time it had left. Returns whether it switched."""
        seg = self._segment
        if seg is None or not isinstance(seg.goal, PartGoal) or not self.part.known:
            return False
        T_now = np.asarray(T_tcp, dtype=float)
        T_part = self.part.predict(t)[0]
        chosen = self._T_part_tcp_chosen
        angles = [float(np.linalg.norm(rotation_error(T_part[:3, :3] @ g[:3, :3], T_now[:3, :3])))
                  for g in (chosen, chosen @ HALF_TURN_Z)]
        if angles[0] - angles[1] <= REGRASP_MARGIN:
            return False
        self.move_to(t, seg.goal, max(seg.t0 + seg.duration - t, 0.0), start=T_now)
        return True

    def goal_at(self, goal: PoseGoal | PartGoal, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Pose of a goal at time ``t`` and its linear velocity."""
        if isinstance(goal, PoseGoal):
            T = goal.T.copy()
            T[:3, 3] += goal.velocity * (t - goal.t_ref)
            return T, goal.velocity
        T_part, velocity = self.part.predict(t)
        T = T_part @ self._T_part_tcp_chosen
        T[2, 3] += goal.height
        return T, velocity

    def reset(self, t: float, T_base_tcp: np.ndarray) -> None:
        """Hold the pose ``T_base_tcp`` from time ``t``."""
        self.move_to(t, PoseGoal(np.array(T_base_tcp, dtype=float), t), 0.0, start=T_base_tcp)

    def move_to(self, t: float, goal: PoseGoal | PartGoal, duration: float,
                start: np.ndarray | None = None) -> float:
        """Start a segment at ``t`` towards ``goal`` lasting at least ``duration`` (s), from
        ``start`` (default: the current target). Returns the duration used."""
        T0 = self.target(t)[0] if start is None else np.asarray(start, dtype=float)
        if isinstance(goal, PartGoal):  # the grasp symmetry is chosen once per segment
            self._T_part_tcp_chosen = self._nearer_grasp(self.part.predict(t)[0], T0)
        G, _ = self.goal_at(goal, t)
        dp = T0[:3, 3] - G[:3, 3]
        dr = rotation_error(T0[:3, :3], G[:3, :3])
        duration = max(float(duration),
                       MIN_JERK_PEAK * float(np.linalg.norm(dp)) / self.max_speed,
                       MIN_JERK_PEAK * float(np.linalg.norm(dr)) / self.max_angular_speed)
        self._segment = _Segment(float(t), duration, goal, dp, dr)
        return duration

    @property
    def goal(self) -> PoseGoal | PartGoal:
        """The goal of the current segment."""
        return self._require().goal

    def segment_end(self) -> float:
        """Time (s) at which the current segment reaches its goal."""
        seg = self._require()
        return seg.t0 + seg.duration

    def target(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """TCP target pose at ``t``, its twist (linear m/s, angular rad/s) and its acceleration
        (m/s^2, rad/s^2), all in the base frame."""
        seg = self._require()
        G, velocity = self.goal_at(seg.goal, t)
        if seg.duration > 0.0:
            s, ds, dds = min_jerk((t - seg.t0) / seg.duration)
            rate, rate2 = ds / seg.duration, dds / seg.duration**2
        else:
            s, rate, rate2 = 1.0, 0.0, 0.0
        T = G.copy()
        T[:3, 3] += (1.0 - s) * seg.offset_position
        if s < 1.0:
            turn = Rotation.from_rotvec((1.0 - s) * seg.offset_rotation).as_matrix()
            T[:3, :3] = turn @ G[:3, :3]
        twist = np.concatenate([velocity - rate * seg.offset_position,
                                -rate * seg.offset_rotation])
        accel = -rate2 * np.concatenate([seg.offset_position, seg.offset_rotation])
        return T, twist, accel

    def _require(self) -> _Segment:
        if self._segment is None:
            raise RuntimeError("TrajectoryPlanner: call reset() with the current TCP pose first")
        return self._segment

"""Closed-loop inverse kinematics (CLIK) at the motion-control rate (500 Hz).

One step maps the current joint set-point ``q`` and a desired tool-centre-point pose
``T_base_tcp`` (with its twist) to the next joint set-point::

    e   = [p_d - p ; vee(R_e - R_e^T) / 2],  R_e = R_d R^T   6D pose error, base frame
    u   = v_d + K e                                         feed-forward twist + feedback
    dq  = J^T (J J^T + lambda^2 I)^-1 (u - J dq0) + dq0     damped least squares (DLS)
    q'  = clip(q + dt * scale(dq), qlim)

The orientation error ``vee(R_e - R_e^T) / 2 = sin(angle) * axis`` is the usual CLIK error
(Siciliano et al., *Robotics*, Sec. 3.7.3): exact in direction, its magnitude within 0.2 % of the
angle below 6 degrees; fed by the interpolating filter, the error stays far below that.
``J`` is the geometric Jacobian of the TCP in the cell base frame (rows: linear velocity m/s,
angular velocity rad/s). ``dq0`` is a secondary joint velocity projected (approximately, through
the damped inverse) onto the null space of ``J``: the R7AX with its track has one redundant
degree of freedom. With ``redundancy="joint_limits"`` ``dq0 = -k0 grad H`` with
``H(q) = 1/2 sum d_i(q)^2``, ``d_i`` the depth of joint ``i`` inside a band of width
``limit_margin * range_i`` next to either limit (zero elsewhere): joints are pushed back out of
the band without moving the tool, and the secondary motion starts and stops smoothly (``grad H``
is continuous). ``scale`` divides ``dq`` by ``max_i |dq_i| / vmax_i`` when that exceeds 1, which
keeps the direction of motion. Joint units: m for prismatic joints, rad for revolute ones.

The step is stateless: the caller keeps the joint set-point and feeds it back (classic CLIK
integrates its own set-point, not the measured joints). One forward-kinematics evaluation per
step; the Jacobian is built from the same frames.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numba import njit

from cellsight.control._rotations import rotvec_of_matrix
from cellsight.model.robot import Robot
from cellsight.rates import CONTROL_HZ

Redundancy = Literal["joint_limits", "none"]

PRISMATIC_SPEED = 0.5  # m/s, default limit of a prismatic joint (the R7AX track)
REVOLUTE_SPEED = 2.0  # rad/s, default limit of a revolute joint


def default_joint_velocity_limits(robot: Robot) -> np.ndarray:
    """Default joint speed limits: 0.5 m/s per prismatic joint, 2 rad/s per revolute joint
    (conservative for a SMART-3 S-class arm), or the robot's rated speed where it is lower (a
    URDF's ``limit velocity``: a KUKA LBR iiwa's first joints turn at 85 deg/s)."""
    limits = np.where(robot.chain.prismatic, PRISMATIC_SPEED, REVOLUTE_SPEED)
    return limits if robot.max_velocity is None else np.minimum(limits, robot.max_velocity)


def tcp_pose_and_jacobian(robot: Robot, q: np.ndarray,
                          T_flange_tcp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pose (4x4, cell base frame) of the point ``T_flange_tcp`` fixed to the robot's last
    frame (its TCP) and its geometric Jacobian (6, n, base frame), from one forward-kinematics
    evaluation."""
    frames = robot.chain.fkine(q)
    T_robot_tcp = frames[-1] @ T_flange_tcp
    J = robot.chain.jacobian_at(frames, T_robot_tcp[:3, 3])
    R = robot.T_base_robot[:3, :3]
    J[:3] = R @ J[:3]
    J[3:] = R @ J[3:]
    return robot.T_base_robot @ T_robot_tcp, J


def rotation_error(R_desired: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Rotation vector (rad, base frame) of ``R_desired @ R.T``: the turn that takes ``R`` to
    ``R_desired``."""
    return rotvec_of_matrix(np.ascontiguousarray(R_desired @ R.T, dtype=float))


class Clik:
    """Damped-least-squares CLIK on the 6D TCP pose error of one robot.

    Parameters: ``gain`` K (1/s, scalar or 6 values: 3 for position, 3 for orientation),
    ``damping`` lambda (DLS damping, in units of the Jacobian's entries), ``joint_velocity_limits``
    (n values, m/s or rad/s; default :func:`default_joint_velocity_limits`), ``redundancy``
    (``"joint_limits"`` or ``"none"``), ``null_gain`` k0 (1/s) and ``limit_margin`` (fraction
    of each joint's range) of the joint-limit term.
    """

    def __init__(
        self,
        robot: Robot,
        *,
        gain: float | np.ndarray = 50.0,
        damping: float = 0.02,
        joint_velocity_limits: np.ndarray | None = None,
        redundancy: Redundancy = "joint_limits",
        null_gain: float = 5.0,
        limit_margin: float = 0.1,
    ) -> None:
        if robot.tool is None:
            raise ValueError(f"Clik: robot {robot.name} has no tool, so no TCP to control")
        if redundancy not in ("joint_limits", "none"):
            raise ValueError(
                f"Clik: redundancy must be 'joint_limits' or 'none', got {redundancy!r}")
        chain = robot.chain
        self.robot = robot
        self.gain = np.broadcast_to(np.asarray(gain, dtype=float), (6,)).copy()
        self.damping = float(damping)
        vmax = (default_joint_velocity_limits(robot) if joint_velocity_limits is None
                else np.asarray(joint_velocity_limits, dtype=float))
        if vmax.shape != (chain.n,) or not np.all(vmax > 0):
            raise ValueError(f"Clik: need {chain.n} positive joint velocity limits, got {vmax}")
        self.joint_velocity_limits = vmax
        self.redundancy: Redundancy = redundancy
        self.null_gain = float(null_gain)
        self.qlim = chain.qlim.copy()
        self._band = limit_margin * (self.qlim[:, 1] - self.qlim[:, 0])
        self._T_flange_tcp = robot.tool.T_flange_tool @ robot.tool.T_tool_tcp
        self._damp2 = self.damping**2 * np.eye(6)

    def tcp_pose_and_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """TCP pose in the cell base frame (4x4) and its geometric Jacobian (6, n) in the base
        frame (:func:`tcp_pose_and_jacobian`)."""
        return tcp_pose_and_jacobian(self.robot, q, self._T_flange_tcp)

    def secondary_velocity(self, q: np.ndarray) -> np.ndarray:
        """The joint velocity ``dq0`` to project onto the null space (zero unless near a limit)."""
        if self.redundancy == "none":
            return np.zeros_like(q)
        below = np.maximum(0.0, self.qlim[:, 0] + self._band - q)
        above = np.maximum(0.0, q - (self.qlim[:, 1] - self._band))
        return self.null_gain * (below - above)

    def step(
        self,
        q: np.ndarray,
        T_target: np.ndarray,
        v_target: np.ndarray | None = None,
        dt: float = 1 / CONTROL_HZ,
    ) -> np.ndarray:
        """Next joint set-point for the TCP pose ``T_target`` (base frame) moving with the twist
        ``v_target`` = (linear m/s, angular rad/s) in the base frame; ``dt`` in seconds."""
        q = np.asarray(q, dtype=float)
        T, J = self.tcp_pose_and_jacobian(q)
        v = np.zeros(6) if v_target is None else np.asarray(v_target, dtype=float)
        return _dls_step(T, J, np.asarray(T_target, dtype=float), v, self.gain, self._damp2,
                         self.secondary_velocity(q), self.joint_velocity_limits, self.qlim, q,
                         float(dt))


@njit(cache=True)
def _dls_step(T, J, T_target, v_target, gain, damp2, dq0, vmax, qlim, q, dt):
    """The module docstring's step from the TCP pose ``T`` and Jacobian ``J`` at ``q``."""
    R_e = np.ascontiguousarray(T_target[:3, :3]) @ np.ascontiguousarray(T[:3, :3].T)
    error = np.empty(6)
    error[:3] = T_target[:3, 3] - T[:3, 3]
    error[3] = 0.5 * (R_e[2, 1] - R_e[1, 2])
    error[4] = 0.5 * (R_e[0, 2] - R_e[2, 0])
    error[5] = 0.5 * (R_e[1, 0] - R_e[0, 1])
    u = gain * error + v_target
    dq = J.T @ np.linalg.solve(J @ J.T + damp2, u - J @ dq0) + dq0
    excess = np.max(np.abs(dq) / vmax)
    if excess > 1.0:
        dq /= excess
    return np.minimum(np.maximum(q + dt * dq, qlim[:, 0]), qlim[:, 1])

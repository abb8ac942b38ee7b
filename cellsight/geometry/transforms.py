"""Rigid transforms as 4x4 homogeneous matrices.

Convention (docs/design.md, "Conventions"): ``T_a_b`` maps coordinates in frame ``b`` to frame
``a``; it is the pose of frame ``b`` expressed in frame ``a``. Composition reads left to right:
``T_base_link = T_base_robot @ T_robot_link``. Units are metres and radians.

Roll-pitch-yaw follows the paper: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (fixed-axis XYZ,
SciPy's ``"xyz"`` extrinsic sequence). Conversions go through :mod:`scipy.spatial.transform`,
but for the two between a pose and its roll-pitch-yaw, written out: the tracker, its PnP
baseline and the frame log call them thousands of times a run, where SciPy's call costs 25-70
us (their tests hold them to SciPy's answers).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from cellsight.errors import GeometryError

RPY_SEQUENCE = "xyz"  # extrinsic x, then y, then z: R = Rz(yaw) Ry(pitch) Rx(roll)


def make_pose(rotation: np.ndarray | None = None, translation=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Build a 4x4 pose from a 3x3 rotation (identity if None) and a translation in metres."""
    T = np.eye(4)
    if rotation is not None:
        T[:3, :3] = rotation
    T[:3, 3] = translation
    return T


GIMBAL_LOCK = 1e-6
"""Below this ``cos(pitch)`` :func:`xyz_rpy_from_pose` leaves roll and yaw, which only their
difference or sum then sets, to SciPy's ``as_euler`` (yaw zero)."""


def pose_from_xyz_rpy(xyz, rpy) -> np.ndarray:
    """Pose from a position (m) and roll-pitch-yaw angles (rad), ``R = Rz(y) Ry(p) Rx(r)``
    (written out: module docstring)."""
    roll, pitch, yaw = (float(a) for a in np.asarray(rpy, dtype=float).reshape(3))
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    T = np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr, 0.0],
                  [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr, 0.0],
                  [-sp, cp * sr, cp * cr, 0.0],
                  [0.0, 0.0, 0.0, 1.0]])
    T[:3, 3] = xyz
    return T


def xyz_rpy_from_pose(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and roll-pitch-yaw (rad: roll and yaw in [-pi, pi], pitch in [-pi/2, pi/2])
    of a pose; inverse of :func:`pose_from_xyz_rpy` (written out, module docstring; at a pitch
    within :data:`GIMBAL_LOCK` of +-pi/2, SciPy's ``as_euler``)."""
    (r00, _, _), (r10, _, _), (r20, r21, r22) = T[:3, :3].tolist()
    cos_pitch = math.hypot(r00, r10)
    if cos_pitch < GIMBAL_LOCK:
        return T[:3, 3].copy(), Rotation.from_matrix(T[:3, :3]).as_euler(RPY_SEQUENCE)
    rpy = [math.atan2(r21, r22), math.atan2(-r20, cos_pitch), math.atan2(r10, r00)]
    return T[:3, 3].copy(), np.array(rpy)


def rotation_z(angle: float) -> np.ndarray:
    """Rotation matrix (3x3) by ``angle`` (rad) about the z axis (written out: the world moves
    the conveyor's part by it at every 500 Hz step, where SciPy's call costs ~20 us)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_angle(R: np.ndarray) -> float:
    """The angle (rad, in [0, pi]) of a rotation matrix (3x3): its axis-angle magnitude, as
    ``atan2(sin, cos)`` from its skew part and its trace (written out: accurate over the whole
    range, and the tracker's holder check takes it every frame, where SciPy's call costs
    ~50 us)."""
    R = np.asarray(R, dtype=float)
    sine = 0.5 * math.sqrt((R[2, 1] - R[1, 2]) ** 2 + (R[0, 2] - R[2, 0]) ** 2
                           + (R[1, 0] - R[0, 1]) ** 2)
    cosine = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    return math.atan2(sine, cosine)


def pose_errors(estimate: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and orientation (rad, the angle of ``R_est^T R_true``) errors between
    (n, 6) rows of ``[x, y, z, roll, pitch, yaw]``; NaN where an estimate row has a NaN."""
    estimate, truth = np.asarray(estimate, dtype=float), np.asarray(truth, dtype=float)
    pos = np.linalg.norm(estimate[:, :3] - truth[:, :3], axis=1)
    ok = np.all(np.isfinite(estimate), axis=1) & np.all(np.isfinite(truth), axis=1)
    ang = np.full(len(estimate), np.nan)
    if ok.any():
        R_est = Rotation.from_euler(RPY_SEQUENCE, estimate[ok, 3:])
        R_true = Rotation.from_euler(RPY_SEQUENCE, truth[ok, 3:])
        ang[ok] = (R_est.inv() * R_true).magnitude()
    return pos, ang


RIGID_TOL = 1e-6  # tolerance of R^T R = I and of the last row [0 0 0 1]
_EYE3, _LAST_ROW = np.eye(3), np.array([0.0, 0.0, 0.0, 1.0])
_RIGID_BOUND_R = RIGID_TOL + 1e-5 * _EYE3
_RIGID_BOUND_ROW = RIGID_TOL + 1e-5 * _LAST_ROW


def is_rigid(T: np.ndarray) -> bool:
    """Whether the finite 4x4 matrix ``T`` is a rigid transform: a rotation (``R^T R = I``
    within :data:`RIGID_TOL`, det +1: no scale, no mirror) and a last row ``0 0 0 1``."""
    R = T[:3, :3]
    # np.allclose's test (|a - b| <= atol + rtol |b|, rtol 1e-5) written out: allclose itself
    # costs tens of microseconds, and a snapshot checks every part's pose each frame
    return bool((np.abs(R.T @ R - _EYE3) <= _RIGID_BOUND_R).all()
                and (np.abs(T[3] - _LAST_ROW) <= _RIGID_BOUND_ROW).all()
                and np.linalg.det(R) > 0)


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform, using the transpose of its rotation."""
    R = T[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply the pose ``T_a_b`` to points given in frame ``b``; returns them in frame ``a``."""
    points = np.asarray(points, dtype=float)
    return points @ T[:3, :3].T + T[:3, 3]


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera pose ``T_base_cam`` (OpenCV axes: x right, y down, z forward) at ``eye`` looking
    at ``target``; ``up`` is the base-frame direction that appears upward in the image."""
    eye, target, up = (np.asarray(v, dtype=float) for v in (eye, target, up))
    z = target - eye
    if not np.linalg.norm(z) > 1e-9:  # also NaN
        raise GeometryError(f"look_at: eye {eye.tolist()} and target {target.tolist()} coincide "
                            f"(no viewing direction)")
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if not np.linalg.norm(x) >= 1e-9:
        raise GeometryError(f"look_at: viewing direction {np.round(z, 6).tolist()} is parallel "
                            f"to up {up.tolist()}")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_pose(np.column_stack([x, y, z]), eye)

"""The calibration's first estimates (:mod:`.solve` refines them): each camera's intrinsics
from OpenCV's calibrateCamera, the board in each camera by solvePnP, and each camera and robot
tied together by OpenCV's robot-world hand-eye solver."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from cellsight.calibration.solution import Problem, Start
from cellsight.calibration.solve_checks import (
    MIN_POSES,
    MIN_SPREAD_DEG,
    rotation_spread_deg,
)
from cellsight.camera import Camera
from cellsight.errors import CellsightError
from cellsight.geometry.transforms import invert_pose, make_pose


def hand_eye(T_cam_board: np.ndarray, T_base_flange: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """Eye-to-hand calibration of one fixed camera and one robot from P poses: the board's
    poses in the camera ``T_cam_board`` (P, 4, 4) and the flange's in the robot's base
    ``T_base_flange`` (P, 4, 4); returns ``(T_base_cam, T_flange_board)``.

    OpenCV's ``calibrateRobotWorldHandEye`` solves ``A_i X = Z B_i`` for ``A`` "world2cam"
    (cTw), ``B`` "base2gripper" (gTb), ``X`` "base2world" (wTb) and ``Z`` "gripper2cam" (cTg).
    Here ``T_cam_board T_board_flange = T_cam_base T_base_flange``: its world is the board,
    its gripper the robot's base, its base the flange: ``A = T_cam_board``, ``B =
    T_base_flange``, ``X = T_board_flange`` and ``Z = T_cam_base``."""
    A, B = np.asarray(T_cam_board, dtype=float), np.asarray(T_base_flange, dtype=float)
    R_x, t_x, R_z, t_z = cv2.calibrateRobotWorldHandEye(
        list(A[:, :3, :3]), list(A[:, :3, 3]), list(B[:, :3, :3]), list(B[:, :3, 3]))
    T_board_flange, T_cam_base = make_pose(R_x, t_x.ravel()), make_pose(R_z, t_z.ravel())
    return invert_pose(T_cam_base), invert_pose(T_board_flange)


def _mean_pose(poses: Sequence[np.ndarray]) -> np.ndarray:
    """The mean of poses: chordal mean rotation, mean position."""
    stack = np.asarray(poses, dtype=float)
    R = Rotation.from_matrix(stack[:, :3, :3]).mean().as_matrix()
    return make_pose(R, stack[:, :3, 3].mean(axis=0))


def _intrinsics(camera: Camera, obj: list[np.ndarray], img: list[np.ndarray], free: bool
                ) -> tuple[np.ndarray, np.ndarray]:
    """K and the 5 distortion coefficients: OpenCV's over the camera's views (the start's K as
    the guess, k3 fixed) when ``free``, else the start's."""
    if not free:
        return camera.K, camera.dist5
    flags = cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    _, K, dist, _, _ = cv2.calibrateCamera(
        [o.astype(np.float32) for o in obj], [i.astype(np.float32) for i in img],
        (camera.width, camera.height), camera.K.copy(), camera.dist5.copy(), flags=flags)
    return K, dist.ravel()[:5]


def _board_in_camera(obj: np.ndarray, img: np.ndarray, K: np.ndarray, dist: np.ndarray
                     ) -> np.ndarray:
    """``T_cam_board`` of one view by ``cv2.solvePnP``."""
    ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist)
    if not ok:
        raise CellsightError("calibration: solvePnP found no board pose in a view")
    return make_pose(Rotation.from_rotvec(rvec.ravel()).as_matrix(), tvec.ravel())


def _pairs(problem: Problem, board: dict[int, np.ndarray], c: int
           ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per robot, camera ``c``'s hand-eye ``(T_robot_cam, T_flange_board)`` where it sees
    ``MIN_POSES`` poses of the robot whose flange turns about more than one axis."""
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for robot in problem.robots:
        index = {v.pose: i for i, v in enumerate(problem.views)
                 if v.camera == c and v.robot == robot}
        flange = np.array([problem.flange[robot, p] for p in index])
        if len(index) >= MIN_POSES and rotation_spread_deg(flange) >= MIN_SPREAD_DEG:
            out[robot] = hand_eye(np.array([board[i] for i in index.values()]), flange)
    return out


def _tie(pairs: dict[int, dict[str, tuple[np.ndarray, np.ndarray]]], reference: str
        ) -> tuple[dict[int, np.ndarray], dict[str, np.ndarray]]:
    """Cameras' poses in ref and robots' bases from the per-camera, per-robot hand-eye
    ``pairs[c][robot] = (T_robot_cam, ...)``: a camera from the robots already placed that it
    sees, a robot from the cameras already placed that see it (means), until nothing more is
    placed. Returns ``(T_ref_cam by camera, T_ref_robot by robot)``; either may lack some."""
    cams: dict[int, np.ndarray] = {}
    bases = {reference: np.eye(4)}
    robots = {robot for found in pairs.values() for robot in found}
    while True:
        new_cams = {c: _mean_pose([bases[r] @ T for r, (T, _) in found.items() if r in bases])
                    for c, found in pairs.items()
                    if c not in cams and any(r in bases for r in found)}
        cams.update(new_cams)
        new_bases = {r: _mean_pose([cams[c] @ invert_pose(pairs[c][r][0])
                                   for c in cams if r in pairs[c]])
                     for r in robots - bases.keys() if any(r in pairs[c] for c in cams)}
        bases.update(new_bases)
        if not new_cams and not new_bases:
            return cams, bases


def initial_estimate(problem: Problem, free_intrinsics: bool) -> Start:
    """OpenCV's first estimates (module docstring, method (1)); the start's values where a
    camera, a robot's base or a board's mount is not reached."""
    start, views, points = problem.start, problem.views, problem.points
    lenses, board, pairs = [], {}, {}
    for c, camera in enumerate(start.cameras):
        mine = [i for i, v in enumerate(views) if v.camera == c]
        obj = [points[views[i].ids] for i in mine]
        img = [np.asarray(views[i].pixels, dtype=float) for i in mine]
        K, dist = _intrinsics(camera, obj, img, free_intrinsics)
        lenses.append((K, dist))
        board.update({i: _board_in_camera(o, p, K, dist) for i, o, p in zip(mine, obj, img,
                                                                             strict=True)})
        pairs[c] = _pairs(problem, board, c)
    cams, bases = _tie(pairs, problem.robots[0])
    mounts = {r: [found[r][1] for found in pairs.values() if r in found] for r in problem.robots}
    cameras = [Camera(K, cam.width, cam.height, cams.get(c, cam.T_base_cam), dist, cam.name)
               for c, (cam, (K, dist)) in enumerate(zip(start.cameras, lenses, strict=True))]
    return Start(cameras, {r: bases.get(r, start.T_ref_robot[r]) for r in problem.robots},
                 {r: _mean_pose(m) if m else start.T_flange_board[r] for r, m in mounts.items()})

"""The joint least-squares solver of the cell calibration (``cellsight calibrate``).

A ChArUco board is bolted to a robot's flange (frame n of its chain,
``chain.fkine(q)[-1]``); the robot moves it through poses, the fixed cameras photograph it,
each image gives the detected corners (ids and distorted pixels) and each pose the joints as
the encoders read them. From that alone (never a truth) :func:`calibrate` estimates, in one
frame, the reference robot's frame 0 ("ref", the grasping robot's base):

- every camera's intrinsics ``fx fy cx cy`` (px) and radial distortion ``k1 k2`` (``p1 p2``
  zero, ``k3`` held at its start value) and its pose ``T_ref_cam`` (the optical frame: x
  right, y down, z forward; m);
- every other robot's base ``T_ref_robot`` (its frame 0 in ref);
- the board's pose on each robot's flange ``T_flange_board`` (the board is moved between
  robots; board points are given in the board frame, m);
- optionally each robot's joint zero offsets ``dq`` (true joint = reading + dq; rad, m for a
  prismatic joint).

**Method.**

1. OpenCV's first estimates: per camera its intrinsics by ``cv2.calibrateCamera`` over its
   views (the start K as the guess, k3 fixed), per view the board's pose in the camera by
   ``cv2.solvePnP``, per camera and robot (with ``MIN_POSES`` poses turning about more than
   one axis) the camera's pose in the robot's base and the board on the flange by
   ``cv2.calibrateRobotWorldHandEye`` (:func:`hand_eye`), tied into ref through the cameras
   that see two robots (mean poses). A camera, a base or a mount no pair reaches keeps its
   start value.
2. One refinement by ``scipy.optimize.least_squares`` of every detected corner's reprojection
   error (px, through :meth:`cellsight.camera.Camera.project_camera`) over all cameras, poses
   and robots at once. Rotations are rotation vectors, increments applied on the left of the
   first estimates (about the axes of ref, or of the flange for the board); positions and
   intrinsics additive increments. MINPACK's Levenberg-Marquardt with ``x_scale`` by the
   Jacobian: from OpenCV's estimates about a dozen iterations, where the trust-region
   reflective method, its region growing from one scaled unit, takes about twenty; a trial
   step that puts a corner behind a camera gives NaN and is rejected as one that raises the
   cost. The Jacobian is analytic (the chain rule through ``cv2.projectPoints``' derivatives
   and SO(3)'s left Jacobian) and dense, a few thousand rows by a few tens of columns: given
   as a sparsity pattern instead, SciPy's finite differences and LSMR steps took hundreds of
   iterations.

**Gauge.** The reference robot's base is the identity and is not estimated. With joint
offsets free, the first and the last joint's offsets of every robot are held at zero, being
unobservable: the first one of the reference robot turns (or, prismatic, shifts) everything
else about its axis, the first one of another robot is a motion of its base about that axis,
and the last one of any robot, ``A_n(q + dq) = A_n(q) X(dq)`` for a constant ``X``, is a
change of the board's mount. The estimates are therefore those of the chain whose first and
last joints read true, with ``T_ref_robot`` and ``T_flange_board`` absorbing their offsets.
The other offsets' identifiability is measured, not assumed (:attr:`Solution.joint_offset_sine`).

**Uncertainty.** The covariance of the estimates is ``s^2 (J^T J)^-1`` with ``J`` the
Jacobian at the solution and ``s^2`` the residual variance per pixel coordinate (``|r|^2 /
(m - p)``), or ``pixel_sigma^2`` when given; reported as standard deviations
(:class:`CameraStd`, :class:`PoseStd`). NaN marks a value that is not estimated.

**Refusals** (:class:`cellsight.errors.CellsightError`, naming the camera or robot and the
poses, and what to do): a camera without any view, a camera or robot with fewer than
``MIN_POSES`` distinct poses, a robot whose flange turns about one axis only between its poses
(hand-eye unobservable: :func:`rotation_spread_deg` below ``MIN_SPREAD_DEG``), and malformed
views.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from threadpoolctl import threadpool_limits

from cellsight.calibration.first_estimate import initial_estimate
from cellsight.calibration.solution import CameraStd, PoseStd, Problem, Solution, Start, View
from cellsight.calibration.solve_checks import (
    MIN_CORNERS,
    check_coverage,
    check_motion,
    check_view,
    pose_joints,
)
from cellsight.camera import Camera
from cellsight.errors import CellsightError
from cellsight.kinematics import KinematicChain

LENS = ("k1", "k2", "p1", "p2")  # OpenCV's first four distortion coefficients, in order
FREE_LENS = ("k1", "k2")
"""The distortion coefficients estimated: the radial ones. Tangential distortion moves a
narrow lens's image almost as a shift of its principal point does: freed, the two trade, and
the principal point wanders by tens of pixels on images that fit within 0.25 px."""
INTRINSICS = ("fx", "fy", "cx", "cy", *FREE_LENS)  # the free intrinsics, in order
_LENS_AT = np.array([LENS.index(k) for k in FREE_LENS])
POSE_SIZE = 6  # a pose increment: rotation vector (3, rad), then translation (3, m)


def calibrate(views: Sequence[View], board_points: np.ndarray,
              chains: dict[str, KinematicChain], start: Start, *, free_intrinsics: bool = True,
              joint_offsets: bool = False, pixel_sigma: float | None = None) -> Solution:
    """Calibrate the cameras, the robots' bases, the board's mounts and (``joint_offsets``)
    the joint zero offsets from ``views`` of the board whose corners are ``board_points``
    (N, 3) m in the board frame, the robots' ``chains`` and the ``start`` values (module
    docstring). ``free_intrinsics`` False holds every camera's K and distortion at the
    start's. ``pixel_sigma`` (px): the detections' noise per coordinate, if known; else the
    residuals' variance scales the standard deviations."""
    if pixel_sigma is not None and not pixel_sigma > 0:
        raise CellsightError(f"calibration: pixel_sigma must be a positive number of pixels "
                             f"or None, got {pixel_sigma!r}")
    problem = _problem(list(views), board_points, chains, start)
    initial = initial_estimate(problem, free_intrinsics)
    model = _Model(problem, initial, free_intrinsics, joint_offsets)
    return model.solve(pixel_sigma)


# --- the checks --------------------------------------------------------------------------------


def _problem(views: list[View], board_points: np.ndarray, chains: dict[str, KinematicChain],
             start: Start) -> Problem:
    """The input checked (module docstring, refusals) and indexed."""
    points = np.asarray(board_points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < MIN_CORNERS:
        raise CellsightError(f"calibration: board_points must be (N >= {MIN_CORNERS}, 3) "
                             f"metres in the board frame, got shape {points.shape}")
    reference = start.reference
    for view in views:
        check_view(view, len(points), start, chains)
    poses = pose_joints(views)
    check_coverage(views, start, reference)
    robots = [reference, *sorted({r for r, _ in poses} - {reference})]
    flange = {key: chains[key[0]].fkine(q)[-1] for key, q in poses.items()}
    for robot in robots:
        check_motion(robot, {p: T for (r, p), T in flange.items() if r == robot})
    return Problem(views, points, chains, start, robots, poses, flange)


# --- OpenCV's first estimates -------------------------------------------------------------------


# --- the refinement -----------------------------------------------------------------------------


def _moved(T0: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``T0`` moved by the increment ``x`` (rotation vector, translation): rotation on the
    left, translation added."""
    T = T0.copy()
    T[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix() @ T0[:3, :3]
    T[:3, 3] += x[3:]
    return T


def _free_joints(chain: KinematicChain, estimate: bool) -> np.ndarray:
    """The joints whose offsets are estimated: none, or all but the first and the last."""
    return np.arange(1, chain.n - 1) if estimate else np.arange(0)


class _Layout:
    """Where each estimate sits in the parameter vector: per camera its pose increment and
    (free intrinsics) the ``INTRINSICS`` increments, per robot but the reference its base's
    increment, per robot its board's, then the free joint offsets."""

    def __init__(self, problem: Problem, free_intrinsics: bool, joint_offsets: bool) -> None:
        self.size, self.free_intrinsics = 0, free_intrinsics
        per_camera = POSE_SIZE + (len(INTRINSICS) if free_intrinsics else 0)
        self.camera = [self._take(per_camera) for _ in problem.start.cameras]
        self.robot = {r: self._take(POSE_SIZE) for r in problem.robots[1:]}
        self.board = {r: self._take(POSE_SIZE) for r in problem.robots}
        self.joints = {r: _free_joints(problem.chains[r], joint_offsets) for r in problem.robots}
        self.offsets = {r: self._take(len(self.joints[r])) for r in problem.robots}

    def _take(self, size: int) -> slice:
        """The next ``size`` parameters."""
        block = slice(self.size, self.size + size)
        self.size += size
        return block


@dataclass(frozen=True)
class _State:
    """The estimates at one parameter vector (the :class:`Solution`'s first fields)."""

    cameras: list[Camera]
    T_ref_robot: dict[str, np.ndarray]
    T_flange_board: dict[str, np.ndarray]
    joint_offsets: dict[str, np.ndarray]


class _Corners(NamedTuple):
    """Corners' Jacobian parts: ``G`` d pixel / d (corner in ref), ``R_base`` the base's
    rotation, ``g`` their poses, ``y`` the corners in the robot's frame 0, ``turned`` the
    board's points turned by the mount (one row per corner)."""

    G: np.ndarray
    R_base: np.ndarray
    g: np.ndarray
    y: np.ndarray
    turned: np.ndarray

    def of(self, mask: np.ndarray) -> _Corners:
        return _Corners(*(a[mask] for a in self))


def _skew(v: np.ndarray) -> np.ndarray:
    """The cross-product matrices ``[v]x`` (..., 3, 3) of vectors ``v`` (..., 3)."""
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return out


def _left_jacobian(rho: np.ndarray) -> np.ndarray:
    """SO(3)'s left Jacobian at the rotation vector ``rho``: ``exp(rho + d) = exp(J d) exp(rho)``
    to first order in ``d``."""
    theta, S = float(np.linalg.norm(rho)), _skew(np.asarray(rho, dtype=float))
    if theta < 1e-8:
        return np.eye(3) + 0.5 * S
    return (np.eye(3) + (1.0 - np.cos(theta)) / theta**2 * S
            + (theta - np.sin(theta)) / theta**3 * S @ S)


def _apply(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Poses ``T`` (M, 4, 4) applied to points (M, 3), one each."""
    return np.einsum("mij,mj->mi", T[:, :3, :3], points) + T[:, :3, 3]


class _Model:
    """The reprojection errors of every detected corner, camera by camera, as a function of
    the parameter vector (:class:`_Layout`: increments on OpenCV's first estimates
    ``initial``, zero there), and their Jacobian (rotations turned on the left: ``d(R v) /
    d rho = -[R v]x J_l(rho)``)."""

    def __init__(self, problem: Problem, initial: Start, free_intrinsics: bool,
                 joint_offsets: bool) -> None:
        self.problem, self.initial = problem, initial
        self.layout = _Layout(problem, free_intrinsics, joint_offsets)
        self.keys = list(problem.poses)  # the poses, (robot, pose)
        slot = {key: g for g, key in enumerate(self.keys)}
        views = problem.views
        self.by_camera = [[i for i, v in enumerate(views) if v.camera == c]
                          for c in range(len(problem.start.cameras))]
        self.local = [np.concatenate([[k] * len(views[i].ids) for k, i in enumerate(mine)])
                      .astype(int) for mine in self.by_camera]  # each corner's view in mine
        self.pose_of = [np.array([slot[views[i].robot, views[i].pose] for i in mine])[local]
                        for mine, local in zip(self.by_camera, self.local, strict=True)]
        self.points = [np.concatenate([problem.points[views[i].ids] for i in mine])
                       for mine in self.by_camera]
        self.robot_of = np.array([problem.robots.index(r) for r, _ in self.keys])  # per pose
        self.pixels = [np.concatenate([np.asarray(views[i].pixels, dtype=float) for i in mine])
                       for mine in self.by_camera]

    def state(self, x: np.ndarray) -> _State:
        """The estimates at ``x``."""
        lay, init = self.layout, self.initial
        cameras = [self._camera(cam, x[lay.camera[c]]) for c, cam in enumerate(init.cameras)]
        bases = {r: _moved(init.T_ref_robot[r], x[lay.robot[r]]) if r in lay.robot
                 else np.eye(4) for r in self.problem.robots}
        boards = {r: _moved(init.T_flange_board[r], x[lay.board[r]])
                  for r in self.problem.robots}
        offsets = {}
        for robot, joints in lay.joints.items():
            offsets[robot] = np.zeros(self.problem.chains[robot].n)
            offsets[robot][joints] = x[lay.offsets[robot]]
        return _State(cameras, bases, boards, offsets)

    def _camera(self, camera: Camera, x: np.ndarray) -> Camera:
        K, dist = camera.K.copy(), camera.dist5.copy()
        if self.layout.free_intrinsics:
            K[0, 0], K[1, 1], K[0, 2], K[1, 2] = K[[0, 1, 0, 1], [0, 1, 2, 2]] + x[6:10]
            dist[_LENS_AT] += x[10:10 + len(FREE_LENS)]
        return Camera(K, camera.width, camera.height, _moved(camera.T_base_cam, x[:6]), dist,
                      camera.name)

    def frames(self, state: _State) -> list[np.ndarray]:
        """Per pose, the robot's frames 0..n (n+1, 4, 4) at the readings plus the offsets."""
        chains, poses = self.problem.chains, self.problem.poses
        return [chains[r].fkine(poses[r, p] + state.joint_offsets[r]) for r, p in self.keys]

    def _per_corner(self, c: int, T: dict[str, np.ndarray]) -> np.ndarray:
        """A robot's pose ``T[robot]`` for each corner of camera ``c`` (M, 4, 4)."""
        robots = [r for r, _ in self.keys]
        return np.array([T[r] for r in robots])[self.pose_of[c]]

    def errors(self, state: _State) -> list[np.ndarray]:
        """Per camera, the projected minus the detected pixels of its corners (M_c, 2)."""
        F = np.array([f[-1] for f in self.frames(state)])
        boards = np.array([state.T_ref_robot[r] @ F[g] @ state.T_flange_board[r]
                           for g, (r, _) in enumerate(self.keys)])
        return [camera.project_camera(_apply(camera.T_cam_base @ boards[self.pose_of[c]],
                                             self.points[c])) - self.pixels[c]
                for c, camera in enumerate(state.cameras)]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return np.concatenate(self.errors(self.state(x))).ravel()

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """d residuals / d x (2M, size)."""
        state = self.state(x)
        frames = self.frames(state)
        return np.concatenate([self._camera_jacobian(c, x, state, frames).reshape(
            -1, self.layout.size) for c in range(len(state.cameras))])

    def _camera_jacobian(self, c: int, x: np.ndarray, state: _State,
                         frames: list[np.ndarray]) -> np.ndarray:
        """Camera ``c``'s corners' rows of the Jacobian (M_c, 2, size)."""
        lay, camera, g = self.layout, state.cameras[c], self.pose_of[c]
        mount, base = (self._per_corner(c, T) for T in (state.T_flange_board, state.T_ref_robot))
        turned = np.einsum("mij,mj->mi", mount[:, :3, :3], self.points[c])  # R_B P
        y = _apply(np.array([f[-1] for f in frames])[g], turned + mount[:, :3, 3])
        w = _apply(base, y)
        u = w - camera.T_base_cam[:3, 3]
        _, jac = cv2.projectPoints(u @ camera.T_base_cam[:3, :3], np.zeros(3), np.zeros(3),
                                   camera.K, camera.dist5)
        jac = jac.reshape(len(u), 2, -1)
        jac[:, 0, 3:6] += camera.K[0, 1] / camera.K[1, 1] * jac[:, 1, 3:6]  # skew, if any
        G = jac[:, :, 3:6] @ camera.T_base_cam[:3, :3].T  # d pixel / d w
        out = np.zeros((len(u), 2, lay.size))
        at = lay.camera[c].start
        out[:, :, at:at + 3] = G @ _skew(u) @ _left_jacobian(x[at:at + 3])
        out[:, :, at + 3:at + 6] = -G
        if lay.free_intrinsics:
            out[:, :, at + 6:at + 10] = jac[:, :, 6:10]
            out[:, :, at + 10:at + 10 + len(FREE_LENS)] = jac[:, :, 10 + _LENS_AT]
        corners = _Corners(G, base[:, :3, :3], g, y, turned)
        for index, robot in enumerate(self.problem.robots):
            mine = self.robot_of[g] == index
            if mine.any():
                out[mine] = self._robot_columns(robot, x, frames, corners.of(mine), out[mine])
        return out

    def _robot_columns(self, robot: str, x: np.ndarray, frames: list[np.ndarray],
                       corners: _Corners, out: np.ndarray) -> np.ndarray:
        """``out`` with the columns of ``robot``'s base, board and offsets filled for its
        ``corners``."""
        lay = self.layout
        G, R_base, g, y, turned = corners
        Gb = G @ R_base  # d pixel / d y
        if robot in lay.robot:
            at = lay.robot[robot].start
            turned_y = np.einsum("mij,mj->mi", R_base, y)
            out[:, :, at:at + 3] = -G @ _skew(turned_y) @ _left_jacobian(x[at:at + 3])
            out[:, :, at + 3:at + 6] = G
        H = Gb @ np.array([f[-1, :3, :3] for f in frames])[g]  # d pixel / d (flange point)
        at = lay.board[robot].start
        out[:, :, at:at + 3] = -H @ _skew(turned) @ _left_jacobian(x[at:at + 3])
        out[:, :, at + 3:at + 6] = H
        chain, joints = self.problem.chains[robot], lay.joints[robot]
        if len(joints):
            own = np.flatnonzero(self.robot_of == self.problem.robots.index(robot))
            lookup = np.zeros(len(self.keys), dtype=int)
            lookup[own] = np.arange(len(own))
            axes, origins = (np.array(a)[lookup[g]][:, joints]
                             for a in zip(*(chain.joint_axes(frames[k]) for k in own), strict=True))
            moves = np.where(chain.prismatic[joints][None, :, None], axes,
                             np.cross(axes, y[:, None] - origins))  # (M, free joints, 3)
            out[:, :, lay.offsets[robot]] = np.einsum("mij,mkj->mik", Gb, moves)
        return out

    def solve(self, pixel_sigma: float | None) -> Solution:
        """The refinement from the first estimates, and its :class:`Solution`."""
        x0 = np.zeros(self.layout.size)
        self._check_start(x0)
        with threadpool_limits(limits=1, user_api="blas"):  # small matrices: threads cost
            result = least_squares(self.residuals, x0, jac=self.jacobian, method="lm",
                                   x_scale="jac")
            return _solution(self, result.x, result.jac, pixel_sigma)

    def _check_start(self, x0: np.ndarray) -> None:
        """Refuse first estimates that put corners behind a camera."""
        for c, errors in enumerate(self.errors(self.state(x0))):
            bad = ~np.isfinite(errors).all(axis=1)
            if bad.any():
                view = self.problem.views[self.by_camera[c][self.local[c][bad][0]]]
                raise CellsightError(
                    f"calibration: camera {self.initial.cameras[c].name}: the first estimate "
                    f"puts the board of robot {view.robot!r} at pose {view.pose} behind it; "
                    f"check the views' camera indices and the start values")


# --- the solution -------------------------------------------------------------------------------


def _covariance(J: np.ndarray, r: np.ndarray, pixel_sigma: float | None
               ) -> tuple[np.ndarray, np.ndarray]:
    """The covariance ``s^2 (J^T J)^-1`` of the estimates (module docstring) and, per
    parameter, the sine of the angle between its column of ``J`` and the span of the others
    (``1 / sqrt`` of the diagonal of the inverse of the column-normalised normal matrix)."""
    dof = max(len(r) - J.shape[1], 1)
    variance = pixel_sigma**2 if pixel_sigma is not None else float(r @ r) / dof
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0.0] = 1.0
    _, s, Vt = np.linalg.svd(J / norms, full_matrices=False)
    s = np.maximum(s, s[0] * np.finfo(float).eps)
    inverse = (Vt.T / s**2) @ Vt
    return variance * inverse / np.outer(norms, norms), 1.0 / np.sqrt(np.diag(inverse))


def _pose_std(sd: np.ndarray) -> PoseStd:
    return PoseStd(1e3 * sd[3:6], np.degrees(sd[:3]))


def _camera_std(sd: np.ndarray, camera: Camera) -> CameraStd:
    if len(sd) == POSE_SIZE:
        sd = np.concatenate([sd, np.full(len(INTRINSICS), np.nan)])
    focal = 100.0 * sd[6:8] / np.array([camera.K[0, 0], camera.K[1, 1]])
    lens = np.full(len(LENS), np.nan)
    lens[_LENS_AT] = sd[10:10 + len(FREE_LENS)]
    return CameraStd(_pose_std(sd), focal, sd[8:10], lens)


def _solution(model: _Model, x: np.ndarray, J: np.ndarray, pixel_sigma: float | None
              ) -> Solution:
    """The :class:`Solution` at ``x``, ``J`` the Jacobian there."""
    lay, state = model.layout, model.state(x)
    errors = model.errors(state)
    cov, sine = _covariance(J, np.concatenate(errors).ravel(), pixel_sigma)
    sd = np.sqrt(np.diag(cov))
    per_view = _per_view(model, errors)
    nan6 = np.full(POSE_SIZE, np.nan)
    offsets_sd, offsets_sine = {}, {}
    for robot, joints in lay.joints.items():
        offsets_sd[robot] = np.full(len(state.joint_offsets[robot]), np.nan)
        offsets_sine[robot] = offsets_sd[robot].copy()
        offsets_sd[robot][joints] = sd[lay.offsets[robot]]
        offsets_sine[robot][joints] = sine[lay.offsets[robot]]
    corners = np.concatenate(errors)
    return Solution(
        state.cameras, state.T_ref_robot, state.T_flange_board, state.joint_offsets, per_view,
        np.array([_rms(e) for e in per_view]), np.array([_rms(e) for e in errors]),
        _rms(corners),
        [_camera_std(sd[lay.camera[c]], cam) for c, cam in enumerate(state.cameras)],
        {r: _pose_std(sd[lay.robot[r]] if r in lay.robot else nan6) for r in lay.board},
        {r: _pose_std(sd[lay.board[r]]) for r in lay.board}, offsets_sd, offsets_sine,
        model.initial)


def _per_view(model: _Model, errors: list[np.ndarray]) -> list[np.ndarray]:
    """The per-camera errors split back into the views' order."""
    out: list[np.ndarray] = [np.empty((0, 2))] * len(model.problem.views)
    for mine, local, e in zip(model.by_camera, model.local, errors, strict=True):
        for k, i in enumerate(mine):
            out[i] = e[local == k]
    return out


def _rms(errors: np.ndarray) -> float:
    """RMS of the reprojection distances (px)."""
    return float(np.sqrt(np.mean(np.sum(errors**2, axis=1)))) if len(errors) else float("nan")

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

from cellsight.camera import Camera
from cellsight.errors import CellsightError, KinematicsError, short_repr
from cellsight.geometry.transforms import invert_pose, make_pose
from cellsight.kinematics import KinematicChain

MIN_POSES = 6  # distinct poses a camera, a robot, or a camera-robot pair for hand-eye, needs
MIN_CORNERS = 4  # corners a view needs (solvePnP's least)
MIN_SPREAD_DEG = 5.0  # deg: least second singular value of the relative flange rotations
IDENTIFIABLE_SINE = 1e-3  # least sine between an offset's column and the others' span
LENS = ("k1", "k2", "p1", "p2")  # OpenCV's first four distortion coefficients, in order
FREE_LENS = ("k1", "k2")
"""The distortion coefficients estimated: the radial ones. Tangential distortion moves a
narrow lens's image almost as a shift of its principal point does: freed, the two trade, and
the principal point wanders by tens of pixels on images that fit within 0.25 px."""
INTRINSICS = ("fx", "fy", "cx", "cy", *FREE_LENS)  # the free intrinsics, in order
_LENS_AT = np.array([LENS.index(k) for k in FREE_LENS])
POSE_SIZE = 6  # a pose increment: rotation vector (3, rad), then translation (3, m)
_IDENTITY_TOL = 1e-9


@dataclass(frozen=True)
class View:
    """One camera's image of the board at one robot pose.

    ``camera``: index into the cameras; ``robot``: the robot holding the board; ``pose``: the
    index of the robot's pose (several cameras see the same pose); ``joints`` (n,): the
    encoder readings at that pose (rad, m); ``ids`` (m,): detected corner ids (rows of the
    board points); ``pixels`` (m, 2): their image coordinates (px, distorted, as detected).
    """

    camera: int
    robot: str
    pose: int
    joints: np.ndarray
    ids: np.ndarray
    pixels: np.ndarray


@dataclass(frozen=True)
class Start:
    """Values to start from, all in ref (the reference robot's frame 0): ``cameras``
    (:class:`cellsight.camera.Camera`, ``T_base_cam`` meaning ``T_ref_cam``), every robot's
    base ``T_ref_robot`` (the reference robot's is the identity) and the board's mount on each
    robot's flange ``T_flange_board``."""

    cameras: list[Camera]
    T_ref_robot: dict[str, np.ndarray]
    T_flange_board: dict[str, np.ndarray]

    @property
    def reference(self) -> str:
        """The reference robot: the one whose ``T_ref_robot`` is the identity."""
        found = [name for name, T in self.T_ref_robot.items()
                 if np.allclose(T, np.eye(4), rtol=0.0, atol=_IDENTITY_TOL)]
        if len(found) != 1:
            raise CellsightError(f"calibration start: exactly one robot's T_ref_robot must be "
                                 f"the identity (the reference robot), got {found or 'none'}; "
                                 f"give the others' bases in the reference robot's frame 0")
        return found[0]


@dataclass(frozen=True)
class PoseStd:
    """Standard deviations of a pose: ``position_mm`` (3,) of its origin along the axes of
    the frame it is given in (mm); ``rotation_deg`` (3,) of its rotation about those axes
    (the board's: about the flange's axes) (deg)."""

    position_mm: np.ndarray
    rotation_deg: np.ndarray


@dataclass(frozen=True)
class CameraStd:
    """Standard deviations of a camera's estimates: ``pose`` (``T_ref_cam``'s, in ref);
    ``focal_pct`` (2,) of fx, fy (% of the value); ``principal_px`` (2,) of cx, cy (px);
    ``distortion`` (4,) of k1, k2, p1, p2. NaN where the intrinsics were held."""

    pose: PoseStd
    focal_pct: np.ndarray
    principal_px: np.ndarray
    distortion: np.ndarray


@dataclass(frozen=True)
class Solution:
    """A calibration, in ref (the reference robot's frame 0).

    ``cameras``: the calibrated cameras (same names and sizes as the start's; ``T_base_cam``
    is ``T_ref_cam``); ``T_ref_robot`` (every robot, the reference's the identity);
    ``T_flange_board``; ``joint_offsets`` (n,) per robot (rad, m; zeros when not estimated
    or fixed by the gauge). ``residuals_px``: per view, in the views' order, the projected
    minus the detected pixels (m, 2); ``view_rms_px`` and ``camera_rms_px``: the RMS of the
    corners' reprojection distances per view and per camera; ``rms_px`` over all corners.
    Standard deviations: ``camera_std``, ``robot_std`` (NaN for the reference),
    ``board_std``, ``joint_offset_std`` (rad, m; NaN where not estimated).
    ``joint_offset_sine``: per offset, the sine of the angle between its column of the
    (column-normalised) Jacobian and the span of all the other columns: 1 when no other
    estimate can mimic it, 0 when it is unobservable (NaN where not estimated).
    ``initial``: OpenCV's first estimates the refinement started from.
    """

    cameras: list[Camera]
    T_ref_robot: dict[str, np.ndarray]
    T_flange_board: dict[str, np.ndarray]
    joint_offsets: dict[str, np.ndarray]
    residuals_px: list[np.ndarray]
    view_rms_px: np.ndarray
    camera_rms_px: np.ndarray
    rms_px: float
    camera_std: list[CameraStd]
    robot_std: dict[str, PoseStd]
    board_std: dict[str, PoseStd]
    joint_offset_std: dict[str, np.ndarray]
    joint_offset_sine: dict[str, np.ndarray]
    initial: Start

    @property
    def joint_offsets_identifiable(self) -> dict[str, np.ndarray]:
        """Per robot (n,) bool: the offset was estimated and its sine is at least
        ``IDENTIFIABLE_SINE`` (the data pin it within 1000 times the precision they would
        give were everything else known)."""
        return {r: np.nan_to_num(s, nan=0.0) >= IDENTIFIABLE_SINE
                for r, s in self.joint_offset_sine.items()}


@dataclass(frozen=True)
class _Problem:
    """The checked input: ``robots`` (the reference first), ``poses`` (robot, pose) -> the
    joints read there, ``flange`` (robot, pose) -> ``T_robot_flange`` at those readings."""

    views: list[View]
    points: np.ndarray
    chains: dict[str, KinematicChain]
    start: Start
    robots: list[str]
    poses: dict[tuple[str, int], np.ndarray]
    flange: dict[tuple[str, int], np.ndarray]


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
    initial = _initial_estimate(problem, free_intrinsics)
    model = _Model(problem, initial, free_intrinsics, joint_offsets)
    return model.solve(pixel_sigma)


# --- the checks --------------------------------------------------------------------------------


def _problem(views: list[View], board_points: np.ndarray, chains: dict[str, KinematicChain],
             start: Start) -> _Problem:
    """The input checked (module docstring, refusals) and indexed."""
    points = np.asarray(board_points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < MIN_CORNERS:
        raise CellsightError(f"calibration: board_points must be (N >= {MIN_CORNERS}, 3) "
                             f"metres in the board frame, got shape {points.shape}")
    reference = start.reference
    for view in views:
        _check_view(view, len(points), start, chains)
    poses = _pose_joints(views)
    _check_coverage(views, start, reference)
    robots = [reference, *sorted({r for r, _ in poses} - {reference})]
    flange = {key: chains[key[0]].fkine(q)[-1] for key, q in poses.items()}
    for robot in robots:
        _check_motion(robot, {p: T for (r, p), T in flange.items() if r == robot})
    return _Problem(views, points, chains, start, robots, poses, flange)


def _check_view(view: View, n_points: int, start: Start, chains: dict[str, KinematicChain]
                ) -> None:
    """One view's fields: a known camera and robot, joints, ids and pixels that agree."""
    where = f"calibration: view of camera {view.camera}, robot {view.robot!r}, pose {view.pose}"
    if not 0 <= view.camera < len(start.cameras):
        raise CellsightError(f"{where}: no such camera (the start has {len(start.cameras)}); "
                             f"number the cameras as the start lists them")
    if view.robot not in chains.keys() & start.T_ref_robot.keys() & start.T_flange_board.keys():
        raise CellsightError(f"{where}: the robot needs a chain, a start base and a start "
                             f"board mount; give them")
    ids, pixels = np.asarray(view.ids), np.asarray(view.pixels)
    good = (ids.ndim == 1 and np.issubdtype(ids.dtype, np.integer) and len(ids) >= MIN_CORNERS
            and len(np.unique(ids)) == len(ids) and pixels.shape == (len(ids), 2)
            and bool(np.isfinite(pixels).all()))
    if not good or not 0 <= ids.min() <= ids.max() < n_points:
        raise CellsightError(f"{where}: needs at least {MIN_CORNERS} distinct integer corner "
                             f"ids in [0, {n_points}) and finite (m, 2) pixels, got ids "
                             f"{short_repr(ids)} and pixels of shape {pixels.shape}; drop the "
                             f"view or fix its detections")
    try:
        chains[view.robot].check_q(view.joints)
    except KinematicsError as exc:
        raise CellsightError(f"{where}: {exc}; give the encoders' reading of every joint") \
            from exc


def _pose_joints(views: list[View]) -> dict[tuple[str, int], np.ndarray]:
    """(robot, pose) -> the joints read there, the same in every view of that pose."""
    poses: dict[tuple[str, int], np.ndarray] = {}
    for view in views:
        q = np.asarray(view.joints, dtype=float)
        known = poses.setdefault((view.robot, view.pose), q)
        if not np.array_equal(known, q):
            raise CellsightError(f"calibration: robot {view.robot!r} pose {view.pose}: the "
                                 f"views of camera {view.camera} and of an earlier one give "
                                 f"different joints; number each pose once")
    return poses


def _check_coverage(views: list[View], start: Start, reference: str) -> None:
    """Every camera sees the board in ``MIN_POSES`` distinct poses, every robot shows it in
    as many."""
    for c, camera in enumerate(start.cameras):
        seen = sorted({(v.robot, v.pose) for v in views if v.camera == c})
        if not seen:
            raise CellsightError(f"calibration: camera {camera.name} has no view of the board; "
                                 f"plan poses in its view, or remove it from the cell")
        if len(seen) < MIN_POSES:
            raise CellsightError(f"calibration: camera {camera.name} sees the board in "
                                 f"{len(seen)} distinct poses ({_poses_text(seen)}), fewer than "
                                 f"{MIN_POSES}; plan more poses in its view")
    if not any(v.robot == reference for v in views):
        raise CellsightError(f"calibration: the reference robot {reference!r} shows the board "
                             f"to no camera: the frame of the calibration is its base; add its "
                             f"poses")
    for robot in sorted({v.robot for v in views}):
        seen = sorted({(v.robot, v.pose) for v in views if v.robot == robot})
        if len(seen) < MIN_POSES:
            raise CellsightError(f"calibration: robot {robot!r} shows the board in "
                                 f"{len(seen)} distinct poses ({_poses_text(seen)}), fewer than "
                                 f"{MIN_POSES}; plan more poses of it in the cameras' view")


def _poses_text(seen: list[tuple[str, int]]) -> str:
    return ", ".join(f"{robot} pose {pose}" for robot, pose in seen)


def rotation_spread_deg(T_base_flange: np.ndarray) -> float:
    """How far the flange's rotations between poses turn about more than one axis (deg): the
    second singular value, over the square root of their count, of the rotation vectors of
    the relative rotations ``R_i^T R_j`` of every pair of poses (``T_base_flange``
    (P, 4, 4)). Zero when every relative rotation is about one axis (or none); the RMS angle
    about the second axis otherwise."""
    R = np.asarray(T_base_flange, dtype=float)[:, :3, :3]
    if len(R) < 3:  # one relative rotation at most: one axis
        return 0.0
    i, j = np.triu_indices(len(R), 1)
    turns = Rotation.from_matrix(np.swapaxes(R[i], 1, 2) @ R[j]).as_rotvec()
    sigma = np.linalg.svd(turns, compute_uv=False) / np.sqrt(len(turns))
    return float(np.degrees(sigma[1]))


def _check_motion(robot: str, flange: dict[int, np.ndarray]) -> None:
    """Refuse a robot whose flange turns about one axis only between its poses."""
    order = sorted(flange)
    spread = rotation_spread_deg(np.array([flange[p] for p in order]))
    if spread < MIN_SPREAD_DEG:
        raise CellsightError(f"calibration: robot {robot!r}, poses {order}: the flange turns "
                             f"about one axis only between them (spread {spread:.3g} deg < "
                             f"{MIN_SPREAD_DEG:g} deg): the cameras' poses and the board's "
                             f"mount are unobservable; add poses that tilt the board about "
                             f"other axes")


# --- OpenCV's first estimates -------------------------------------------------------------------


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


def _pairs(problem: _Problem, board: dict[int, np.ndarray], c: int
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


def _initial_estimate(problem: _Problem, free_intrinsics: bool) -> Start:
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

    def __init__(self, problem: _Problem, free_intrinsics: bool, joint_offsets: bool) -> None:
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

    def __init__(self, problem: _Problem, initial: Start, free_intrinsics: bool,
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

"""Perspective-n-point pose of a workpiece from one frame's pixels in one or more cameras.

Used to initialise the EKF when a part is first seen, and as the per-frame baseline the EKF is
compared against. Steps:

1. per camera with at least ``min_points`` features: ``cv2.solvePnP`` (SQPnP, then
   Levenberg-Marquardt refinement) gives ``T_cam_part``, hence
   ``T_base_part = T_base_cam T_cam_part``;
2. fusion: each per-camera solution seeds a damped Gauss-Newton (Levenberg-Marquardt) minimisation
   of the reprojection error over all cameras' features together, in the pose parameters
   ``[x, y, z, roll, pitch, yaw]`` with the analytic Jacobian of
   :class:`~cellsight.tracking.measurement.PinholeMeasurement`; the lowest-cost result wins.

Pixels are ideal pinhole pixels (distortion removed). The returned covariance of the six pose
parameters is ``sigma^2 (J^T J)^-1`` at the solution.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from cellsight.geometry.transforms import pose_from_xyz_rpy, xyz_rpy_from_pose
from cellsight.tracking.measurement import Observation
from cellsight.tracking.motion import POSE_DIM, STATE_DIM


@dataclass(frozen=True)
class PoseFix:
    """A single-frame pose estimate: ``T_base_part``, 6x6 covariance of ``[xyz, rpy]``,
    RMS reprojection error (px), number of points and of cameras used; ``offsets_px``: camera
    index -> the image offset (2,) px taken out of its pixels first (an acquisition that
    estimates the cameras' offsets, :mod:`.acquisition`), else None; ``dropped``: the
    (camera index, feature id) of each point given but left out as wrong
    (:func:`estimate_pose_robust`); ``on_support``: fitted on a level support (``x``, ``y``
    and the yaw alone, :data:`ON_SUPPORT`)."""

    T_base_part: np.ndarray
    covariance: np.ndarray
    rms_px: float
    n_points: int
    n_cameras: int
    offsets_px: dict[int, np.ndarray] | None = None
    dropped: tuple[tuple[int, int], ...] = ()
    on_support: bool = False


def solve_pnp_camera(observation: Observation) -> np.ndarray | None:
    """``T_base_part`` from one camera's observation (>= 4 points), or None if OpenCV fails
    (including a degenerate point set that makes SQPnP raise)."""
    obj = np.ascontiguousarray(observation.points_model, dtype=np.float64).reshape(-1, 1, 3)
    img = np.ascontiguousarray(observation.pixels, dtype=np.float64).reshape(-1, 1, 2)
    if len(obj) < 4:
        return None
    # the pixels are undistorted (Camera.undistort): the camera's ideal pinhole model fits them
    camera = observation.model.camera.ideal()
    K, dist = camera.K, camera.dist
    try:
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_SQPNP)
    except cv2.error:  # degenerate configurations trip SQPnP's internal assertions
        return None
    if not ok:
        return None
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, dist, rvec, tvec)
    T_cam_part = np.eye(4)
    T_cam_part[:3, :3] = cv2.Rodrigues(rvec)[0]
    T_cam_part[:3, 3] = tvec.ravel()
    return camera.T_base_cam @ T_cam_part


def camera_shifts(observations: list[Observation], fix: PoseFix,
                  min_points: int = 4) -> dict[int, np.ndarray]:
    """Each camera's median reprojection residual (2,) px at ``fix``, for the cameras with at
    least ``min_points`` points: the image offset its calibration error would give."""
    xyz, rpy = xyz_rpy_from_pose(fix.T_base_part)
    shifts = {}
    for obs in observations:
        if len(obs.feature_ids) >= min_points:
            r, _ = _residuals([obs], np.concatenate([xyz, rpy]))
            shifts[obs.camera_index] = np.median(r.reshape(-1, 2), axis=0)
    return shifts


def _residuals(observations: list[Observation], params: np.ndarray):
    state = np.zeros(STATE_DIM)
    state[:POSE_DIM] = params
    res, jac = [], []
    for obs in observations:
        pred, H = obs.model.evaluate(state, obs.points_model)
        res.append((np.asarray(obs.pixels, dtype=float) - pred).ravel())
        jac.append(H[:, :POSE_DIM])
    return np.concatenate(res), np.concatenate(jac)


ALL_FREE = (0, 1, 2, 3, 4, 5)
ON_SUPPORT = (0, 1, 5)
"""The pose parameters free for a part resting on a level support: ``x``, ``y`` and ``yaw``
(``R = Rz(yaw) Ry(pitch) Rx(roll)``: a turn about the base z axis changes the yaw alone); its
height, roll and pitch are the support's."""

STEP_TOL = 1e-9
"""The refinement stops at a step shorter than this (m and rad of the pose): after it, the
cost changes only by rounding, and the steps were rejected one by one until the damping ran
out (about half of the evaluations of a frame's refinement)."""


def refine_pose(
    observations: list[Observation],
    T_init: np.ndarray,
    iterations: int = 30,
    sigma_px: float = 0.5,
    free: tuple[int, ...] = ALL_FREE,
) -> PoseFix | None:
    """Levenberg-Marquardt refinement of ``T_base_part`` over all observations' pixels, in the
    ``free`` pose parameters of ``[x, y, z, roll, pitch, yaw]`` (the others kept at
    ``T_init``'s; :data:`ON_SUPPORT`: a part resting on a level support). The covariance of a
    kept parameter is zero (the caller knows how well it is kept).

    Returns None when a point ends behind a camera or the normal equations are singular.
    """
    xyz, rpy = xyz_rpy_from_pose(T_init)
    params = np.concatenate([xyz, rpy])
    idx = list(free)
    lam = 1e-3
    try:
        r, J = _residuals(observations, params)
        J = J[:, idx]
        cost = r @ r
        for _ in range(iterations):
            A = J.T @ J
            step = np.linalg.solve(A + lam * np.diag(np.diag(A)), J.T @ r)
            trial = params.copy()
            trial[idx] += step
            r_t, J_t = _residuals(observations, trial)
            J_t = J_t[:, idx]
            cost_t = r_t @ r_t
            if np.isfinite(cost_t) and cost_t < cost:
                params, r, J, cost = trial, r_t, J_t, cost_t
                lam = max(lam / 10, 1e-9)
            else:
                lam *= 10
                if lam > 1e8:
                    break
            if np.linalg.norm(step) < STEP_TOL:  # converged: what is left is rounding
                break
        cov = np.zeros((POSE_DIM, POSE_DIM))
        cov[np.ix_(idx, idx)] = sigma_px**2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return None
    T = pose_from_xyz_rpy(params[:3], params[3:])
    in_front = all(
        np.all(o.model.camera.depth(o.points_model @ T[:3, :3].T + T[:3, 3]) > 0)
        for o in observations
    )
    if not (np.isfinite(cost) and in_front):
        return None
    n = len(r) // 2
    return PoseFix(
        T_base_part=T,
        covariance=cov,
        rms_px=float(np.sqrt(cost / n)),
        n_points=n,
        n_cameras=sum(1 for o in observations if len(o.feature_ids)),
    )


def estimate_pose(
    observations: list[Observation], min_points: int = 4, sigma_px: float = 0.5,
    guess: np.ndarray | None = None, support: np.ndarray | None = None,
) -> PoseFix | None:
    """Fused multi-camera PnP (module docstring); None if no camera has ``min_points`` points.
    ``guess``: a ``T_base_part`` already near the part (a search's candidate) seeds the fusion
    too, and alone where the cameras together have ``min_points`` points but none has.
    ``support``: the ``T_base_part`` of the part lying on a level support; the fit is then of
    ``x``, ``y`` and the yaw alone (:data:`ON_SUPPORT`), every seed moved onto the support
    (:func:`onto_support`)."""
    used = [o for o in observations if len(o.feature_ids) > 0]
    seeds = [solve_pnp_camera(o) for o in used if len(o.feature_ids) >= max(min_points, 4)]
    if guess is not None and sum(len(o.feature_ids) for o in used) >= max(min_points, 4):
        seeds.append(np.asarray(guess, dtype=float))
    free = ALL_FREE if support is None else ON_SUPPORT
    best: PoseFix | None = None
    for T0 in seeds:
        if T0 is None:
            continue
        if support is not None:
            T0 = onto_support(T0, support)
        fix = refine_pose(used, T0, sigma_px=sigma_px, free=free)
        if fix is not None and (best is None or fix.rms_px < best.rms_px):
            best = fix
    return best if best is None or support is None else replace(best, on_support=True)


def onto_support(T_base_part: np.ndarray, support: np.ndarray) -> np.ndarray:
    """``T_base_part`` moved onto a level support: its ``x``, ``y`` and yaw with the height,
    roll and pitch of ``support`` (the part's ``T_base_part`` lying there)."""
    xyz, rpy = xyz_rpy_from_pose(T_base_part)
    s_xyz, s_rpy = xyz_rpy_from_pose(support)
    return pose_from_xyz_rpy([xyz[0], xyz[1], s_xyz[2]], [s_rpy[0], s_rpy[1], rpy[2]])


def estimate_pose_robust(
    observations: list[Observation],
    max_rms_px: float,
    min_points: int = 4,
    sigma_px: float = 0.5,
    max_outliers: int = 3,
    max_residual_px: float = np.inf,
    guess: np.ndarray | None = None,
    support: np.ndarray | None = None,
) -> PoseFix | None:
    """:func:`estimate_pose`, dropping the worst-fitting point and solving again while the RMS
    reprojection error exceeds ``max_rms_px`` or the worst point lies more than
    ``max_residual_px`` from its reprojection (at most ``max_outliers`` points, and while more
    than ``min_points + 2`` remain): one wrong corner (an occluder's, a background edge's) would
    otherwise spoil a still part's acquisition in every frame, and among many points a corner
    10 px off hides under a small RMS. Returns the last fix, whatever its RMS (the caller
    checks), with the points it dropped (``PoseFix.dropped``). ``guess``, ``support``: as for
    :func:`estimate_pose` (on a support, points are dropped while more than ``min_points``
    remain: its fit has three parameters, not six)."""
    obs = [o for o in observations if len(o.feature_ids) > 0]
    fix = estimate_pose(obs, min_points, sigma_px, guess, support)
    dropped: list[tuple[int, int]] = []
    spare = 2 if support is None else 0
    for _ in range(max_outliers):
        if fix is None or fix.n_points <= min_points + spare:
            break
        xyz, rpy = xyz_rpy_from_pose(fix.T_base_part)
        r, _ = _residuals(obs, np.concatenate([xyz, rpy]))
        distances = np.linalg.norm(r.reshape(-1, 2), axis=1)
        worst = int(np.argmax(distances))
        if fix.rms_px <= max_rms_px and distances[worst] <= max_residual_px:
            break
        sizes = np.cumsum([len(o.feature_ids) for o in obs])
        k = int(np.searchsorted(sizes, worst, side="right"))
        row = worst - (sizes[k - 1] if k else 0)
        o = obs[k]
        dropped.append((o.camera_index, int(o.feature_ids[row])))
        keep = np.arange(len(o.feature_ids)) != row
        obs[k] = replace(o, feature_ids=o.feature_ids[keep], points_model=o.points_model[keep],
                         pixels=o.pixels[keep])
        obs = [o for o in obs if len(o.feature_ids) > 0]
        fix = estimate_pose(obs, min_points, sigma_px, guess, support)
    return None if fix is None else replace(fix, dropped=tuple(dropped))

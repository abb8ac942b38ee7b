"""The calibration's views checked before the refinement (:mod:`.solve`): each view's corners
and joints, every camera's coverage of the board, and enough motion between the poses to pin
the hand-eye problem."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from cellsight.calibration.solution import Start, View
from cellsight.errors import CellsightError, KinematicsError, short_repr
from cellsight.kinematics import KinematicChain

MIN_POSES = 6  # distinct poses a camera, a robot, or a camera-robot pair for hand-eye, needs
MIN_CORNERS = 4  # corners a view needs (solvePnP's least)
MIN_SPREAD_DEG = 5.0  # deg: least second singular value of the relative flange rotations


def check_view(view: View, n_points: int, start: Start, chains: dict[str, KinematicChain]
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


def pose_joints(views: list[View]) -> dict[tuple[str, int], np.ndarray]:
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


def check_coverage(views: list[View], start: Start, reference: str) -> None:
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


def check_motion(robot: str, flange: dict[int, np.ndarray]) -> None:
    """Refuse a robot whose flange turns about one axis only between its poses."""
    order = sorted(flange)
    spread = rotation_spread_deg(np.array([flange[p] for p in order]))
    if spread < MIN_SPREAD_DEG:
        raise CellsightError(f"calibration: robot {robot!r}, poses {order}: the flange turns "
                             f"about one axis only between them (spread {spread:.3g} deg < "
                             f"{MIN_SPREAD_DEG:g} deg): the cameras' poses and the board's "
                             f"mount are unobservable; add poses that tilt the board about "
                             f"other axes")

"""PnP on a level support (a part resting where the kinematic prior says it rests): ``x``, ``y``
and the yaw from a few points across cameras, none of which has the four a camera's own PnP
needs. The pixels are OpenCV's projection (``cv2.projectPoints``) of the built-in part at a true
pose on its support, with the cameras' ideal pinhole model."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsight import load_cell
from cellsight.geometry.transforms import pose_from_xyz_rpy, xyz_rpy_from_pose
from cellsight.tracking import Observation, PinholeMeasurement, estimate_pose
from cellsight.tracking.acquisition import PnPAcquisition
from cellsight.tracking.pnp import PoseFix, estimate_pose_robust

REST_STD = (0.002, 0.01)  # m, rad: the support's height, roll and pitch (TrackerConfig.rest_std)


@pytest.fixture(scope="module")
def cell():
    return load_cell()


def _on_support(cell, dx: float, dy: float, turn: float) -> np.ndarray:
    """The part's support pose moved by ``dx``, ``dy`` (m) and turned ``turn`` (rad) about the
    base z axis."""
    support = cell.workpieces[0].T_base_part
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array([0.0, 0.0, turn]))[0] @ support[:3, :3]
    T[:3, 3] = support[:3, 3] + [dx, dy, 0.0]
    return T


def _observations(cell, T: np.ndarray, ids_per_camera: list[list[int]],
                  wrong: dict[tuple[int, int], float] | None = None) -> list[Observation]:
    """The features ``ids_per_camera[c]`` of the part at ``T`` as camera ``c`` sees them
    (OpenCV's projection), those in ``wrong`` moved that many pixels along u."""
    part, out = cell.workpieces[0], []
    for c, ids in enumerate(ids_per_camera):
        if not ids:
            continue
        cam = cell.cameras[c].ideal()
        T_cam_part = np.linalg.inv(cam.T_base_cam) @ T
        rvec = cv2.Rodrigues(T_cam_part[:3, :3])[0]
        points = part.feature_points[ids]
        px = cv2.projectPoints(points, rvec, T_cam_part[:3, 3], cam.K, cam.dist)[0].reshape(-1, 2)
        for (cw, f), shift in (wrong or {}).items():
            if cw == c:
                px[ids.index(f), 0] += shift
        out.append(Observation(PinholeMeasurement(cell.cameras[c]), c, np.array(ids), points, px))
    return out


def _gap(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    """Position (m) and rotation (rad) between two poses."""
    angle = np.linalg.norm(cv2.Rodrigues(A[:3, :3].T @ B[:3, :3])[0])
    return float(np.linalg.norm(A[:3, 3] - B[:3, 3])), float(angle)


def _ids_seen_by_both(cell, T: np.ndarray) -> tuple[list[int], list[int]]:
    """Three features camera 0 sees and two others camera 1 sees, at ``T`` (inside both images,
    in front): no camera has the four its own PnP needs."""
    points = cell.workpieces[0].feature_points @ T[:3, :3].T + T[:3, 3]
    inside = [cam.sees(points) for cam in cell.cameras[:2]]
    first = [int(f) for f in np.flatnonzero(inside[0])[::3][:3]]
    second = [int(f) for f in np.flatnonzero(inside[1]) if f not in first][::2][:2]
    return first, second


@settings(max_examples=25, deadline=None)
@given(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(-np.pi, np.pi),
       st.floats(-0.02, 0.02), st.floats(-0.02, 0.02), st.floats(-0.15, 0.15))
def test_five_points_in_two_cameras_fit_a_resting_part(cell, dx, dy, turn, gx, gy, gturn):
    T = _on_support(cell, dx, dy, turn)
    ids = _ids_seen_by_both(cell, T)
    obs = _observations(cell, T, list(ids))
    guess = T @ pose_from_xyz_rpy([gx, gy, 0.0], [0.0, 0.0, gturn])
    assert estimate_pose(obs) is None  # no camera has four points: no seed
    fix = estimate_pose(obs, guess=guess, support=T)
    assert fix is not None and fix.on_support and fix.n_points == 5
    moved, turned = _gap(fix.T_base_part, T)
    assert moved < 1e-6 and turned < 1e-6 and fix.rms_px < 1e-3
    held = xyz_rpy_from_pose(fix.T_base_part)
    kept = xyz_rpy_from_pose(T)
    assert abs(held[0][2] - kept[0][2]) < 1e-12 and np.allclose(held[1][:2], kept[1][:2])
    assert np.all(fix.covariance[[2, 3, 4], :] == 0) and fix.covariance[0, 0] > 0


def test_a_wrong_corner_among_five_is_dropped_on_the_support(cell):
    T = _on_support(cell, 0.05, -0.04, 0.6)
    first, second = _ids_seen_by_both(cell, T)
    obs = _observations(cell, T, [first, second], wrong={(0, first[1]): 12.0})
    guess = T @ pose_from_xyz_rpy([0.01, -0.01, 0.0], [0.0, 0.0, 0.05])
    fix = estimate_pose_robust(obs, max_rms_px=2.0, guess=guess, support=T)
    assert fix is not None and fix.dropped == ((0, first[1]),) and fix.n_points == 4
    moved, turned = _gap(fix.T_base_part, T)
    assert moved < 1e-6 and turned < 1e-6
    # six numbers from the same five points: nothing dropped (five are too few to spare one),
    # and the wrong corner pulls the fit away
    free = estimate_pose_robust(obs, max_rms_px=2.0, guess=guess)
    assert free is None or free.rms_px > 2.0 or _gap(free.T_base_part, T)[0] > 1e-3


def test_the_acquisition_falls_back_on_the_support_where_six_numbers_need_more(cell):
    T = _on_support(cell, -0.03, 0.06, -1.1)
    obs = _observations(cell, T, list(_ids_seen_by_both(cell, T)))
    guess = T @ pose_from_xyz_rpy([0.008, 0.005, 0.0], [0.0, 0.0, -0.04])
    acquisition = PnPAcquisition()
    six = acquisition.fix(obs, 0.5, coarse=True, guess=guess)
    assert six is None or not acquisition.enough(six)  # five points: six numbers need six
    fix = acquisition.fix(obs, 0.5, coarse=True, guess=guess, support=(T, REST_STD))
    assert fix is not None and fix.on_support and acquisition.enough(fix)
    assert _gap(fix.T_base_part, T)[0] < 1e-6
    h, a = REST_STD
    assert np.allclose(np.diag(fix.covariance)[2:5], [h**2, a**2, a**2])
    assert not acquisition.enough(PoseFix(T, np.eye(6), 0.1, 3, 2, on_support=True))
    assert not acquisition.enough(PoseFix(T, np.eye(6), 0.1, 5, 2))


@pytest.mark.parametrize("looked, used, stands", [
    ((1, 12), (1, 5), False),  # one found of one looked for, and 5 of 12: nothing confirms
    ((4, 12), (3, 5), True),  # 3 of 4 looked for in the first camera
    ((3, 12), (3, 8), True),  # 8 of 12 in the second
    ((0, 0), (0, 0), False)])
def test_a_verification_stands_on_a_camera_that_looked_for_enough(looked, used, stands):
    """A verifying fix of 6 points stands where some camera that looked for at least
    ``verify_looked`` (4) features found ``verify_support`` (0.6) of them."""
    fix = PoseFix(np.eye(4), np.eye(6), 1.0, 6, 2)
    assert PnPAcquisition().confirms(fix, np.array(looked), np.array(used)) is stands

"""Camera projection against OpenCV's projectPoints."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cellsight.camera import Camera
from cellsight.errors import CameraError
from cellsight.geometry.transforms import invert_pose, look_at, make_pose


def test_project_matches_opencv_with_distortion() -> None:
    rng = np.random.default_rng(0)
    for trial in range(200):
        fx, fy = rng.uniform(400, 2500, 2)
        K = np.array([[fx, 0, rng.uniform(300, 450)], [0, fy, rng.uniform(200, 350)], [0, 0, 1]])
        dist = rng.normal(0, [0.1, 0.05, 0.002, 0.002, 0.01]) if trial % 4 else None
        T_base_cam = make_pose(Rotation.random(random_state=trial).as_matrix(),
                               rng.uniform(-2, 2, 3))
        cam = Camera(K, 768, 576, T_base_cam, dist)
        pts_cam = np.column_stack([rng.uniform(-0.5, 0.5, (50, 2)), rng.uniform(0.5, 4, 50)])
        pts_base = pts_cam @ T_base_cam[:3, :3].T + T_base_cam[:3, 3]
        T_cam_base = invert_pose(T_base_cam)
        rvec, _ = cv2.Rodrigues(T_cam_base[:3, :3])
        expected, _ = cv2.projectPoints(pts_base, rvec, T_cam_base[:3, 3], K,
                                        np.zeros(5) if dist is None else dist)
        np.testing.assert_allclose(cam.project(pts_base), expected[:, 0], atol=1e-6)


def test_center_front_and_image_helpers() -> None:
    K = np.array([[1000.0, 0, 383.5], [0, 1000.0, 287.5], [0, 0, 1]])
    cam = Camera(K, 768, 576, look_at([0, -2, 1], [0, 0, 0]), name="c")
    np.testing.assert_allclose(cam.center, [0, -2, 1])
    target = np.array([[0.0, 0.0, 0.0]])
    np.testing.assert_allclose(cam.project(target), [[383.5, 287.5]], atol=1e-9)
    assert cam.in_front(target).all()
    behind = np.array([[0.0, -4.0, 2.0]])
    assert not cam.in_front(behind).any()
    assert np.isnan(cam.project(behind)).all()
    assert not cam.sees(behind).any()
    assert cam.in_image(np.array([[0.0, 0.0], [767.4, 575.4]])).all()
    assert not cam.in_image(np.array([[-0.6, 10.0], [10.0, 576.0], [np.nan, 1.0]])).any()
    np.testing.assert_allclose(cam.depth(target), [np.sqrt(5)])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"K": np.eye(3) * [0, 1, 1]}, "fx, fy > 0"),
        ({"width": 0}, "image size"),
        ({"T_base_cam": np.diag([1.0, 1, -1, 1])}, "proper rotation"),
        ({"dist": [0.1, 0.2, np.nan, 0]}, "dist must be 4 or 5 finite"),
        ({"K": np.full((3, 3), np.nan)}, "finite 3x3"),
    ],
)
def test_bad_camera_parameters_are_rejected(kwargs, message) -> None:
    args = {"K": np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]]), "width": 640,
            "height": 480, "T_base_cam": np.eye(4), "name": "bad"}
    args.update(kwargs)
    with pytest.raises(CameraError, match=message):
        Camera(**args)

"""The camera model (:mod:`cellsight.camera`) and its numba twin, against OpenCV."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cellsight._camera_kernel import pinhole_jacobian, project_point, to_camera
from cellsight.camera import Camera, camera_from_lens, intrinsics
from cellsight.errors import CameraError
from cellsight.geometry.transforms import invert_pose, look_at, make_pose
from cellsight.occlusion._frame_kernel import project_points


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
    assert cam.depth(target)[0] > 0 and cam.sees(target).all()
    behind = np.array([[0.0, -4.0, 2.0]])
    assert cam.depth(behind)[0] < 0
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


def _random_camera(rng: np.random.Generator, seed: int, dist: bool = True,
                   skew: float = 0.0) -> Camera:
    fx, fy = rng.uniform(400, 2500, 2)
    K = intrinsics(fx, fy, rng.uniform(300, 450), rng.uniform(200, 350), skew)
    d = rng.normal(0, [0.1, 0.05, 0.002, 0.002, 0.01]) if dist else None
    T = make_pose(Rotation.random(random_state=seed).as_matrix(), rng.uniform(-2, 2, 3))
    return Camera(K, 768, 576, T, d, name=f"c{seed}")


def _points_cam(rng: np.random.Generator, n: int = 50) -> np.ndarray:
    return np.column_stack([rng.uniform(-0.5, 0.5, (n, 2)), rng.uniform(0.5, 4, n)])


def test_pinhole_jacobian_matches_finite_differences_and_opencv() -> None:
    rng = np.random.default_rng(1)
    for trial in range(20):
        cam = _random_camera(rng, trial, dist=False, skew=rng.uniform(-2, 2))
        pts = _points_cam(rng, 20)
        J = cam.pinhole_jacobian(pts)
        assert J.shape == (20, 2, 3)
        h = 1e-6
        for a in range(3):
            step = np.zeros(3)
            step[a] = h
            fd = (cam.project_camera(pts + step) - cam.project_camera(pts - step)) / (2 * h)
            np.testing.assert_allclose(J[:, :, a], fd, rtol=1e-6, atol=1e-4)
        # OpenCV's d(pixel)/d(tvec) at rvec = 0, tvec = 0 is d(pixel)/d(camera-frame point);
        # its projectPoints ignores the skew
        K = cam.K * [[1, 0, 1], [1, 1, 1], [1, 1, 1]]
        _, jac = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, np.zeros(5))
        J = Camera(K, cam.width, cam.height, cam.T_base_cam).pinhole_jacobian(pts)
        np.testing.assert_allclose(J.reshape(-1, 3), jac[:, 3:6], rtol=1e-9, atol=1e-9)


def test_undistort_inverts_the_distorted_projection() -> None:
    rng = np.random.default_rng(2)
    for trial in range(20):
        cam = _random_camera(rng, trial)
        pts = _points_cam(rng)
        pts = pts[np.all(np.abs(pts[:, :2] / pts[:, 2:]) < 0.3, axis=1)]  # usual field of view
        np.testing.assert_allclose(cam.undistort(cam.project_camera(pts)),
                                   cam.ideal().project_camera(pts), atol=1e-3)
    plain = Camera(np.eye(3) * [800, 800, 1] + [[0, 0, 320], [0, 0, 240], [0, 0, 0]], 640, 480,
                   np.eye(4))
    px = np.array([[1.0, 2.0], [3.0, 4.0]])
    assert plain.ideal() is plain and np.array_equal(plain.undistort(px), px)
    assert plain.undistort(np.empty((0, 2))).shape == (0, 2)


def test_numba_twin_agrees_with_the_camera_and_opencv() -> None:
    rng = np.random.default_rng(3)
    for trial in range(40):
        skew = rng.uniform(-1, 1) if trial % 2 else 0.0  # OpenCV's projectPoints has no skew
        cam = _random_camera(rng, trial, dist=trial % 4 != 0, skew=skew)
        pts = _points_cam(rng)
        pts_base = pts @ cam.T_base_cam[:3, :3].T + cam.T_base_cam[:3, 3]
        R, t = cam.T_cam_base[:3, :3].copy(), cam.T_cam_base[:3, 3].copy()
        twin_cam = np.array([to_camera(R, t, p) for p in pts_base])
        np.testing.assert_allclose(twin_cam, pts, atol=1e-12)
        twin_px = np.array([project_point(cam.K, cam.dist5, *p) for p in pts])
        if not skew:
            rvec, _ = cv2.Rodrigues(cam.T_cam_base[:3, :3])
            expected, _ = cv2.projectPoints(pts_base, rvec, cam.T_cam_base[:3, 3], cam.K,
                                            cam.dist5)
            np.testing.assert_allclose(twin_px, expected[:, 0], atol=1e-6)
        np.testing.assert_allclose(twin_px, cam.project(pts_base), rtol=1e-13, atol=1e-9)
        px, status, box = np.empty((len(pts), 2)), np.empty(len(pts), np.int8), np.empty(5)
        count = project_points(pts_base, cam.T_cam_base, cam.K, cam.dist5, cam.width,
                               cam.height, px, status, box)
        np.testing.assert_allclose(px, cam.project(pts_base), rtol=1e-13, atol=1e-9)
        inside = cam.in_image(px)
        assert count == inside.sum() and np.array_equal(status == 0, inside)
        ideal = cam.ideal()
        for p, J in zip(pts, ideal.pinhole_jacobian(pts), strict=True):
            u, v, d = pinhole_jacobian(cam.K, *p)
            np.testing.assert_allclose([u, v], ideal.project_camera(p)[0], rtol=1e-13)
            np.testing.assert_array_equal(np.array(d), J)


def test_scaled_intrinsics_keep_the_field_of_view() -> None:
    rng = np.random.default_rng(4)
    cam = _random_camera(rng, 0, dist=False, skew=0.5)
    np.testing.assert_allclose(cam.scaled_K((cam.width, cam.height)), cam.K, atol=1e-12)
    pts = _points_cam(rng)
    for size in [(384, 288), (1536, 1152), (640, 480)]:
        s = np.array(size) / [cam.width, cam.height]
        small = Camera(cam.scaled_K(size), *size, cam.T_base_cam)
        # the image edges (-0.5 and W - 0.5) map onto each other: u' + 0.5 = (u + 0.5) * s
        np.testing.assert_allclose(small.project_camera(pts) + 0.5,
                                   (cam.project_camera(pts) + 0.5) * s, atol=1e-9)


def test_distortion_maps_send_each_distorted_pixel_to_its_ideal_pixel() -> None:
    rng = np.random.default_rng(5)
    cam = _random_camera(rng, 1)
    assert cam.ideal().distortion_maps() is None
    for size in [None, (384, 288)]:
        w, h = size or (cam.width, cam.height)
        map_u, map_v = cam.distortion_maps(size)
        assert map_u.shape == map_v.shape == (h, w) and map_u.dtype == np.float32
        scaled = Camera(cam.scaled_K((w, h)), w, h, cam.T_base_cam, cam.dist)
        v, u = rng.integers(0, h, 200), rng.integers(0, w, 200)
        ideal_px = np.column_stack([map_u[v, u], map_v[v, u]]).astype(float)
        ray = np.linalg.solve(scaled.K, np.column_stack([ideal_px, np.ones(200)]).T).T
        np.testing.assert_allclose(scaled.project_camera(ray), np.column_stack([u, v]),
                                   atol=2e-3)


def test_intrinsics_from_focal_length_or_lens() -> None:
    T = look_at([0, -2, 1], [0, 0, 0])
    lens = camera_from_lens(768, 576, T, 16.0, 0.0083, name="lens")
    f = 16.0 / 0.0083
    np.testing.assert_array_equal(lens.K, [[f, 0, 383.5], [0, f, 287.5], [0, 0, 1]])
    px = Camera.from_intrinsics(640, 480, T, (800.0, 810.0), principal=(300.0, 250.0),
                                skew=0.2, dist=[0.1, 0, 0, 0])
    np.testing.assert_array_equal(px.K, intrinsics(800.0, 810.0, 300.0, 250.0, 0.2))
    np.testing.assert_array_equal(px.dist5, [0.1, 0, 0, 0, 0])
    np.testing.assert_array_equal(lens.dist5, np.zeros(5))
    centred = Camera.from_intrinsics(640, 480, T, 800.0)
    np.testing.assert_array_equal(centred.K, intrinsics(800.0, 800.0, 319.5, 239.5))
    with pytest.raises(CameraError, match="must be positive"):
        camera_from_lens(640, 480, T, 16.0, 0.0)

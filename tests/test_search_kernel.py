"""The whole-image search's compiled scoring (:mod:`cellsight.tracking._search_kernel`)
against the same sums in NumPy through the camera's own projection
(:meth:`cellsight.camera.Camera.project_camera`), on the built-in cell's cameras (with and
without lens distortion), random part poses and random corners. The reference divides the
float32 distance image in float64, as the kernel does (in float32, a corner at the
tolerance's distance rounds to no match: ``tol`` 1.0000000000000002, ``d`` 1.0).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

import cellsight.tracking._search_kernel as kernel
from cellsight import load_cell
from cellsight.camera import Camera
from cellsight.tracking.search import _distance_image


@pytest.fixture(scope="module")
def cell():
    return load_cell()


def _placed(poses, points, z):
    """(G * F, 3) every feature point with the part at each pose ``(x, y, psi)``."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    px, py, pz = points.T
    X = c[:, None] * px - s[:, None] * py + poses[:, :1]
    Y = s[:, None] * px + c[:, None] * py + poses[:, 1:2]
    return np.stack([X, Y, np.broadcast_to(pz + z, X.shape)], -1).reshape(-1, 3)


def _reference(camera: Camera, poses, points, z, distance, tol, hard):
    """(G,) the scores the NumPy way: every placed point projected, its rounded pixel's
    distance looked up (none behind the camera or outside the image)."""
    uv = camera.project_camera(camera.to_camera(_placed(poses, points, z)))
    h, w = distance.shape
    ok = np.isfinite(uv).all(axis=1)
    u, v = np.full(len(uv), -1), np.full(len(uv), -1)
    u[ok], v[ok] = np.rint(uv[ok, 0]).astype(int), np.rint(uv[ok, 1]).astype(int)
    ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
    match = np.zeros(len(uv))
    match[ok] = np.maximum(0.0, 1.0 - distance[v[ok], u[ok]].astype(np.float64) / tol)
    return (match > 0 if hard else match).reshape(len(poses), -1).sum(axis=1)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), k1=st.sampled_from([0.0, -0.08]),
       tol=st.floats(1.0, 12.0), hard=st.booleans())
@example(seed=0, k1=0.0, tol=1.0000000000000002, hard=True)  # a corner at the tolerance
def test_the_kernel_scores_as_numpy_does(cell, seed, k1, tol, hard):
    rng = np.random.default_rng(seed)
    base = cell.cameras[seed % len(cell.cameras)]
    camera = Camera(base.K, base.width, base.height, base.T_base_cam,
                    dist=None if k1 == 0 else np.array([k1, 0.01, 0.0, 0.0, 0.0]))
    part = cell.workpieces[0]
    points = part.feature_points @ part.T_base_part[:3, :3].T
    centre = part.T_base_part[:2, 3]
    poses = np.column_stack([centre + rng.uniform(-0.4, 0.4, (300, 2)),
                             rng.uniform(-np.pi, np.pi, 300)])
    z = float(part.T_base_part[2, 3])
    poses[0, :2] = centre  # in view: its corners among the random ones give it a score
    corners = np.vstack([rng.uniform([0, 0], [camera.width, camera.height], (400, 2)),
                         camera.project(_placed(poses[:1], points, z))])
    distance = _distance_image(camera, corners)
    R, t = camera.T_cam_base[:3, :3], camera.T_cam_base[:3, 3]
    got = kernel.scores(poses, points, z, R, t, camera.K, camera.dist5, distance, tol, hard)
    np.testing.assert_allclose(got, _reference(camera, poses, points, z, distance, tol, hard),
                               rtol=0, atol=1e-9)
    assert got[0] > 0  # the first pose's corners match it: the test has teeth


def test_the_depths_are_the_camera_s(cell):
    camera, part = cell.cameras[0], cell.workpieces[0]
    points = part.feature_points @ part.T_base_part[:3, :3].T
    poses = np.array([[0.5, 0.0, 0.3], [0.6, -0.1, -1.2]])
    z = float(part.T_base_part[2, 3])
    got = kernel.depths(poses, points, z, camera.T_cam_base[:3, :3],
                        camera.T_cam_base[:3, 3])
    for g, (x, y, psi) in enumerate(poses):
        c, s = np.cos(psi), np.sin(psi)
        world = points @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T + [x, y, z]
        np.testing.assert_allclose(got[g * len(points):(g + 1) * len(points)],
                                   camera.depth(world), atol=1e-12)

"""True visibility of feature points from MuJoCo ray casts (never from the BSP code).

A feature is visible in a camera when it lies in front of the camera, projects inside the
image, and the ray from the optical centre to it meets no geom before it; hits within
``tol`` (m) of the feature along the ray are the feature's own surfaces and do not count.
The default, 2 mm (a little over two pixels' footprint at the part's distance), also lets a
feature resting on a support stay visible when the kinematic world has pressed the part a
fraction of a millimetre into it (a held part follows the gripper, with no contact forces);
it matches the predictor's ``surface_tolerance``.
A hidden feature is attributed to the cell object whose geom the ray hits first
(``'floor'`` for the floor plane), or to ``'outside'`` / ``'behind'``.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from cellsight.camera import Camera

OUTSIDE, BEHIND, VISIBLE = "outside", "behind", ""


@dataclass(frozen=True)
class RayVisibility:
    """Per camera: visible mask (F,) and occluder name per feature."""

    visible: np.ndarray
    occluders: list[str]


def cast_visibility(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    camera: Camera,
    points: np.ndarray,
    geom_names: list[str],
    tol: float = 2e-3,
) -> RayVisibility:
    """Visibility of base-frame ``points`` (F, 3) from ``camera`` by ray casts in ``data``'s
    current (kinematically up-to-date) state. ``geom_names[g]`` names the object of geom g."""
    points = np.asarray(points, dtype=float)
    n = len(points)
    in_cam = camera.to_camera(points)
    front = in_cam[:, 2] > 1e-6
    inside = camera.in_image(camera.project_camera(in_cam)) & front
    vec = points - camera.center
    length = np.linalg.norm(vec, axis=1)
    unit = np.ascontiguousarray(vec / length[:, None])
    geomid = np.full(n, -1, dtype=np.int32)
    dist = np.full(n, -1.0)
    mujoco.mj_multiRay(
        model, data, camera.center, unit.ravel(), None, True, -1, geomid, dist, None, n,
        float(length.max()) + 1.0,
    )
    blocked = (dist >= 0) & (dist < length - tol)
    visible = inside & ~blocked
    state = zip(front.tolist(), inside.tolist(), blocked.tolist(), geomid.tolist(), strict=True)
    occluders = [
        BEHIND if not f else OUTSIDE if not i else geom_names[g] if b else VISIBLE
        for f, i, b, g in state
    ]
    return RayVisibility(visible, occluders)

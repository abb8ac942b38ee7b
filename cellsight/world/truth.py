"""True visibility of feature points from MuJoCo ray casts (never from the BSP code).

A feature is visible in a camera when it lies in front of the camera, projects inside the
image, and the ray from the optical centre to it meets no geom before it; hits within
``tol`` (m) of the feature along the ray are the feature's own surfaces and do not count.
The default, 2 mm (a little over two pixels' footprint at the part's distance), also lets a
feature resting on a support stay visible when the kinematic world has pressed the part a
fraction of a millimetre into it (a held part follows the gripper, with no contact forces);
it matches the predictor's ``surface_tolerance``.

The answer has the predictors' type, :class:`~cellsight.visibility.CameraVisibility`: a hidden
feature's ``occluder`` indexes the cell object whose geom the ray hits first, in
``object_labels`` = the labels of ``cell.objects`` followed by the world's own geoms (the
``floor``); ``status`` says whether it is behind the camera or outside the image; ``reason``
names it as the predictors do (``self``, ``R7AX.gripper``, ``table``, ``floor``, ``behind``,
``outside``).
"""

from __future__ import annotations

from collections.abc import Mapping

import mujoco
import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.transforms import transform_points
from cellsight.model import Cell
from cellsight.visibility import (
    STATUS_BEHIND,
    STATUS_INSIDE,
    STATUS_OUTSIDE,
    CameraVisibility,
    Views,
)
from cellsight.world.intruders import Intruders
from cellsight.world.mjcf import object_bodies
from cellsight.world.scene import Scene

SURFACE_TOL = 2e-3  # m, see the module docstring


def cast_visibility(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    camera: Camera,
    points: np.ndarray,
    geom_object: np.ndarray,
    object_labels: list[str],
    part_object: int,
    tol: float = SURFACE_TOL,
) -> CameraVisibility:
    """Visibility of base-frame ``points`` (F, 3) of one workpiece from ``camera`` by ray casts
    in ``data``'s current (kinematically up-to-date) state. ``geom_object[g]``: index into
    ``object_labels`` of the object of geom g; ``part_object``: the workpiece's own index."""
    points = np.asarray(points, dtype=float)
    n = len(points)
    in_cam = camera.to_camera(points)
    front = in_cam[:, 2] > 1e-6
    pixels = camera.project_camera(in_cam)
    inside = camera.in_image(pixels) & front
    vec = points - camera.center
    length = np.linalg.norm(vec, axis=1)
    unit = np.ascontiguousarray(vec / length[:, None])
    geomid = np.full(n, -1, dtype=np.int32)
    dist = np.full(n, -1.0)
    mujoco.mj_multiRay(
        model, data, camera.center, unit.ravel(), None, True, -1, geomid, dist, None, n,
        float(length.max()) + 1.0,
    )
    blocked = inside & (dist >= 0) & (dist < length - tol)
    status = np.where(~front, STATUS_BEHIND, np.where(inside, STATUS_INSIDE, STATUS_OUTSIDE))
    occluder = np.where(blocked, geom_object[np.maximum(geomid, 0)], -1).astype(np.int32)
    return CameraVisibility(camera.name, inside & ~blocked, pixels, occluder,
                            status.astype(np.int8), object_labels, part_object)


class RayTruth:
    """The simulator's truth about what the cameras see and where the cell objects are."""

    def __init__(self, scene: Scene, cell: Cell) -> None:
        self.scene = scene
        self.cell = cell
        model = scene.model
        self.object_labels = [o.label for o in cell.objects]
        index = {o.name: i for i, o in enumerate(cell.objects)}  # geoms are named like objects
        geom_object = []
        for g in range(model.ngeom):
            name = model.geom(g).name
            if name not in index:  # the world's own geoms (the floor)
                index[name] = len(self.object_labels)
                self.object_labels.append(name)
            geom_object.append(index[name])
        self.geom_object = np.array(geom_object, dtype=np.int32)
        self._part_object = {p.name: cell.object_index(p.name) for p in cell.workpieces}
        self._object_body = np.array([model.body(b).id for b in object_bodies(cell)])
        self._vertices = [o.solid.vertices for o in cell.objects]

    def views(self, part_poses: Mapping[str, np.ndarray]) -> Views:
        """Workpiece -> one :class:`CameraVisibility` per camera (``cell.cameras`` order), for
        the workpieces at ``part_poses`` (``T_base_part``, the poses MuJoCo holds now)."""
        self.scene.sync()
        out: Views = {}
        for name, T in part_poses.items():
            points = self.cell.workpiece(name).feature_points @ T[:3, :3].T + T[:3, 3]
            out[name] = [
                cast_visibility(self.scene.model, self.scene.data, cam, points,
                                self.geom_object, self.object_labels, self._part_object[name])
                for cam in self.cell.cameras
            ]
        return out

    def object_poses(self) -> np.ndarray:
        """``T_base_obj`` of every cell object (``cell.objects`` order), (n, 4, 4), read from
        MuJoCo."""
        return self.scene.body_poses(self._object_body)

    def corner_pixels(self, intruders: Intruders) -> list[np.ndarray]:
        """Per camera, the distorted pixels (N, 2) of the vertices of every cell object and
        intruder that lie in front of it, at their poses now (whether each vertex is itself
        hidden is not checked)."""
        poses = list(self.object_poses()) + [self.scene.body_pose(b) for b in intruders.bodies]
        solids = self._vertices + [i.solid.vertices for i in intruders.intruders]
        points = np.concatenate([transform_points(T, v) for T, v in zip(poses, solids,
                                                                         strict=True)])
        out = []
        for cam in self.cell.cameras:
            in_cam = cam.to_camera(points)
            out.append(cam.project_camera(in_cam[in_cam[:, 2] > 1e-6]))
        return out

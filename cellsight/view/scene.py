"""The cell as a viser scene (:class:`CellScene`).

Nodes (base frame = viser's world frame, z up, metres):

- ``/cell/<object>``: one mesh per cell object (``cell.objects``: robot links, gripper palms and
  jaws, workpieces, static objects), its polyhedron triangulated in the object's frame and the
  node posed at ``T_base_obj`` of the shown state (:meth:`~cellsight.model.cell.Cell.snapshot`);
- ``/estimate/<workpiece>``: a translucent magenta copy of a workpiece at the tracker's estimate,
  hidden while there is none;
- ``/cameras/<camera>``: one frustum per camera at ``T_base_cam`` (OpenCV axes, as viser's
  frustums: z forward along the optical axis, x right, y down), its vertical field of view and
  aspect from the intrinsics (``2 atan(H / 2 fy)``; ``(W / fx) / (H / fy)``), showing the
  camera's image;
- ``/features/<workpiece>``: the feature points (base frame, on the true part) coloured by what
  the chosen camera sees: green visible, red hidden (grey: not known, a workpiece a run did
  not log).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np
import viser
import viser.transforms as vtf

from cellsight.camera import Camera
from cellsight.geometry.transforms import transform_points
from cellsight.model.cell import Cell, CellObject
from cellsight.report.overlay import OCCLUDED, VISIBLE
from cellsight.view.states import FrameState

ROBOT_COLOURS = ((235, 140, 50), (110, 165, 215), (120, 185, 95), (200, 95, 95), (160, 125, 205))
KIND_COLOURS = {"tool": (75, 75, 85), "workpiece": (250, 215, 60), "static": (185, 185, 190)}
ESTIMATE_COLOUR, ESTIMATE_OPACITY = (230, 60, 200), 0.45
FRUSTUM_COLOUR = (30, 30, 30)
UNKNOWN_COLOUR = (150, 150, 150)  # features of a workpiece the shown state says nothing about
FRUSTUM_SCALE = 0.12  # size of a frustum in the scene (viser's units, m)
FEATURE_SIZE = 0.016  # m, diameter of a feature point
FRUSTUM_IMAGE_WIDTH = 384  # px, images shown in the frustums are scaled to this width


def node_name(prefix: str, name: str) -> str:
    """A scene node's name: ``/prefix/name`` (``/`` in ``name`` would make a child node)."""
    return f"/{prefix}/{name.replace('/', '_')}"


def pose_args(T: np.ndarray) -> dict[str, np.ndarray]:
    """viser's ``wxyz`` and ``position`` of a rigid transform (4, 4)."""
    return {"wxyz": vtf.SO3.from_matrix(T[:3, :3]).wxyz, "position": np.asarray(T[:3, 3])}


def place(handle, T: np.ndarray) -> None:
    """Pose a scene node at ``T`` (4, 4) in its parent's frame."""
    args = pose_args(T)
    handle.wxyz, handle.position = args["wxyz"], args["position"]


def camera_fov(camera: Camera) -> tuple[float, float]:
    """A camera's vertical field of view (rad) and aspect (image-plane width over height)."""
    fx, fy = camera.K[0, 0], camera.K[1, 1]
    fov = 2.0 * math.atan2(camera.height / 2.0, fy)
    return fov, (camera.width / fx) / (camera.height / fy)


def feature_colours(visible: np.ndarray | None, n: int) -> np.ndarray:
    """(n, 3) uint8: green where ``visible``, red where not; all grey when it is None."""
    if visible is None:
        return np.tile(np.array(UNKNOWN_COLOUR, np.uint8), (n, 1))
    return np.where(np.asarray(visible, dtype=bool)[:, None], np.array(VISIBLE, np.uint8),
                    np.array(OCCLUDED, np.uint8)).astype(np.uint8)


def object_colour(cell: Cell, obj: CellObject) -> tuple[int, int, int]:
    if obj.kind == "link":
        k = [r.name for r in cell.robots].index(obj.robot)
        return ROBOT_COLOURS[k % len(ROBOT_COLOURS)]
    return KIND_COLOURS[obj.kind]


class CellScene:
    """The scene nodes of a cell (module docstring) and their update to a :class:`FrameState`.
    ``meshes``, ``estimates``, ``frustums``, ``features``: the viser handles, by object,
    workpiece, camera index and workpiece."""

    def __init__(self, server: viser.ViserServer, cell: Cell) -> None:
        self.server, self.cell = server, cell
        scene = server.scene
        self.meshes = {
            obj.name: scene.add_mesh_simple(
                node_name("cell", obj.name), obj.solid.vertices, obj.solid.triangles(),
                color=object_colour(cell, obj), flat_shading=True, side="double")
            for obj in cell.objects}
        self.estimates = {
            part.name: scene.add_mesh_simple(
                node_name("estimate", part.name), part.solid.vertices, part.solid.triangles(),
                color=ESTIMATE_COLOUR, opacity=ESTIMATE_OPACITY, flat_shading=True,
                visible=False)
            for part in cell.workpieces}
        self.frustums = []
        for cam in cell.cameras:
            fov, aspect = camera_fov(cam)
            self.frustums.append(scene.add_camera_frustum(
                node_name("cameras", cam.name), fov, aspect, scale=FRUSTUM_SCALE,
                thickness=0.004, color=FRUSTUM_COLOUR, **pose_args(cam.T_base_cam)))
            scene.add_label(node_name("cameras", cam.name) + "/label", cam.name,
                            position=(0.0, 0.0, -0.03))
        self.features = {
            part.name: scene.add_point_cloud(
                node_name("features", part.name), transform_points(
                    part.T_base_part, part.feature_points),
                colors=feature_colours(None, len(part.feature_points)),
                point_size=FEATURE_SIZE, point_shape="circle", precision="float32")
            for part in cell.workpieces}

    def show(self, state: FrameState, camera: int = 0, truth: bool = False) -> None:
        """Pose every object at ``state`` (joints and openings checked as the cell's
        snapshot checks them), the estimates, and the features as camera ``camera`` sees them
        (predicted, or by the ray casts when ``truth`` and the state has them)."""
        snapshot = self.cell.snapshot(state.joints, state.part_poses, state.openings)
        with self.server.atomic():
            for obj, T in zip(self.cell.objects, snapshot.poses, strict=True):
                place(self.meshes[obj.name], T)
            for name, handle in self.estimates.items():
                T = state.estimates.get(name)
                if T is not None:
                    place(handle, T)
                handle.visible = T is not None
            self.colour_features(state, camera, truth, snapshot.part_poses)

    def colour_features(self, state: FrameState, camera: int, truth: bool,
                        part_poses: dict[str, np.ndarray] | None = None) -> None:
        """Feature points on their true part, coloured as camera ``camera`` sees them; grey
        for a workpiece without a :class:`FeatureState` in ``state`` (a run logs one)."""
        poses = part_poses or state.part_poses
        for name, handle in self.features.items():
            part = self.cell.workpiece(name)
            if name in poses:
                handle.points = transform_points(poses[name], part.feature_points).astype(
                    np.float32)
            feats = state.features.get(name)
            mask = None if feats is None else feats.colour_mask(camera, truth)
            handle.colors = feature_colours(mask, len(part.feature_points))

    def set_images(self, images: Sequence[np.ndarray]) -> None:
        """Show each camera's (RGB) image in its frustum, scaled down."""
        for handle, image in zip(self.frustums, images, strict=True):
            h, w = image.shape[:2]
            size = (FRUSTUM_IMAGE_WIDTH, max(1, round(h * FRUSTUM_IMAGE_WIDTH / w)))
            handle.image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)

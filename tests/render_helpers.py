"""Test-only scaffolding for the tracking tests: MuJoCo rendering of a workpiece, ray-cast
visibility, a simple visibility predictor, a synthetic feature source and a known trajectory.

MuJoCo camera from an OpenCV camera (``Camera``: x right, y down, z forward; K; T_base_cam):

* position: the optical centre ``T_base_cam[:3, 3]``;
* orientation: MuJoCo's camera looks along its -z with y up, so its axes in the base frame are
  ``x_mj = x_cv``, ``y_mj = -y_cv``, ``z_mj = -z_cv``, given as ``xyaxes = (x_cv, -y_cv)``;
* intrinsics: ``focalpixel = (fx, fy)``, ``resolution = (W, H)`` and
  ``principalpixel = ((W - 1) / 2 - cx, (H - 1) / 2 - cy)``: MuJoCo's image centre sits at
  OpenCV pixel ``((W - 1) / 2, (H - 1) / 2)`` (OpenCV puts pixel centres at integers) and a
  positive ``principalpixel`` moves the principal point left and up. ``sensorsize`` must be
  non-zero for these to take effect; its value does not matter. Distortion is not modelled.
* the framebuffer must be at least W x H (``<visual><global offwidth offheight>``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen, before mujoco is imported

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from cellsight.camera import Camera  # noqa: E402
from cellsight.geometry.transforms import pose_from_xyz_rpy  # noqa: E402
from cellsight.visibility import STATUS_INSIDE, STATUS_OUTSIDE, CameraVisibility  # noqa: E402

VISION_PERIOD = 1.0 / 26.0


def _num(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in np.ravel(values))


def camera_mjcf(camera: Camera, name: str) -> str:
    """A MuJoCo ``<camera>`` reproducing an OpenCV camera without distortion."""
    if camera.dist is not None:
        raise ValueError("render_helpers: distortion is not rendered")
    R = camera.T_base_cam[:3, :3]
    K, W, H = camera.K, camera.width, camera.height
    return (
        f'<camera name="{name}" pos="{_num(camera.center)}" '
        f'xyaxes="{_num(np.concatenate([R[:, 0], -R[:, 1]]))}" '
        f'focalpixel="{_num([K[0, 0], K[1, 1]])}" resolution="{W} {H}" '
        f'sensorsize="{_num([W * 1e-5, H * 1e-5])}" '
        f'principalpixel="{_num([(W - 1) / 2 - K[0, 2], (H - 1) / 2 - K[1, 2]])}"/>'
    )


def _flat_mesh(solid) -> tuple[np.ndarray, np.ndarray]:
    """Vertices repeated per face (flat shading) and the triangles indexing them."""
    verts, tris = [], []
    for k, face in enumerate(solid.faces):
        base = sum(len(f) for f in solid.faces[:k])
        verts.append(solid.vertices[list(face)])
        tris.append(solid.face_triangles(k) + base)
    return np.concatenate(verts), np.concatenate(tris)


class PartRenderer:
    """Offscreen MuJoCo renders of one polyhedral workpiece (mocap body) over a dark floor
    ``floor_z`` (m), lit by three directional lights (from above, from +x, from -y) so that its
    faces contrast; grayscale."""

    def __init__(self, cameras: list[Camera], solid, floor_z: float = 0.58) -> None:
        self.cameras = cameras
        self.solid = solid
        verts, tris = _flat_mesh(solid)
        W = max(c.width for c in cameras)
        H = max(c.height for c in cameras)
        cams = "\n".join(camera_mjcf(c, f"cam{i}") for i, c in enumerate(cameras))
        xml = f"""<mujoco>
  <visual><global offwidth="{W}" offheight="{H}"/><quality offsamples="8"/>
    <headlight ambient="0.2 0.2 0.2" diffuse="0 0 0" specular="0 0 0"/></visual>
  <asset>
    <mesh name="part" vertex="{_num(verts)}" face="{_num(tris)}"/>
    <material name="part" rgba="0.85 0.85 0.85 1" specular="0" shininess="0" reflectance="0"/>
    <material name="floor" rgba="0.1 0.1 0.1 1" specular="0" shininess="0" reflectance="0"/>
  </asset>
  <worldbody>
    <light directional="true" dir="0 0 -1" diffuse="0.45 0.45 0.45" specular="0 0 0"
           castshadow="false"/>
    <light directional="true" dir="-1 0.3 0" diffuse="0.3 0.3 0.3" specular="0 0 0"
           castshadow="false"/>
    <light directional="true" dir="0 1 0" diffuse="0.15 0.15 0.15" specular="0 0 0"
           castshadow="false"/>
    <geom type="plane" size="5 5 0.1" pos="0 0 {floor_z}" material="floor"/>
    <body name="part" mocap="true">
      <geom type="mesh" mesh="part" material="part" contype="0" conaffinity="0"/>
    </body>
    {cams}
  </worldbody>
</mujoco>"""
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        self.renderers = {}

    def _pose(self, T_base_part: np.ndarray) -> None:
        self.data.mocap_pos[0] = T_base_part[:3, 3]
        q = Rotation.from_matrix(T_base_part[:3, :3]).as_quat()  # x, y, z, w
        self.data.mocap_quat[0] = [q[3], q[0], q[1], q[2]]
        mujoco.mj_forward(self.model, self.data)

    def render(self, camera_index: int, T_base_part: np.ndarray) -> np.ndarray:
        """Grayscale uint8 image (H, W) of the part at ``T_base_part`` from one camera."""
        cam = self.cameras[camera_index]
        key = (cam.height, cam.width)
        if key not in self.renderers:
            self.renderers[key] = mujoco.Renderer(self.model, cam.height, cam.width)
        self._pose(T_base_part)
        r = self.renderers[key]
        r.update_scene(self.data, camera=f"cam{camera_index}")
        rgb = r.render().astype(np.float64)
        return np.round(rgb @ [0.299, 0.587, 0.114]).astype(np.uint8)

    def visible(self, camera_index: int, T_base_part: np.ndarray) -> np.ndarray:
        """Truth visibility (F,) of the feature points: a MuJoCo ray from the optical centre
        reaches the point (no hit more than 1 mm before it), and it projects in the image."""
        cam = self.cameras[camera_index]
        self._pose(T_base_part)
        pts = self.solid.feature_points @ T_base_part[:3, :3].T + T_base_part[:3, 3]
        out = np.zeros(len(pts), dtype=bool)
        geomid = np.zeros(1, dtype=np.int32)
        for i, p in enumerate(pts):
            d = p - cam.center
            dist = np.linalg.norm(d)
            hit = mujoco.mj_ray(self.model, self.data, cam.center, d / dist, None, 1, -1, geomid)
            out[i] = hit < 0 or hit >= dist - 1e-3
        return out & cam.sees(pts, margin=8.0)

    def close(self) -> None:
        for r in self.renderers.values():
            r.close()
        self.renderers.clear()


class BackfacePredictor:
    """TEST-ONLY occlusion predictor: a feature is visible when it projects in the image and one
    of the faces through it faces the camera (back-face culling of the part alone; no mutual
    occlusion, exact only for convex parts). Cameras listed in ``blind`` see nothing (stands for
    a predicted mutual occlusion)."""

    def __init__(self, cameras: list[Camera], name: str, solid) -> None:
        self.cameras = cameras
        self.name = name
        self.solid = solid
        self.blind: set[int] = set()
        self.near: set[tuple[int, int]] = set()  # (camera, feature) flagged near an occluder
        F = len(solid.feature_points)
        self.faces_of = [
            [k for k, face in enumerate(solid.faces) if v in face] for v in solid.feature_vertices
        ]
        assert len(self.faces_of) == F

    def visibility(self, camera_index: int, T_base_part: np.ndarray) -> CameraVisibility:
        cam = self.cameras[camera_index]
        R, o = T_base_part[:3, :3], T_base_part[:3, 3]
        pts = self.solid.feature_points @ R.T + o
        normals = self.solid.normals @ R.T
        pixels = cam.project(pts)
        visible = cam.sees(pts, margin=8.0)
        for j, faces in enumerate(self.faces_of):
            visible[j] &= any(normals[k] @ (cam.center - pts[j]) > 1e-9 for k in faces)
        if camera_index in self.blind:
            visible[:] = False
        near = np.zeros(len(visible), dtype=bool)
        near[[j for c, j in self.near if c == camera_index]] = True
        inside = cam.sees(pts)
        status = np.where(inside, STATUS_INSIDE, STATUS_OUTSIDE).astype(np.int8)
        occluder = np.where(visible | ~inside, -1, 0).astype(np.int32)  # hidden: by itself
        return CameraVisibility(cam.name, visible, pixels, occluder, status, [self.name], 0,
                                near & visible)

    def predict(self, joints, part_poses, openings=None):
        return {
            name: [self.visibility(c, T) for c in range(len(self.cameras))]
            for name, T in part_poses.items()
            if name == self.name
        }


@dataclass
class SyntheticView:
    """Stands for one camera's image in the synthetic tests: the true projections (F, 2) and
    the true visibility (F,) of the part's features."""

    pixels: np.ndarray
    visible: np.ndarray


class SyntheticExtractor:
    """TEST-ONLY extractor: a feature is measured (true projection + N(0, sigma^2) px noise)
    when it is truly visible and its true projection lies in its window; ``outliers`` maps a
    feature index to a pixel offset added to its measurement (a wrong corner)."""

    def __init__(self, sigma_px: float = 0.5, seed: int = 0) -> None:
        self.sigma = sigma_px
        self.rng = np.random.default_rng(seed)
        self.outliers: dict[int, np.ndarray] = {}

    def extract(self, camera_index: int, view: SyntheticView | None, plan) -> dict:
        out = {}
        if view is None:
            return out
        for f, box in zip(plan.features, plan.boxes, strict=True):
            u, v = view.pixels[f]
            inside = box[0] <= u < box[2] and box[1] <= v < box[3]
            if view.visible[f] and inside:
                noise = self.rng.normal(0.0, self.sigma, 2)
                out[int(f)] = view.pixels[f] + noise + self.outliers.get(int(f), 0.0)
        return out


def conveyor_pose(t: float, T0: np.ndarray, sway: float = 1.0) -> np.ndarray:
    """Known workpiece trajectory: ``T0`` carried along +x at 0.06 m/s (from 5 cm before it),
    swaying ``sway`` x (+-2 cm in y at 0.3 Hz, +-0.15 rad in yaw at 0.2 Hz, +-0.03 rad in roll
    at 0.25 Hz); ``sway=0`` is a constant-velocity motion with a 0.02 rad/s yaw rate."""
    xyz0 = T0[:3, 3]
    yaw0 = Rotation.from_matrix(T0[:3, :3]).as_euler("xyz")[2]
    xyz = xyz0 + [0.06 * t - 0.05, sway * 0.02 * np.sin(2 * np.pi * 0.3 * t), 0.0]
    rpy = [
        sway * 0.03 * np.sin(2 * np.pi * 0.25 * t),
        0.0,
        yaw0 + 0.15 * sway * np.sin(2 * np.pi * 0.2 * t) + (1.0 - sway) * 0.02 * t,
    ]
    return pose_from_xyz_rpy(xyz, rpy)


def rotation_error(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle (rad) of ``R_a^T R_b``."""
    return float(np.linalg.norm(Rotation.from_matrix(R_a.T @ R_b).as_rotvec()))

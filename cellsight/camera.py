"""Calibrated fixed camera in the OpenCV pinhole convention.

Camera frame: x right, y down, z forward (optical axis). Pixel ``(u, v)`` = (column, row), the
centre of the top-left pixel at (0, 0). ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels;
distortion ``(k1, k2, p1, p2, k3)`` is OpenCV's radial-tangential model. ``T_base_cam`` is the
camera's pose in the cell base frame (maps camera coordinates to base coordinates).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cellsight.errors import CameraError
from cellsight.geometry.transforms import invert_pose, transform_points


@dataclass(frozen=True)
class Camera:
    """A calibrated camera: intrinsics ``K`` (3x3, px), image size (px), pose ``T_base_cam``."""

    K: np.ndarray
    width: int
    height: int
    T_base_cam: np.ndarray
    dist: np.ndarray | None = None
    name: str = "camera"
    T_cam_base: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float)
        T = np.asarray(self.T_base_cam, dtype=float)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise CameraError(f"camera {self.name}: K must be a finite 3x3 matrix, got {K!r}")
        if K[0, 0] <= 0 or K[1, 1] <= 0 or K[2, 2] != 1 or K[1, 0] or K[2, 0] or K[2, 1]:
            raise CameraError(
                f"camera {self.name}: K must be [[fx,s,cx],[0,fy,cy],[0,0,1]] with fx, fy > 0, "
                f"got {K.tolist()}"
            )
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise CameraError(
                f"camera {self.name}: image size must be positive, got {self.width}x{self.height}"
            )
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise CameraError(f"camera {self.name}: T_base_cam must be a finite 4x4 matrix")
        R = T[:3, :3]
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise CameraError(f"camera {self.name}: T_base_cam rotation is not a proper rotation")
        dist = None
        if self.dist is not None:
            dist = np.zeros(5)
            given = np.asarray(self.dist, dtype=float).ravel()
            if given.size not in (4, 5) or not np.all(np.isfinite(given)):
                raise CameraError(
                    f"camera {self.name}: dist must be 4 or 5 finite numbers (k1,k2,p1,p2[,k3]), "
                    f"got {given.tolist()}"
                )
            dist[: given.size] = given
            if not np.any(dist):
                dist = None
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "T_base_cam", T)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "T_cam_base", invert_pose(T))

    @property
    def center(self) -> np.ndarray:
        """Optical centre in the base frame (m)."""
        return self.T_base_cam[:3, 3].copy()

    @property
    def focal_px(self) -> float:
        """Mean focal length in pixels, ``(fx + fy) / 2``."""
        return 0.5 * (self.K[0, 0] + self.K[1, 1])

    def to_camera(self, points_base: np.ndarray) -> np.ndarray:
        """Points from the base frame to the camera frame, shape (N, 3)."""
        return transform_points(self.T_cam_base, np.atleast_2d(points_base))

    def project_camera(self, points_cam: np.ndarray) -> np.ndarray:
        """Project camera-frame points to pixels, (N, 2), with distortion if any.

        Points with z <= 0 get NaN pixels: they are behind the camera.
        """
        p = np.atleast_2d(np.asarray(points_cam, dtype=float))
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.where(z > 0, p[:, 0] / z, np.nan)
            y = np.where(z > 0, p[:, 1] / z, np.nan)
        if self.dist is not None:
            k1, k2, p1, p2, k3 = self.dist
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
            x, y = xd, yd
        K = self.K
        u = K[0, 0] * x + K[0, 1] * y + K[0, 2]
        v = K[1, 1] * y + K[1, 2]
        return np.column_stack([u, v])

    def project(self, points_base: np.ndarray) -> np.ndarray:
        """Project base-frame points to pixels ``(u, v)``, shape (N, 2); NaN behind the camera."""
        return self.project_camera(self.to_camera(points_base))

    def in_front(self, points_base: np.ndarray, min_depth: float = 1e-6) -> np.ndarray:
        """Boolean mask: the point lies in front of the camera (depth > ``min_depth`` m)."""
        return self.to_camera(points_base)[:, 2] > min_depth

    def in_image(self, pixels: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Boolean mask: the pixel lies inside the image, at least ``margin`` px from its border.

        The image spans ``[-0.5, width - 0.5] x [-0.5, height - 0.5]`` (pixel centres at integers).
        """
        px = np.atleast_2d(pixels)
        u, v = px[:, 0], px[:, 1]
        with np.errstate(invalid="ignore"):
            return (
                (u >= -0.5 + margin)
                & (u <= self.width - 0.5 - margin)
                & (v >= -0.5 + margin)
                & (v <= self.height - 0.5 - margin)
            )

    def sees(self, points_base: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Boolean mask: in front of the camera and projecting inside the image."""
        return self.in_front(points_base) & self.in_image(self.project(points_base), margin)

    def depth(self, points_base: np.ndarray) -> np.ndarray:
        """Depth along the optical axis (m) of base-frame points."""
        return self.to_camera(points_base)[:, 2]

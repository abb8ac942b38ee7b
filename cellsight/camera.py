"""Calibrated fixed camera in the OpenCV pinhole convention.

Camera frame: x right, y down, z forward (optical axis). Pixel ``(u, v)`` = (column, row), the
centre of the top-left pixel at (0, 0). ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels;
distortion ``(k1, k2, p1, p2, k3)`` is OpenCV's radial-tangential model. ``T_base_cam`` is the
camera's pose in the cell base frame (maps camera coordinates to base coordinates).

This module is the one home of the camera model: intrinsics (:func:`intrinsics`,
:meth:`Camera.from_intrinsics`, :meth:`Camera.scaled_K`), projection with distortion, the
pinhole projection Jacobian, undistortion of pixels and the renderer's distortion maps. Its
numba twin for compiled kernels is :mod:`cellsight._camera_kernel`; a new lens model changes
these two modules only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from cellsight._camera_kernel import pinhole_jacobians
from cellsight.errors import CameraError
from cellsight.geometry.transforms import invert_pose, transform_points

MAX_IMAGE_PX = 8192  # px: the largest image side; beyond, offscreen framebuffers fail
FOV_DEG = (0.01, 179.0)  # deg: the field of view a pinhole camera may have along each image axis
MIN_DEPTH_M = 1e-6  # m: a point is in front of a camera when its depth exceeds this
UNDISTORT_TOL_PX = 1e-6  # px: convergence of the fixed-point undistortion of the pixel maps
UNDISTORT_MAX_ITER = 200


def intrinsics(fx: float, fy: float, cx: float, cy: float, skew: float = 0.0) -> np.ndarray:
    """Camera matrix ``K = [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]`` (all in px)."""
    return np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _distort(dist: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's radial-tangential distortion of normalised coordinates (x/z, y/z)."""
    k1, k2, p1, p2, k3 = dist
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


def _undistort_normalized(
    dist: np.ndarray, xd: np.ndarray, yd: np.ndarray, fx: float
) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`_distort` by fixed-point iteration, until a step moves no point more
    than ``UNDISTORT_TOL_PX`` pixels of focal length ``fx`` (px)."""
    k1, k2, p1, p2, k3 = dist
    x, y = xd.copy(), yd.copy()
    for _ in range(UNDISTORT_MAX_ITER):
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        x_new = (xd - 2 * p1 * x * y - p2 * (r2 + 2 * x * x)) / radial
        y_new = (yd - p1 * (r2 + 2 * y * y) - 2 * p2 * x * y) / radial
        step = max(np.abs(x_new - x).max(), np.abs(y_new - y).max())
        x, y = x_new, y_new
        if step * fx < UNDISTORT_TOL_PX:
            break
    return x, y


@dataclass(frozen=True)
class Camera:
    """A calibrated camera: intrinsics ``K`` (3x3, px), image size (px), pose ``T_base_cam``,
    distortion ``dist`` (k1, k2, p1, p2, k3) or None.

    ``P`` (3x4, px, or None) is the projection matrix a calibration file gave (ROS
    ``camera_info``'s, of the rectified image), kept only to be written out again; None means
    ``[K | 0]``. cellsight projects with ``K`` and ``dist`` alone.

    Derived at construction: ``T_cam_base`` (the inverse pose), ``dist5`` (the distortion as a
    float64 5-vector, zeros when there is none: the form :mod:`cellsight._camera_kernel`
    takes) and ``focal_px`` (the mean focal length ``(fx + fy) / 2``, px).
    """

    K: np.ndarray
    width: int
    height: int
    T_base_cam: np.ndarray
    dist: np.ndarray | None = None
    name: str = "camera"
    P: np.ndarray | None = None
    T_cam_base: np.ndarray = field(init=False, repr=False)
    dist5: np.ndarray = field(init=False, repr=False)
    focal_px: float = field(init=False, repr=False)

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
        if not (0 < int(self.width) <= MAX_IMAGE_PX and 0 < int(self.height) <= MAX_IMAGE_PX):
            raise CameraError(
                f"camera {self.name}: image size must be 1 to {MAX_IMAGE_PX} px a side (what the "
                f"renderer's framebuffer takes), got {self.width}x{self.height}"
            )
        for axis, focal, side in (("x", K[0, 0], self.width), ("y", K[1, 1], self.height)):
            fov_deg = np.degrees(2.0 * np.arctan2(0.5 * int(side), focal))
            if not FOV_DEG[0] <= fov_deg <= FOV_DEG[1]:
                raise CameraError(
                    f"camera {self.name}: focal length f{axis} = {focal:.6g} px gives a "
                    f"{fov_deg:.6g} deg field of view over {int(side)} px; expected "
                    f"{FOV_DEG[0]:g} to {FOV_DEG[1]:g} deg (check lens_mm and pixel_mm units)"
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
        if self.P is not None:
            P = np.asarray(self.P, dtype=float)
            if P.shape != (3, 4) or not np.all(np.isfinite(P)):
                raise CameraError(f"camera {self.name}: P must be None or a finite 3x4 matrix")
            object.__setattr__(self, "P", P)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "T_base_cam", T)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "T_cam_base", invert_pose(T))
        object.__setattr__(self, "dist5", np.zeros(5) if dist is None else dist)
        object.__setattr__(self, "focal_px", 0.5 * (K[0, 0] + K[1, 1]))

    @classmethod
    def from_intrinsics(cls, width: int, height: int, T_base_cam: np.ndarray,
                        focal_px: float | tuple[float, float], *,
                        principal: tuple[float | None, float | None] | None = None,
                        skew: float = 0.0, dist: np.ndarray | None = None,
                        name: str = "camera") -> Camera:
        """A camera of ``width`` x ``height`` px at ``T_base_cam`` from its focal length in px,
        ``fx`` or ``(fx, fy)``; the principal point ``(cx, cy)`` (px; either None, or the
        whole, defaults to the image centre ``((W - 1) / 2, (H - 1) / 2)``, pixel centres at
        integers)."""
        fx, fy = (focal_px, focal_px) if np.isscalar(focal_px) else focal_px
        cx, cy = principal if principal is not None else (None, None)
        cx = cx if cx is not None else (width - 1) / 2
        cy = cy if cy is not None else (height - 1) / 2
        return cls(intrinsics(fx, fy, cx, cy, skew), width, height, T_base_cam, dist, name)

    def ideal(self) -> Camera:
        """The same camera without lens distortion (the pinhole model of undistorted pixels);
        the camera itself when it has none."""
        return self if self.dist is None else replace(self, dist=None)

    def scaled_K(self, size: tuple[int, int]) -> np.ndarray:
        """The camera matrix for images of ``size`` = (width, height) px showing the same field
        of view (pixel centres at integer coordinates, as in OpenCV)."""
        sx, sy = size[0] / self.width, size[1] / self.height
        K = self.K.copy()
        K[0, :2] *= sx
        K[1, 1] *= sy
        K[0, 2] = (self.K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (self.K[1, 2] + 0.5) * sy - 0.5
        return K

    @property
    def center(self) -> np.ndarray:
        """Optical centre in the base frame (m)."""
        return self.T_base_cam[:3, 3].copy()

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
            x, y = _distort(self.dist, x, y)
        K = self.K
        u = K[0, 0] * x + K[0, 1] * y + K[0, 2]
        v = K[1, 1] * y + K[1, 2]
        return np.column_stack([u, v])

    def pinhole_jacobian(self, points_cam: np.ndarray) -> np.ndarray:
        """Jacobian ``d(u, v)/d(x, y, z)`` (N, 2, 3), px/m, of the ideal pinhole projection
        (no distortion) at camera-frame points (N, 3) with z > 0::

            J = (1/z) [[fx, s, -(fx x + s y)/z], [0, fy, -fy y/z]]    (x = X/z, y = Y/z)
        """
        p = np.ascontiguousarray(np.atleast_2d(points_cam), dtype=np.float64)
        pixels, jac = np.empty((len(p), 2)), np.empty((len(p), 2, 3))
        pinhole_jacobians(self.K, p, pixels, jac)
        return jac

    def undistort(self, pixels: np.ndarray) -> np.ndarray:
        """Measured (distorted) pixels (N, 2) -> ideal pinhole pixels with the same ``K``: the
        inverse of :meth:`project_camera`'s distortion (OpenCV's ``undistortPoints``). A copy
        for a camera without distortion."""
        px = np.asarray(pixels, dtype=float).reshape(-1, 2)
        if self.dist is None or len(px) == 0:
            return px.copy()
        out = cv2.undistortPoints(px.reshape(-1, 1, 2), self.K, self.dist, P=self.K)
        return out.reshape(-1, 2)

    def distortion_maps(
        self, size: tuple[int, int] | None = None
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """``cv2.remap`` maps (float32, (H, W) each) that turn an ideal pinhole image of
        ``size`` = (width, height) px (default: the camera's; intrinsics :meth:`scaled_K`)
        into the camera's distorted image, or None for a camera without distortion.

        Each output pixel is undistorted by fixed-point iteration of the distortion model to
        ``UNDISTORT_TOL_PX``, then mapped through the ideal camera matrix."""
        if self.dist is None:
            return None
        w, h = size if size is not None else (self.width, self.height)
        K = self.scaled_K((w, h))
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        yd = (v - K[1, 2]) / K[1, 1]
        xd = (u - K[0, 2] - K[0, 1] * yd) / K[0, 0]
        x, y = _undistort_normalized(self.dist, xd, yd, K[0, 0])
        map_u = K[0, 0] * x + K[0, 1] * y + K[0, 2]
        map_v = K[1, 1] * y + K[1, 2]
        return map_u.astype(np.float32), map_v.astype(np.float32)

    def project(self, points_base: np.ndarray) -> np.ndarray:
        """Project base-frame points to pixels ``(u, v)``, shape (N, 2); NaN behind the camera."""
        return self.project_camera(self.to_camera(points_base))

    def in_image(self, pixels: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Boolean mask: the pixel lies inside the image, at least ``margin`` px from its border
        (:func:`border_distance`)."""
        return border_distance(self, pixels) >= margin

    def sees(self, points_base: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Boolean mask: in front of the camera (depth > :data:`MIN_DEPTH_M`) and projecting
        inside the image."""
        return (self.depth(points_base) > MIN_DEPTH_M) & self.in_image(self.project(points_base),
                                                                        margin)

    def depth(self, points_base: np.ndarray) -> np.ndarray:
        """Depth along the optical axis (m) of base-frame points."""
        return self.to_camera(points_base)[:, 2]


def seen_by_any(cameras: Sequence[Camera], points_base: np.ndarray) -> np.ndarray:
    """(N,) bool: some camera of ``cameras`` sees each base-frame point (N, 3) (m;
    :meth:`Camera.sees`)."""
    seen = np.zeros(len(points_base), dtype=bool)
    for camera in cameras:
        seen |= camera.sees(points_base)
    return seen


def border_distance(camera: Camera, pixels: np.ndarray) -> np.ndarray:
    """(N,) px: each pixel's distance inside ``camera``'s image border, negative outside, -inf
    for a NaN pixel. The image spans ``[-0.5, width - 0.5] x [-0.5, height - 0.5]`` (pixel
    centres at integers)."""
    px = np.atleast_2d(pixels)
    u, v = px[:, 0], px[:, 1]
    d = np.minimum(np.minimum(u + 0.5, camera.width - 0.5 - u),
                   np.minimum(v + 0.5, camera.height - 0.5 - v))
    return np.where(np.isnan(d), -np.inf, d)


def camera_from_lens(width: int, height: int, T_base_cam: np.ndarray, lens_mm: float,
                     pixel_mm: float, *, dist: np.ndarray | None = None,
                     name: str = "camera") -> Camera:
    """A camera from a lens of focal length ``lens_mm`` on square pixels of pitch
    ``pixel_mm`` (fx = fy = lens / pitch), its principal point at the image centre."""
    if not (lens_mm > 0 and pixel_mm > 0):
        raise CameraError(f"camera {name}: lens_mm and pixel_mm must be positive, got "
                          f"{lens_mm!r} and {pixel_mm!r}")
    return Camera.from_intrinsics(width, height, T_base_cam, lens_mm / pixel_mm, dist=dist,
                                  name=name)

"""A camera's pose refitted to points the cell knows and where they were seen (beyond the
paper; the registration to the gripper).

A calibration's error moves a camera's image of the work area by an amount that changes across
it (a pose error acts by depth, a lens error by the distance from the image's centre): one
pixel offset, right where it was measured, is millimetres off elsewhere (in ``harsh`` cells, a
part set down 40 cm from where the offset was found is 5-11 mm off). Given points in the base
frame (the gripper's corners, from the joint measurements and the arm's model) and the pixels
each camera found them at, :func:`refit_pose` moves the camera's pose, its intrinsics kept,
to the smallest correction that brings them together: a robust least-squares fit (soft L1 loss)
of the reprojection errors, each in units of ``pixel_sd``, with a prior that holds the
correction near none (``position_sd`` along the camera's axes, ``rotation_sd`` about them),
then the same fit, plain least squares, to the points it left within 3 ``pixel_sd`` (the
corners of something else, pixels off, then weigh nothing).
Seen from one place only, a move across the view and a turn look alike there (a caller then
holds what one place cannot show with a tiny sd: :mod:`.registration` holds the position and
the roll); points from several places (the gripper at HOME, at the part's grasp, where it lets
the part go) pin both down, and the prior keeps the smaller of what stays alike. The
intrinsics' own errors end up in the pose as a calibration's do: right in the work area the
points cover.

Units: m, rad, px.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from cellsight.camera import Camera
from cellsight.geometry.transforms import make_pose


@dataclass(frozen=True)
class PoseFit:
    """A refitted camera: ``camera`` (the given one with its pose corrected), the correction
    ``position`` (3,) m and ``rotation`` (3,) rad (a rotation vector), both in the given
    camera's axes (``T_base_cam @ [R(rotation) | position]``), and the ``rms_px`` of the
    reprojection errors after the fit, over the points within 3 ``pixel_sd`` of the fit
    (``inliers`` of them; ``inlier`` (N,) which)."""

    camera: Camera
    position: np.ndarray
    rotation: np.ndarray
    rms_px: float
    inlier: np.ndarray

    @property
    def inliers(self) -> int:
        """How many points are within 3 ``pixel_sd`` of the fit."""
        return int(self.inlier.sum())


def corrected(camera: Camera, correction: np.ndarray) -> Camera:
    """``camera`` moved by ``correction`` (6,): a rotation vector (rad) then a translation (m),
    in the camera's axes."""
    move = make_pose(Rotation.from_rotvec(correction[:3]).as_matrix(), correction[3:])
    return replace(camera, T_base_cam=camera.T_base_cam @ move)


def refit_pose(camera: Camera, points: np.ndarray, pixels: np.ndarray, *,
               pixel_sd: float = 0.5, position_sd: float | Sequence[float] = 0.010,
               rotation_sd: float | Sequence[float] = np.radians(0.5)) -> PoseFit:
    """``camera`` with its pose fitted to ``points`` (N, 3) m, base frame, seen at ``pixels``
    (N, 2) px (module docstring); ``position_sd`` (m) and ``rotation_sd`` (rad), one for all
    three of the camera's axes or one per axis (x, y across the view, z along it)."""
    points = np.asarray(points, dtype=float)
    pixels = np.asarray(pixels, dtype=float)
    prior = np.concatenate([np.broadcast_to(np.asarray(rotation_sd, dtype=float), 3),
                            np.broadcast_to(np.asarray(position_sd, dtype=float), 3)])

    def residuals(x: np.ndarray, keep: np.ndarray) -> np.ndarray:
        gap = corrected(camera, x).project(points[keep]) - pixels[keep]
        return np.concatenate([gap.ravel() / pixel_sd, x / prior])

    every = np.ones(len(points), dtype=bool)
    rough = least_squares(residuals, np.zeros(6), loss="soft_l1", f_scale=3.0, x_scale=prior,
                          args=(every,))
    inlier = _gaps(corrected(camera, rough.x), points, pixels) <= 3.0 * pixel_sd
    x = rough.x
    if inlier.any():
        x = least_squares(residuals, rough.x, x_scale=prior, args=(inlier,)).x
    moved = corrected(camera, x)
    gap = _gaps(moved, points, pixels)
    inlier = gap <= 3.0 * pixel_sd
    rms = float(np.sqrt(np.mean(gap[inlier] ** 2))) if inlier.any() else float("nan")
    return PoseFit(moved, x[3:].copy(), x[:3].copy(), rms, inlier)


def _gaps(camera: Camera, points: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(N,) px: how far ``camera`` projects each point from its pixel."""
    return np.linalg.norm(camera.project(points) - pixels, axis=1)

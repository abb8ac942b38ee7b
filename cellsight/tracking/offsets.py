"""Each camera's calibration error as an image offset the EKF estimates (beyond the paper).

A camera's extrinsic and principal-point errors move the whole image of a part near the work
area by nearly the same few pixels: in the realistic world's ``harsh`` cameras by 2-7 px per
camera, with under 1 px of spread across the part's features. Two cameras whose offsets differ
cannot both fit one pose; with the pixel noise alone in its model, the filter rejects their
good corners as outliers and drifts on what is left. :class:`CameraOffsets` adds two states per
camera, the offset ``b_c`` (px) added to every pixel it predicts in camera ``c``, with a prior
of ``sigma_px`` per axis and a random walk of ``walk_px`` px per square-root second (none by
default; a camera slowly moving, warming up). The part's pose and the offsets share the pixels:
what the cameras agree on goes into the pose, what only one camera sees into its offset, and
the part of the calibration error common to all cameras stays in the pose, within the prior.
How the filter gates with them: :meth:`cellsight.tracking.ekf.PoseEKF.update`.

The offsets belong to the cameras, not to one track: a filter started again (re-acquisition)
keeps the earlier filter's offsets and their covariance, and a first filter starts from the
acquisition's per-camera shifts (:meth:`cellsight.tracking.tracker.Tracker.initialise`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CameraOffsets:
    """Prior (``sigma_px``, px per axis) and random walk (``walk_px``, px/sqrt(s)) of each of
    ``n_cameras`` cameras' image offsets."""

    n_cameras: int
    sigma_px: float
    walk_px: float = 0.0

    def __post_init__(self) -> None:
        if self.n_cameras < 1 or not self.sigma_px > 0 or not self.walk_px >= 0:
            raise ValueError(f"CameraOffsets: n_cameras >= 1, sigma_px > 0 and walk_px >= 0, got "
                             f"{self.n_cameras}, {self.sigma_px}, {self.walk_px}")

    @property
    def dim(self) -> int:
        """Number of states the offsets add: two per camera."""
        return 2 * self.n_cameras

    @property
    def gauge(self) -> np.ndarray:
        """(dim x dim) projector onto offsets that sum to zero over the cameras (per axis):
        a shift common to every camera moves the part's image as its translation does, so the
        pose carries it and the offsets keep only how the cameras disagree. Without it the
        filter, confident in a direction the pixels do not fix, let the common shift and the
        pose drift together (25 px and 20 mm in a 48 s run with ``harsh``'s cameras)."""
        C = self.n_cameras
        return np.kron(np.eye(C) - np.full((C, C), 1.0 / C), np.eye(2))

    def prior(self) -> tuple[np.ndarray, np.ndarray]:
        """Zero offsets (dim,) and their prior covariance (dim x dim, px^2): ``sigma_px`` per
        axis, within the gauge (:attr:`gauge`)."""
        return np.zeros(self.dim), self.gauge * self.sigma_px**2

    def walk(self, dt: float) -> np.ndarray:
        """Covariance (dim x dim, px^2) the offsets gain over ``dt`` seconds, within the
        gauge."""
        return self.gauge * (self.walk_px**2 * dt)

    def in_gauge(self, offsets: np.ndarray) -> np.ndarray:
        """``offsets`` (dim,) less their mean over the cameras (per axis)."""
        return self.gauge @ np.asarray(offsets, dtype=float)


def with_offset(pred: np.ndarray, H: np.ndarray, camera_index: int, offsets: np.ndarray,
                first: int, total: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``pred`` (n, 2) of camera ``camera_index`` moved by its offset, and the Jacobian
    ``H`` (2n, k) widened to ``total`` states with ones in that camera's two offset columns
    (the offsets start at state ``first``)."""
    n = len(pred)
    out = np.zeros((2 * n, total))
    out[:, :H.shape[1]] = H
    col = first + 2 * camera_index
    out[0::2, col] = 1.0
    out[1::2, col + 1] = 1.0
    return pred + offsets[2 * camera_index:2 * camera_index + 2], out

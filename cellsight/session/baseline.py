"""The per-frame PnP baseline the EKF is compared with (``pnp_*`` columns of ``frames.csv``).

Each frame, a fused multi-camera PnP (:func:`~cellsight.tracking.pnp.estimate_pose`) on the
tracker's measurements of that frame alone, with the same pinhole measurement model and pixel
noise as the tracker. A frame with too few measurements holds the last fix, for at most
``hold_s`` seconds (the tracker's ``lost_after_s``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cellsight.camera import Camera
from cellsight.tracking.measurement import Observation, PinholeMeasurement
from cellsight.tracking.pnp import estimate_pose
from cellsight.tracking.tracker import Tracker


class PnPBaseline:
    """The baseline of the module docstring for one workpiece. ``feature_points`` (F, 3) in
    the part frame (m); ``sigma_px``: pixel noise (px); ``hold_s``: how long a fix is held (s)."""

    def __init__(self, cameras: Sequence[Camera], feature_points: np.ndarray, sigma_px: float,
                 hold_s: float) -> None:
        self.cameras = list(cameras)
        self.points = np.asarray(feature_points, dtype=float)
        self.sigma_px = float(sigma_px)
        self.hold_s = float(hold_s)
        self._models = [PinholeMeasurement(cam, self.sigma_px) for cam in self.cameras]
        self._last: tuple[float, np.ndarray] | None = None  # (t, T_base_part) of the last fix

    @classmethod
    def of(cls, tracker: Tracker, feature_points: np.ndarray) -> PnPBaseline:
        """The baseline beside ``tracker``: its cameras, pixel noise and loss time."""
        return cls(tracker.cameras, feature_points, tracker.config.sigma_px,
                   tracker.components.loss.lost_after_s)

    def update(self, t: float, measured: np.ndarray) -> np.ndarray | None:
        """``T_base_part`` at time ``t`` (s) from this frame's measured pixels (C, F, 2), as in
        the image (distorted), NaN where none; None when there is no fix to give."""
        observations = []
        for c, cam in enumerate(self.cameras):
            ids = np.flatnonzero(np.all(np.isfinite(measured[c]), axis=1))
            if len(ids):
                observations.append(Observation(self._models[c], c, ids, self.points[ids],
                                                cam.undistort(measured[c, ids])))
        fix = estimate_pose(observations, sigma_px=self.sigma_px) if observations else None
        if fix is not None:
            self._last = (t, fix.T_base_part)
        if self._last is None or t - self._last[0] > self.hold_s:
            return None
        return self._last[1]

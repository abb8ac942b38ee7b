"""Acquisition of a workpiece not tracked yet, or lost (beyond the paper's Fig. 5).

The occlusion predictor runs at a guess of the pose (the cell's nominal pose of the part, or
the last prediction of a lost part); every usable predicted-visible feature gets a square
window of ``window_px``; the corners found there give a fused multi-camera PnP that drops up to
three wrong corners (:func:`~cellsight.tracking.pnp.estimate_pose_robust`: while the RMS
reprojection error exceeds ``max_rms_px`` or a corner lies more than ``max_residual_px`` from
its reprojection). The filter starts from it when its RMS is at most ``max_rms_px``, with the
PnP covariance inflated by ``pose_inflation`` and a velocity uncertainty ``velocity_std`` (m/s,
rad/s); the corners it dropped are recorded as rejected.

With ``camera_offsets`` (the tracker estimates each camera's calibration error as an image
offset, :mod:`.offsets`), a fix whose RMS is too large is tried once more with each camera's
median residual taken out of its pixels (:func:`~cellsight.tracking.pnp.camera_shifts`): two
cameras that disagree by a few pixels no longer keep a part from being acquired, and the
filter starts from those offsets.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from cellsight.tracking.measurement import Observation
from cellsight.tracking.motion import POSE_DIM, STATE_DIM
from cellsight.tracking.pnp import PoseFix, camera_shifts, estimate_pose_robust


@dataclass(frozen=True)
class PnPAcquisition:
    """Acquisition by robust multi-camera PnP (module docstring). Units: px, m/s, rad/s."""

    window_px: float = 64.0
    max_rms_px: float = 2.0
    max_residual_px: float = 6.0
    velocity_std: tuple[float, float] = (0.2, 0.5)
    pose_inflation: float = 4.0
    search_m: float = 0.015
    search_step_m: float = 0.005
    camera_offsets: bool = False

    def guess(self, base: np.ndarray, attempt: int) -> np.ndarray:
        """``base`` (``T_base_part``) moved by the ``attempt``-th offset of the search (module
        docstring; it starts over after the last)."""
        n = int(round(self.search_m / self.search_step_m)) if self.search_step_m > 0 else 0
        steps = np.arange(-n, n + 1) * self.search_step_m
        offsets = sorted(((x, y) for x in steps for y in steps),
                         key=lambda o: (round(np.hypot(*o), 9), o))
        T = np.array(base, dtype=float)
        T[:2, 3] += offsets[attempt % len(offsets)]
        return T

    def fix(self, observations: list[Observation], sigma_px: float) -> PoseFix | None:
        """The pose to start from, or None when the corners found do not give one."""
        fix = estimate_pose_robust(observations, self.max_rms_px, sigma_px=sigma_px,
                                   max_residual_px=self.max_residual_px)
        if fix is not None and fix.rms_px > self.max_rms_px and self.camera_offsets:
            shifts = camera_shifts(observations, fix)
            moved = [replace(o, pixels=o.pixels - shifts.get(o.camera_index, 0.0))
                     for o in observations]
            fix = estimate_pose_robust(moved, self.max_rms_px, sigma_px=sigma_px,
                                       max_residual_px=self.max_residual_px)
            fix = None if fix is None else replace(fix, offsets_px=shifts)
        return fix if fix is not None and fix.rms_px <= self.max_rms_px else None

    def covariance(self, pose_covariance: np.ndarray) -> np.ndarray:
        """Initial 12x12 state covariance: ``pose_covariance`` (6x6, xyz + rpy) and the
        velocity uncertainty; the caller inflates a PnP covariance first (:meth:`start`)."""
        P = np.zeros((STATE_DIM, STATE_DIM))
        P[:POSE_DIM, :POSE_DIM] = pose_covariance
        lin, ang = self.velocity_std
        P[POSE_DIM:, POSE_DIM:] = np.diag([lin**2] * 3 + [ang**2] * 3)
        return P

    def start(self, fix: PoseFix) -> np.ndarray:
        """Initial state covariance from a PnP fix (its covariance inflated)."""
        return self.covariance(self.pose_inflation * fix.covariance)

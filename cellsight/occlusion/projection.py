"""Visibility without occlusion prediction: the ``--no-occlusion-prediction`` baseline.

Every feature point in front of a camera that projects inside its image counts as visible;
nothing hides anything (no BSP). Same interface as the BSP predictor
(:class:`cellsight.visibility.VisibilitySource`).
"""

from __future__ import annotations

import numpy as np

from cellsight.camera import MIN_DEPTH_M, Camera
from cellsight.model.cell import Cell
from cellsight.visibility import (
    STATUS_BEHIND,
    STATUS_INSIDE,
    STATUS_OUTSIDE,
    CameraVisibility,
    Views,
)


class ProjectionOnly:
    """Visibility source: in front of the camera and inside the image (module docstring)."""

    def __init__(self, cell: Cell) -> None:
        self.cell = cell
        self.cameras = list(cell.cameras)
        self.labels = [o.label for o in cell.objects]

    def recalibrate(self, index: int, camera: Camera) -> None:
        """Project into camera ``index`` with ``camera`` from now on."""
        self.cameras[index] = camera

    def predict(self, joints=None, part_poses=None, openings=None) -> Views:
        """Workpiece name -> one :class:`CameraVisibility` per camera; ``joints`` and
        ``openings`` are ignored (robots hide nothing here); a workpiece without a pose in
        ``part_poses`` is at its nominal pose."""
        out: Views = {}
        for part in self.cell.workpieces:
            T = (part_poses or {}).get(part.name, part.T_base_part)
            points = part.feature_points @ T[:3, :3].T + T[:3, 3]
            out[part.name] = []
            for cam in self.cameras:
                front = cam.depth(points) > MIN_DEPTH_M
                pixels = cam.project(points)
                inside = front & cam.in_image(np.nan_to_num(pixels, nan=-1e9))
                status = np.where(~front, STATUS_BEHIND,
                                  np.where(inside, STATUS_INSIDE, STATUS_OUTSIDE))
                out[part.name].append(CameraVisibility(
                    cam.name, inside, pixels, np.full(len(points), -1, dtype=np.int32),
                    status.astype(np.int8), self.labels, self.cell.object_index(part.name)))
        return out

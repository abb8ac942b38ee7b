"""What the experiment runner plugs into the tracker besides the real parts.

- :class:`FramePredictor`: the visibility source the tracker calls, with this frame's jaw
  openings, keeping its last answer (for the log's occluder labels).
- :class:`ProjectionOnly`: the ``--no-occlusion-prediction`` baseline: every feature point in
  front of a camera that projects inside its image counts as visible (no BSP, no occlusion).
- :class:`IdealExtractor`: the ``--sensor ideal`` extractor: the true projection of a truly
  visible feature whose window contains it, plus Gaussian pixel noise; nothing otherwise.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from cellsight.model.cell import Cell
from cellsight.occlusion.predictor import (
    STATUS_BEHIND,
    STATUS_INSIDE,
    STATUS_OUTSIDE,
    CameraVisibility,
)
from cellsight.tracking.windowing import WindowPlan


class FramePredictor:
    """Wraps a predictor with ``predict(joints, part_poses, openings)``: the runner sets
    ``openings`` (robot -> jaw opening, m) each frame; ``last`` holds the latest answer."""

    def __init__(self, source) -> None:
        self.source = source
        self.openings: Mapping[str, float] | None = None
        self.last: dict[str, list[CameraVisibility]] = {}

    def predict(self, joints, part_poses) -> dict[str, list[CameraVisibility]]:
        self.last = self.source.predict(joints, part_poses, self.openings)
        return self.last


class ProjectionOnly:
    """Visibility without occlusion prediction: in front of the camera and inside the image."""

    def __init__(self, cell: Cell) -> None:
        self.cell = cell
        self.labels = [o.label for o in cell.objects]

    def predict(self, joints=None, part_poses=None, openings=None):
        """Workpiece name -> one :class:`CameraVisibility` per camera (``joints`` and
        ``openings`` are ignored: robots hide nothing here)."""
        out = {}
        for part in self.cell.workpieces:
            T = (part_poses or {}).get(part.name, part.T_base_part)
            points = part.feature_points @ T[:3, :3].T + T[:3, 3]
            out[part.name] = []
            for cam in self.cell.cameras:
                front = cam.in_front(points)
                pixels = cam.project(points)
                inside = front & cam.in_image(np.nan_to_num(pixels, nan=-1e9))
                status = np.where(~front, STATUS_BEHIND,
                                  np.where(inside, STATUS_INSIDE, STATUS_OUTSIDE))
                out[part.name].append(CameraVisibility(
                    cam.name, inside, pixels, np.full(len(points), -1, dtype=np.int32),
                    status.astype(np.int8), self.labels, self.cell.object_index(part.name)))
        return out


class IdealExtractor:
    """Extractor of the ideal sensor (module docstring). ``sigma_px``: noise per coordinate;
    call :meth:`set_truth` with the frame's true pixels and visibility before each step."""

    def __init__(self, sigma_px: float, seed: int) -> None:
        self.sigma_px = float(sigma_px)
        self._rng = np.random.default_rng(seed)
        self._pixels: np.ndarray | None = None
        self._visible: np.ndarray | None = None

    def set_truth(self, pixels: np.ndarray, visible: np.ndarray) -> None:
        """``pixels`` (C, F, 2) true distorted projections, ``visible`` (C, F) true labels."""
        self._pixels, self._visible = pixels, visible

    def extract(self, camera_index: int, image, plan: WindowPlan) -> dict[int, np.ndarray]:
        out: dict[int, np.ndarray] = {}
        for f, box in zip(plan.features, plan.boxes, strict=True):
            if not self._visible[camera_index, f]:
                continue
            px = self._pixels[camera_index, f] + self._rng.normal(0.0, self.sigma_px, 2)
            u0, v0, u1, v1 = box
            if u0 - 0.5 <= px[0] <= u1 - 0.5 and v0 - 0.5 <= px[1] <= v1 - 0.5:
                out[int(f)] = px
        return out

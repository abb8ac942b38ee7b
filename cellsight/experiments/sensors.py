"""The ``--sensor ideal`` extractor the experiment runner plugs into the tracker instead of the
corner extractor: the true projection of a truly visible feature whose window contains it,
plus Gaussian pixel noise; nothing otherwise."""

from __future__ import annotations

import numpy as np

from cellsight.tracking.windowing import WindowPlan


class IdealExtractor:
    """Extractor of the ideal sensor (module docstring). ``sigma_px``: noise per coordinate
    (px); ``seed`` seeds the noise; call :meth:`set_truth` with the frame's true pixels and
    visibility before each step."""

    def __init__(self, sigma_px: float, seed: int) -> None:
        self.sigma_px = float(sigma_px)
        self._rng = np.random.default_rng(seed)
        self._pixels: np.ndarray | None = None
        self._visible: np.ndarray | None = None

    def set_truth(self, pixels: np.ndarray, visible: np.ndarray) -> None:
        """``pixels`` (C, F, 2) true distorted projections, ``visible`` (C, F) true labels."""
        self._pixels, self._visible = pixels, visible

    def extract(self, camera_index: int, image, plan: WindowPlan) -> dict[int, np.ndarray]:
        """Feature index -> measured pixel (2,) for camera ``camera_index``'s windows; the
        image is ignored."""
        out: dict[int, np.ndarray] = {}
        for f, box in zip(plan.features, plan.boxes, strict=True):
            if not self._visible[camera_index, f]:
                continue
            px = self._pixels[camera_index, f] + self._rng.normal(0.0, self.sigma_px, 2)
            u0, v0, u1, v1 = box
            if u0 - 0.5 <= px[0] <= u1 - 0.5 and v0 - 0.5 <= px[1] <= v1 - 0.5:
                out[int(f)] = px
        return out

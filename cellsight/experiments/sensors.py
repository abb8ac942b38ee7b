"""The ``--sensor ideal`` extractor the experiment runner plugs into the tracker instead of the
corner extractor: it measures the *selected* features as a perfect corner extractor would.

For each window the tracker plans:

- a feature the world's truth says is visible, whose true projection (plus Gaussian pixel
  noise) lies in its window, is measured there;
- otherwise (hidden, or outside its window) the extractor finds what a corner extractor would
  find in that window instead: the corner of whatever is there (an occluder, another feature,
  an unknown body; :meth:`~cellsight.experiments.plant.GroundTruth.true_corners`) nearest the
  window's centre, plus the same noise, or nothing when no corner lies in the window. Its own
  hidden vertex (within ``OWN_PX`` of its true projection) is not a candidate.

So a wrong prediction costs what it would cost a real extractor. A dropped frame (no truth set)
measures nothing. Whether a candidate corner is itself hidden is not checked.
"""

from __future__ import annotations

import numpy as np

from cellsight.tracking.windowing import WindowPlan

OWN_PX = 0.5  # px: a corner this close to a hidden feature's projection is that feature


class IdealExtractor:
    """Extractor of the ideal sensor (module docstring). ``sigma_px``: noise per coordinate
    (px); ``seed`` seeds the noise; call :meth:`set_truth` before each step."""

    def __init__(self, sigma_px: float, seed: int) -> None:
        self.sigma_px = float(sigma_px)
        self._rng = np.random.default_rng(seed)
        self._pixels: np.ndarray | None = None
        self._visible: np.ndarray | None = None
        self._corners: list[np.ndarray] = []

    def set_truth(self, pixels: np.ndarray | None, visible: np.ndarray | None,
                  corners: list[np.ndarray] | None = None) -> None:
        """``pixels`` (C, F, 2) true distorted projections, ``visible`` (C, F) true labels,
        ``corners`` per camera (N, 2) pixels of every corner in view; None: the frame was
        dropped."""
        self._pixels, self._visible = pixels, visible
        self._corners = corners if corners is not None else []

    def extract(self, camera_index: int, image, plan: WindowPlan) -> dict[int, np.ndarray]:
        """Feature index -> measured pixel (2,) for camera ``camera_index``'s windows; the
        image is ignored."""
        out: dict[int, np.ndarray] = {}
        if self._pixels is None:
            return out
        for f, box in zip(plan.features, plan.boxes, strict=True):
            true_px = self._pixels[camera_index, f]
            visible = bool(self._visible[camera_index, f])
            if visible:
                px = true_px + self._rng.normal(0.0, self.sigma_px, 2)
                if _inside(px, box):
                    out[int(f)] = px
                    continue
            corner = self._corner_in(camera_index, box, None if visible else true_px)
            if corner is not None:
                out[int(f)] = corner + self._rng.normal(0.0, self.sigma_px, 2)
        return out

    def _corner_in(self, c: int, box, own: np.ndarray | None) -> np.ndarray | None:
        """The corner nearest the centre of ``box`` inside it, not within ``OWN_PX`` of
        ``own``; None when there is none."""
        if c >= len(self._corners):
            return None
        pts = self._corners[c]
        pts = pts[_inside(pts.T, box)]
        if own is not None and np.all(np.isfinite(own)):
            pts = pts[np.linalg.norm(pts - own, axis=1) > OWN_PX]
        if len(pts) == 0:
            return None
        u0, v0, u1, v1 = box
        centre = np.array([(u0 + u1 - 1) / 2, (v0 + v1 - 1) / 2])
        return pts[np.argmin(np.linalg.norm(pts - centre, axis=1))].copy()


def _inside(px: np.ndarray, box) -> np.ndarray | bool:
    """Pixel(s) ``px`` ((2,) or (2, N)) inside the window ``box`` = (u0, v0, u1, v1), pixel
    centres at integers (OpenCV)."""
    u0, v0, u1, v1 = box
    return (u0 - 0.5 <= px[0]) & (px[0] <= u1 - 0.5) & (v0 - 0.5 <= px[1]) & (px[1] <= v1 - 0.5)

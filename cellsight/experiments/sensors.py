"""The ``--sensor ideal`` extractor the experiment runner plugs into the tracker instead of the
corner extractor: it measures the *selected* features as a perfect corner extractor would.

What it measures is its input, like the images of the corner extractor: the run gives
:meth:`Tracker.step <cellsight.tracking.Tracker.step>` one :class:`IdealView` per camera (the
truth as that camera was exposed) instead of an image. For each window the tracker plans:

- a feature the world's truth says is visible, whose true projection (plus Gaussian pixel
  noise) lies in its window, is measured there;
- otherwise (hidden, or outside its window) the extractor finds what a corner extractor would
  find in that window instead: the corner of whatever is there (an occluder, another feature,
  an unknown body; :meth:`~cellsight.experiments.plant.GroundTruth.true_corners`) nearest the
  window's centre, plus the same noise, or nothing when no corner lies in the window. Its own
  hidden vertex (within ``OWN_PX`` of its true projection) is not a candidate.

So a wrong prediction costs what it would cost a real extractor. A dropped frame (no view)
measures nothing. Whether a candidate corner is itself hidden is not checked.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cellsight.tracking.windowing import WindowPlan

OWN_PX = 0.5  # px: a corner this close to a hidden feature's projection is that feature


@dataclass(frozen=True)
class IdealView:
    """What the ideal sensor takes of the tracked workpiece in one camera at one frame:
    ``pixels`` (F, 2) true projections (px, distorted; NaN behind the camera), ``visible`` (F,)
    true labels, ``corners`` (N, 2) px: every corner in view (none by default)."""

    pixels: np.ndarray
    visible: np.ndarray
    corners: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


class IdealExtractor:
    """Extractor of the ideal sensor (module docstring). ``sigma_px``: noise per coordinate
    (px); ``seed`` seeds the noise."""

    def __init__(self, sigma_px: float, seed: int) -> None:
        self.sigma_px = float(sigma_px)
        self._rng = np.random.default_rng(seed)

    def extract(self, camera_index: int, view: IdealView | None,
                plan: WindowPlan) -> dict[int, np.ndarray]:
        """Feature index -> measured pixel (2,) px in the windows of ``plan``, from ``view``,
        camera ``camera_index``'s truth (None: the frame was dropped, nothing is measured)."""
        out: dict[int, np.ndarray] = {}
        if view is None:
            return out
        for f, box in zip(plan.features, plan.boxes, strict=True):
            true_px = view.pixels[f]
            visible = bool(view.visible[f])
            if visible:
                px = true_px + self._rng.normal(0.0, self.sigma_px, 2)
                if _inside(px, box):
                    out[int(f)] = px
                    continue
            corner = _corner_in(view.corners, box, None if visible else true_px)
            if corner is not None:
                out[int(f)] = corner + self._rng.normal(0.0, self.sigma_px, 2)
        return out


    def detect(self, view: IdealView | None) -> np.ndarray:
        """(N, 2) px: every corner in view (:attr:`IdealView.corners`) with the pixel noise,
        as a whole-image corner detector would find them; none for a dropped frame."""
        if view is None:
            return np.zeros((0, 2))
        corners = np.asarray(view.corners, dtype=float).reshape(-1, 2)
        return corners + self._rng.normal(0.0, self.sigma_px, corners.shape)


def _corner_in(corners: np.ndarray, box, own: np.ndarray | None) -> np.ndarray | None:
    """The corner of ``corners`` (N, 2) px nearest the centre of ``box`` inside it, not within
    ``OWN_PX`` of ``own``; None when there is none."""
    pts = np.asarray(corners, dtype=float).reshape(-1, 2)
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

"""The parts a :class:`~cellsight.tracking.Tracker` is wired from, as protocols: any object
with these methods plugs in (the visibility source is
:class:`cellsight.visibility.VisibilitySource`)."""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from cellsight.camera import Camera
from cellsight.tracking.windowing import WindowPlan


class Extractor(Protocol):
    """Finds the features in one camera's image windows: feature index -> pixel (2,) as in
    the image (with distortion)."""

    def extract(self, camera_index: int, image: Any, plan: WindowPlan) -> dict[int, np.ndarray]: ...


class MeasurementModel(Protocol):
    """One camera's model of a part's feature pixels: ``evaluate(state, points_model)`` gives
    the predicted ideal pixels (n, 2) and their Jacobian (2n, 12) w.r.t. the state (layout in
    :mod:`cellsight.tracking.motion`); ``sigma_px`` the pixel noise (px)."""

    camera: Camera
    sigma_px: float

    def evaluate(
        self, state: np.ndarray, points_model: np.ndarray, rotation: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]: ...

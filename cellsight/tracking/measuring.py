"""One part's features measured in one frame (for :mod:`.tracker` and :mod:`.acquire`): which
may be measured (predicted visible, not held back next to an occluder, not under an unknown
occluder), then, for the selected ones, the windows planned around the other parts' features,
the image regions grabbed (every tracked part's at once, one grab a camera), the corners
extracted and the observations built."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from cellsight.camera import Camera
from cellsight.tracking.grabbing import grabbed
from cellsight.tracking.interfaces import (
    CornerDetector,
    Extractor,
    MeasurementModel,
    OccluderMap,
    WindowPlanner,
)
from cellsight.tracking.measurement import Observation
from cellsight.tracking.part_track import StepContext, observed_of
from cellsight.tracking.windowing import WindowPlan


class Measurer:
    """The measurement of a part's features by ``cameras`` (shared with the tracker: a camera
    recalibrated there is measured with here), windows planned by ``windows``, features
    extracted by ``extractor``, observations of the cameras' measurement ``models``; the
    ``unknown``-occluder maps mask what may be measured, and so does the image's edge (within
    ``edge_margin_px``, px). ``detect``: the extractor's whole-image corner detector
    (:class:`~.interfaces.CornerDetector`), None when it has none."""

    def __init__(self, cameras: list[Camera], windows: WindowPlanner, extractor: Extractor,
                 models: list[MeasurementModel], unknown: OccluderMap,
                 edge_margin_px: float) -> None:
        self.cameras, self.windows, self.extractor = cameras, windows, extractor
        self.models, self.unknown = models, unknown
        self.edge_margin_px = float(edge_margin_px)

    @property
    def extractor(self) -> Extractor:
        """What extracts the features (its detector checked once, when it is set)."""
        return self._extractor

    @extractor.setter
    def extractor(self, extractor: Extractor) -> None:
        self._extractor = extractor
        self.detect: Callable[[Any], np.ndarray] | None = (
            extractor.detect if isinstance(extractor, CornerDetector) else None)

    def usable(self, context: StepContext, t_hold: float | None) -> np.ndarray:
        """(C, F) bool: the features that may be measured: predicted visible, at least
        ``edge_margin_px`` inside the image, not held back next to an occluder at time
        ``t_hold`` (s; :mod:`.eligibility`; None, for a pose acquisition tries: not flagged
        next to one at that pose) and not under an unknown occluder (recorded in
        ``rec.unknown``)."""
        rec = context.rec
        inside = np.empty_like(rec.visible)
        for c, cam in enumerate(self.cameras):
            rec.unknown[c] = rec.visible[c] & self.unknown.covered(c, rec.pixels[c], context.t)
            inside[c] = cam.in_image(rec.pixels[c], self.edge_margin_px)
        if t_hold is None:  # the track's hold is of its own predictions, not of a trial pose's
            return rec.visible & inside & ~rec.near_occluder & ~rec.unknown
        held = context.track.hold.usable(rec.visible, rec.near_occluder, t_hold)
        return held & inside & ~rec.unknown

    def measure(self, context: StepContext,
                 covariance: Callable[[int, np.ndarray], np.ndarray],
                 size_px: float | None = None) -> list[Observation]:
        """Plan the windows of the selected features (:meth:`plan`), grab each camera's,
        extract and build the observations (:meth:`extract`)."""
        plans = self.plan(context, covariance, size_px)
        with context.timer("grab"):
            seen = self.grab(context.observed, [plans])
        return self.extract(context, plans, seen)

    def plan(self, context: StepContext, covariance: Callable[[int, np.ndarray], np.ndarray],
             size_px: float | None = None) -> list[WindowPlan | None]:
        """Per camera, the windows of the selected features (None: none selected there;
        ``covariance(c, idx)``: their innovation covariances (n, 2, 2) px^2 in camera ``c``;
        ``size_px``: fixed window size, px), recorded in ``rec.windows``."""
        rec = context.rec
        plans: list[WindowPlan | None] = [None] * len(self.cameras)
        for c, cam in enumerate(self.cameras):
            idx = np.flatnonzero(rec.selected[c])
            if len(idx) == 0:
                continue
            with context.timer("windowing"):
                crowd, offsets = context.crowd[c]
                own = own_rows(*offsets[rec.name], idx)
                plans[c] = rec.windows[c] = self.windows.plan(
                    cam, rec.pixels[c, idx], idx, covariance(c, idx), crowd, own, size_px)
        return plans

    def grab(self, observed: Any, plans: Sequence[Sequence[WindowPlan | None]]) -> list[Any]:
        """Per camera, what it took (``observed``, as given to the tracker's step) read for
        the windows of every part's ``plans`` (per part, per camera) at once: one grab a
        camera, each part's windows a group (:func:`~.grabbing.grabbed`); None where no part
        has windows."""
        seen: list[Any] = []
        for c in range(len(self.cameras)):
            groups = [plan.boxes for part in plans if (plan := part[c]) is not None]
            seen.append(None if not groups else
                        grabbed(observed_of(observed, self.cameras, c), groups=groups))
        return seen

    def extract(self, context: StepContext, plans: Sequence[WindowPlan | None],
                seen: Sequence[Any]) -> list[Observation]:
        """The features found in each camera's windows (``plans``) of what it took
        (``seen``, read for them), in ``rec.measured``, and their observations."""
        rec, track = context.rec, context.track
        observations = []
        for c, plan in enumerate(plans):
            if plan is None:
                continue
            with context.timer("extraction"):
                found = self.extractor.extract(c, seen[c], plan)
            if not found:
                continue
            ids = np.array(sorted(found), dtype=np.int64)
            px = np.array([found[i] for i in ids], dtype=float).reshape(-1, 2)
            rec.measured[c, ids] = px
            observations.append(Observation(self.models[c], c, ids, track.points[ids],
                                            self.cameras[c].undistort(px),
                                            float(context.lags[c])))
        return observations


def own_rows(start: int, visible: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Rows of the crowd (:data:`Crowd`) of the features ``idx`` of a part whose rows start at
    ``start`` for its visible features ``visible`` (sorted); -1 for a feature not among them."""
    pos = np.searchsorted(visible, idx)
    inside = pos < len(visible)
    inside[inside] = visible[pos[inside]] == idx[inside]
    return np.where(inside, start + pos, -1)

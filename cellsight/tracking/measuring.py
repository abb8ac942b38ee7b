"""One part's features measured in one frame (for :mod:`.tracker` and :mod:`.acquire`): which
may be measured (predicted visible, not held back next to an occluder, not under an unknown
occluder), then, for the selected ones, the windows planned around the other parts' features,
the image regions grabbed, the corners extracted and the observations built."""

from __future__ import annotations

from collections.abc import Callable
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
        """Plan the windows of the selected features (``covariance(c, idx)``: their innovation
        covariances (n, 2, 2) px^2 in camera ``c``; ``size_px``: fixed window size, px),
        extract, build the observations."""
        rec, timer, track = context.rec, context.timer, context.track
        observations = []
        for c, cam in enumerate(self.cameras):
            idx = np.flatnonzero(rec.selected[c])
            if len(idx) == 0:
                continue
            with timer("windowing"):
                crowd, offsets = context.crowd[c]
                own = own_rows(*offsets[rec.name], idx)
                plan = self.windows.plan(cam, rec.pixels[c, idx], idx,
                                                    covariance(c, idx), crowd, own, size_px)
                rec.windows[c] = plan
            with timer("grab"):
                seen = grabbed(observed_of(context.observed, self.cameras, c), plan.boxes)
            with timer("extraction"):
                found = self.extractor.extract(c, seen, plan)
            if not found:
                continue
            ids = np.array(sorted(found), dtype=np.int64)
            px = np.array([found[i] for i in ids], dtype=float).reshape(-1, 2)
            rec.measured[c, ids] = px
            observations.append(Observation(self.models[c], c, ids, track.points[ids],
                                            cam.undistort(px), float(context.lags[c])))
        return observations


def own_rows(start: int, visible: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Rows of the crowd (:data:`Crowd`) of the features ``idx`` of a part whose rows start at
    ``start`` for its visible features ``visible`` (sorted); -1 for a feature not among them."""
    pos = np.searchsorted(visible, idx)
    inside = pos < len(visible)
    inside[inside] = visible[pos[inside]] == idx[inside]
    return np.where(inside, start + pos, -1)

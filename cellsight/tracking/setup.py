"""The tracker a run uses, built in one place for ``cellsight run`` and ``cellsight track``.

:func:`build_tracker` gives the :class:`~cellsight.tracking.tracker.Tracker` of every workpiece
of a cell, acquiring each around its nominal pose, with the occlusion predictor
(``occlusion_prediction``; else projection only: every feature in the image counts as visible)
on the chosen ``structure``, and, with ``unknown_occluders``, the map of unknown occluders
(:mod:`.unknown`) and a coasting track that resumes only on three features passing the gate
together; with ``camera_offsets_px`` > 0, each camera's calibration error estimated as an image
offset of that prior (px; :mod:`.offsets`); with ``awaiting_registration``, a tracked part is
``degraded`` until the cameras are first registered to an arm (``TrackerConfig``). A part
lying on its support is held to twice the cell file's conveyor speed and 1 cm/s
(``TrackerConfig.support_speed``; the belt's speed is known to a few tens of percent, and
nothing else in the cell moves a lying part).
"""

from __future__ import annotations

from dataclasses import replace

from cellsight.model.cell import Cell
from cellsight.occlusion.predictor import OBJECT_BVH, VisibilityPredictor
from cellsight.occlusion.projection import ProjectionOnly
from cellsight.tracking.config import TrackerConfig, TrackerParts
from cellsight.tracking.interfaces import Extractor
from cellsight.tracking.tracker import Tracker
from cellsight.tracking.unknown import UnknownOccluderRule


def build_tracker(cell: Cell, *, occlusion_prediction: bool = True,
                  unknown_occluders: bool = False, structure: str = OBJECT_BVH,
                  extractor: Extractor | None = None, camera_offsets_px: float = 0.0,
                  awaiting_registration: bool = False) -> Tracker:
    """The tracker of the cell's workpieces (module docstring); ``extractor``: the sensor
    (default: corners in images)."""
    predictor = (VisibilityPredictor(cell, structure=structure) if occlusion_prediction
                 else ProjectionOnly(cell))
    speed = 2.0 * cell.experiments.conveyor_speed + 0.01
    config = TrackerConfig(camera_offsets_px=camera_offsets_px,
                           support_speed=(speed, TrackerConfig.support_speed[1]),
                           awaiting_registration=awaiting_registration)
    parts = TrackerParts()
    if unknown_occluders:
        config = replace(config, resume_support=3)
        parts = replace(parts, unknown=UnknownOccluderRule())
    return Tracker.from_cell(cell, predictor, extractor, config, parts)

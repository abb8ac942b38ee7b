"""The tracker a run uses, chosen and built in one place for ``cellsight run``, ``cellsight
track``, ``cellsight sweep`` and the API.

The choice a user makes is a :class:`~cellsight.trackers.TrackerChoice`. :func:`build_tracker`
gives the :class:`~cellsight.tracking.tracker.Tracker` of every workpiece
of a cell, acquiring each around its nominal pose, with the occlusion predictor on the chosen
``structure`` (or projection only), and, with ``unknown-occluders``, the map of unknown
occluders and a coasting track that resumes only on three features passing the gate together;
with ``camera-offsets``, each camera's calibration error estimated as an image offset; with
``awaiting_registration``, a tracked part is
``degraded`` until the cameras are first registered to an arm (``TrackerConfig``). A part
lying on its support is held to twice the cell file's fastest belt speed (the conveyor's,
or a line's passing parts') and 1 cm/s (``TrackerConfig.support_speed``; the belt's speed is
known to a few tens of percent, and nothing else in the cell moves a lying part). A line's
passing part waiting out of view is looked for where it would come in along its travel
(:meth:`~cellsight.tracking.acquire.Acquirer.entry`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from cellsight.model.cell import Cell
from cellsight.occlusion.backends import visibility_predictor
from cellsight.occlusion.projection import ProjectionOnly
from cellsight.trackers import DEFAULT_TRACKER, TrackerChoice
from cellsight.tracking.config import TrackerConfig, TrackerParts
from cellsight.tracking.interfaces import Extractor
from cellsight.tracking.tracker import Tracker
from cellsight.tracking.unknown import UnknownOccluderRule
from cellsight.visibility import OBJECT_BVH


def tracker_facts(choice: TrackerChoice) -> dict[str, object]:
    """The choice as ``metrics.json`` keeps it (:class:`~cellsight.runfolder.RunMetrics`)."""
    return {"tracker": choice.kind, "occlusion_prediction": choice.occlusion_prediction,
            "kinematic_prior": choice.kinematic, "unknown_occluders": choice.unknown_occluders,
            "camera_offsets_px": choice.camera_offsets_px}


def build_tracker(cell: Cell, choice: TrackerChoice = DEFAULT_TRACKER, *,
                  structure: str = OBJECT_BVH, extractor: Extractor | None = None,
                  awaiting_registration: bool = False) -> Tracker:
    """The tracker of the cell's workpieces (module docstring) as ``choice`` has it;
    ``extractor``: the sensor (default: corners in images); ``awaiting_registration``: the
    caller registers the cameras to an arm (the kinematic tracker with images)."""
    predictor = (visibility_predictor(cell, structure=structure) if choice.occlusion_prediction
                 else ProjectionOnly(cell))
    setup = cell.experiments
    speed = 2.0 * max(setup.conveyor_speed, setup.passing_speed) + 0.01
    config = TrackerConfig(camera_offsets_px=choice.camera_offsets_px,
                           support_speed=(speed, TrackerConfig.support_speed[1]),
                           awaiting_registration=awaiting_registration)
    parts = TrackerParts()
    if choice.unknown_occluders:
        config = replace(config, resume_support=3)
        parts = replace(parts, unknown=UnknownOccluderRule())
    tracker = Tracker.from_cell(cell, predictor, extractor, config, parts)
    for name in setup.passing:  # a part waiting upstream comes into the views along it
        tracker.tracks[name].travel = np.array(setup.passing_travel, dtype=float)
    return tracker

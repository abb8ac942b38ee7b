"""What the view shows at one instant (:class:`FrameState`): the cell's state (joints, jaw
openings, true part poses), the tracker's estimate, and per workpiece what each camera sees of
its feature points (:class:`FeatureState`). :func:`static_state` makes one from given joints and
part poses with the :class:`~cellsight.occlusion.predictor.VisibilityPredictor`; a run's frames
come from :class:`cellsight.view.replay.RunReplay`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from cellsight.model.cell import Cell
from cellsight.occlusion.backends import visibility_predictor
from cellsight.occlusion.predictor import VisibilityPredictor
from cellsight.tracking.unknown import Grid


@dataclass
class FeatureState:
    """One workpiece's F feature points seen by the C cameras (``cell.cameras`` order).

    ``visible`` (C, F) bool: predicted visible; ``pixels`` (C, F, 2): their predicted
    projections (u, v) in px, NaN where none; ``truth`` (C, F) bool: visible by the
    simulator's ray casts (a run's ``vis_true``), or None; ``selected``, ``measured``,
    ``rejected`` (C, F) bool: the tracker's windows, measurements and gate rejections (a run's
    ``sel`` / ``meas`` / ``rej``), or None; ``measured_pixels`` (C, F, 2): where to mark the
    measurements (the logged corners; for runs logged before them, the true projections), or
    None; ``windows``: per camera the logged windows (n, 4) int, or None (planned again).
    """

    visible: np.ndarray
    pixels: np.ndarray
    truth: np.ndarray | None = None
    selected: np.ndarray | None = None
    measured: np.ndarray | None = None
    rejected: np.ndarray | None = None
    measured_pixels: np.ndarray | None = None
    windows: list[np.ndarray] | None = None

    def colour_mask(self, camera: int, truth: bool = False) -> np.ndarray:
        """(F,) bool: the features camera ``camera`` sees, as predicted or (``truth``, when
        there is one) by the ray casts."""
        source = self.truth if truth and self.truth is not None else self.visible
        return np.asarray(source[camera], dtype=bool)


@dataclass
class FrameState:
    """The shown instant: robot name -> joints, workpiece name -> true ``T_base_part``, robot
    name -> jaw opening (m), workpiece name -> estimated ``T_base_part`` (only those with an
    estimate), workpiece name -> :class:`FeatureState`, a caption (time, phase, status) and,
    per camera, the tracker's unknown-occluder map (:class:`~cellsight.tracking.unknown.Grid`,
    None where empty; none outside a run)."""

    joints: dict[str, np.ndarray]
    part_poses: dict[str, np.ndarray]
    openings: dict[str, float] = field(default_factory=dict)
    estimates: dict[str, np.ndarray] = field(default_factory=dict)
    features: dict[str, FeatureState] = field(default_factory=dict)
    caption: str = ""
    unknown: list[Grid | None] = field(default_factory=list)


def static_state(cell: Cell, joints: Mapping[str, np.ndarray] | None = None,
                 part_poses: Mapping[str, np.ndarray] | None = None,
                 predictor: VisibilityPredictor | None = None,
                 openings: Mapping[str, float] | None = None) -> FrameState:
    """The cell at ``joints`` (robots left out at HOME) with its workpieces at ``part_poses``
    (left out: nominal) and its grippers at ``openings`` (m; left out: open), every
    workpiece's features coloured by the predictor's answer.
    Joints are checked (length, limits) and part names too: errors name the robot or part."""
    snapshot = cell.snapshot(joints or {}, part_poses or {}, openings or {})
    views = (predictor or visibility_predictor(cell)).predict_snapshot(snapshot)
    features = {
        part: FeatureState(visible=np.array([v.visible for v in per_camera], dtype=bool),
                           pixels=np.array([v.pixels for v in per_camera], dtype=float))
        for part, per_camera in views.items()
    }
    given = ", ".join(sorted(joints or {})) or "none"
    caption = f"{cell.name}: joints given for {given} (others at HOME)"
    return FrameState(dict(snapshot.joints), dict(snapshot.part_poses), dict(snapshot.openings),
                      {}, features, caption)

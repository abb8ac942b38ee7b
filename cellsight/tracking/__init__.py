"""Visual tracking of the workpieces (paper, Section IV and Fig. 5).

EKF per workpiece (:mod:`.motion`, :mod:`.measurement`, :mod:`.ekf`), PnP initialisation and
baseline (:mod:`.pnp`), optimal feature selection (:mod:`.selection`), image windows
(:mod:`.windowing`), sub-pixel corner extraction (:mod:`.extraction`) and the closed loop with
the occlusion predictor (:mod:`.tracker`).
"""

from cellsight.tracking.ekf import AdaptiveNoise, PoseEKF, UpdateReport
from cellsight.tracking.extraction import CornerExtractor, ExtractionConfig, extract_corner
from cellsight.tracking.measurement import Observation, PinholeMeasurement, undistort_pixels
from cellsight.tracking.motion import ConstantVelocity
from cellsight.tracking.pnp import (
    PoseFix,
    estimate_pose,
    estimate_pose_robust,
    refine_pose,
    solve_pnp_camera,
)
from cellsight.tracking.selection import (
    Selection,
    SelectionConfig,
    select_features,
    selection_quality,
)
from cellsight.tracking.tracker import PartFrame, Tracker, TrackerConfig, TrackerFrame
from cellsight.tracking.windowing import WindowConfig, WindowPlan, plan_windows

__all__ = [
    "AdaptiveNoise",
    "ConstantVelocity",
    "CornerExtractor",
    "ExtractionConfig",
    "Observation",
    "PartFrame",
    "PinholeMeasurement",
    "PoseEKF",
    "PoseFix",
    "Selection",
    "SelectionConfig",
    "Tracker",
    "TrackerConfig",
    "TrackerFrame",
    "UpdateReport",
    "WindowConfig",
    "WindowPlan",
    "estimate_pose",
    "estimate_pose_robust",
    "extract_corner",
    "plan_windows",
    "refine_pose",
    "select_features",
    "selection_quality",
    "solve_pnp_camera",
    "undistort_pixels",
]

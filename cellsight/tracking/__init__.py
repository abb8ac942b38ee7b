"""Visual tracking of the workpieces (paper, Section IV and Fig. 5).

EKF per workpiece (:mod:`.motion`, :mod:`.measurement`, :mod:`.ekf`) with its gate
(:mod:`.gate`), PnP (:mod:`.pnp`) for acquisition (:mod:`.acquisition`) and as a baseline,
loss and coasting (:mod:`.loss`), tracking health (:mod:`.health`), usable features
(:mod:`.eligibility`), optimal feature selection (:mod:`.selection`), image windows
(:mod:`.windowing`), sub-pixel corner extraction (:mod:`.extraction`); the tracker
(:mod:`.tracker`) only wires them, with the occlusion predictor, into the paper's loop; it
reports :mod:`.records` with a :mod:`.status` and :mod:`.timing` per stage. Each part is a
protocol (:mod:`.interfaces`) with its default; the tracker takes its parts and its numbers
apart (:mod:`.config`).
"""

from cellsight.tracking.acquisition import PnPAcquisition
from cellsight.tracking.adaptive_noise import AdaptiveNoise
from cellsight.tracking.config import TrackerConfig, TrackerParts
from cellsight.tracking.ekf import PoseEKF, UpdateReport
from cellsight.tracking.extraction import CornerExtractor, ExtractionConfig, extract_corner
from cellsight.tracking.gate import ChiSquareGate
from cellsight.tracking.health import HealthMonitor, HealthRule, TrackHealthReport
from cellsight.tracking.interfaces import (
    Acquisition,
    Extractor,
    Gate,
    HealthCheck,
    MeasurementModel,
    MotionModel,
    OccluderMap,
    OccluderMemory,
    Selector,
    TrackHealth,
    TrackMonitor,
    WindowPlanner,
)
from cellsight.tracking.loss import LossRule
from cellsight.tracking.measurement import Observation, PinholeMeasurement
from cellsight.tracking.motion import ConstantVelocity
from cellsight.tracking.part_track import StepContext
from cellsight.tracking.pnp import (
    PoseFix,
    estimate_pose,
    estimate_pose_robust,
    refine_pose,
    solve_pnp_camera,
)
from cellsight.tracking.records import PartFrame, TrackerFrame
from cellsight.tracking.selection import (
    OptimalSelector,
    Selection,
    SelectionConfig,
    select_features,
    selection_quality,
)
from cellsight.tracking.status import TrackStatus
from cellsight.tracking.timing import STAGES
from cellsight.tracking.tracker import Tracker
from cellsight.tracking.unknown import UNKNOWN_LABEL, Grid, UnknownOccluderRule, UnknownOccluders
from cellsight.tracking.windowing import CovarianceWindows, WindowConfig, WindowPlan, plan_windows

__all__ = [
    "STAGES",
    "UNKNOWN_LABEL",
    "Acquisition",
    "AdaptiveNoise",
    "ChiSquareGate",
    "ConstantVelocity",
    "CornerExtractor",
    "CovarianceWindows",
    "ExtractionConfig",
    "Extractor",
    "Gate",
    "Grid",
    "HealthCheck",
    "HealthMonitor",
    "HealthRule",
    "LossRule",
    "MeasurementModel",
    "MotionModel",
    "Observation",
    "OccluderMap",
    "OccluderMemory",
    "OptimalSelector",
    "PartFrame",
    "PinholeMeasurement",
    "PnPAcquisition",
    "PoseEKF",
    "PoseFix",
    "Selection",
    "SelectionConfig",
    "Selector",
    "StepContext",
    "TrackHealth",
    "TrackHealthReport",
    "TrackMonitor",
    "Tracker",
    "TrackerConfig",
    "TrackerFrame",
    "TrackerParts",
    "TrackStatus",
    "UnknownOccluderRule",
    "UnknownOccluders",
    "UpdateReport",
    "WindowPlanner",
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
]

"""What a :class:`~cellsight.tracking.Tracker` is made of: its parts (:class:`TrackerParts`,
each a protocol of :mod:`.interfaces` with its default implementation) and its plain numbers
(:class:`TrackerConfig`). The defaults are the paper's tracker with this package's additions
(gate, acquisition, loss, health, unknown occluders, near-occluder hold)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from cellsight.camera import Camera
from cellsight.tracking.acquisition import PnPAcquisition
from cellsight.tracking.camera_check import CameraCheckRule
from cellsight.tracking.gate import ChiSquareGate
from cellsight.tracking.health import HealthRule
from cellsight.tracking.interfaces import (
    Acquisition,
    Gate,
    HealthCheck,
    MeasurementModel,
    MotionModel,
    OccluderMemory,
    Selector,
    TrackHealth,
    WindowPlanner,
)
from cellsight.tracking.loss import LossRule
from cellsight.tracking.measurement import PinholeMeasurement
from cellsight.tracking.motion import ConstantVelocity
from cellsight.tracking.search import PlaneSearch
from cellsight.tracking.selection import OptimalSelector
from cellsight.tracking.unknown import UnknownOccluderRule
from cellsight.tracking.windowing import CovarianceWindows


@dataclass(frozen=True)
class TrackerParts:
    """The tracker's swappable parts, in the order of one step (:mod:`.tracker`).

    ``motion`` predicts each filter; ``loss`` says when a track coasts and when it is lost;
    ``health`` makes each track's health monitor, which says when a tracked part is degraded;
    ``unknown`` makes the map of unknown occluders that the selection avoids (off by default,
    ``UnknownOccluderRule()`` turns it on); ``selector``
    chooses the features to measure; ``windows`` plans their image windows;
    ``gate`` screens the innovations (None accepts every measurement); ``acquisition`` starts a
    filter from one frame's measurements; ``search`` finds a part being acquired anywhere on
    its support plane in the whole images, when the extractor can ``detect`` corners (None:
    only near the last prediction or the nominal pose); ``cameras`` drops a camera that
    disagrees with the others and re-estimates its pose; ``measurement`` builds a camera's
    measurement model from the camera and the pixel noise ``TrackerConfig.sigma_px`` (px). The
    extractor (the sensor) is the tracker's own argument: it goes with what
    :meth:`Tracker.step` is given.
    """

    motion: MotionModel = ConstantVelocity()
    loss: TrackHealth = LossRule()
    health: HealthCheck = HealthRule()
    unknown: OccluderMemory = UnknownOccluderRule(enabled=False)
    selector: Selector = OptimalSelector()
    windows: WindowPlanner = CovarianceWindows()
    gate: Gate | None = ChiSquareGate(0.999)
    acquisition: Acquisition = PnPAcquisition()
    search: PlaneSearch | None = PlaneSearch()
    cameras: CameraCheckRule = CameraCheckRule()
    measurement: Callable[[Camera, float], MeasurementModel] = PinholeMeasurement


@dataclass(frozen=True)
class TrackerConfig:
    """The tracker's plain numbers. Units: px, s, m^2/s, rad^2/s.

    ``sigma_px``: pixel noise of the measurement model and of acquisition's fix;
    ``adaptive_noise``: re-estimate it per camera from the innovations
    (:class:`~cellsight.tracking.adaptive_noise.AdaptiveNoise`); ``carried_noise``: random-walk
    densities of a held part's pose relative to its holder, with the kinematic prior (``holders`` in
    :meth:`Tracker.step`); ``near_occluder_hold_s``: how long a feature stays unusable after it
    was last flagged ``near_occluder`` (:mod:`.eligibility`); ``resume_support``: how many
    features the gate must accept together in the first update after a tracked frame without
    one, or after an acquisition (a coasting track's prediction is wide, and a lone intruder's
    corner fits it: in the realistic world one such corner threw the velocity off by 0.5 m/s;
    :class:`~cellsight.tracking.gate.SupportedGate`; at least the loss rule's
    :meth:`~cellsight.tracking.loss.LossRule.resume_support` share of the features looked for
    applies too; 3 goes with the unknown-occluder map); ``camera_offsets_px``: the prior (px per
    axis) of each camera's image offset, its calibration error as the filter estimates it
    (0: not estimated; :mod:`.offsets`), with a random walk of ``camera_offsets_walk_px``
    (px/sqrt(s)); ``held_std``: one sigma (m, rad) of where a holder puts a part (the grasp's
    seat, the joints' errors), with which a held part that is not tracked starts there;
    ``hold_std``: one sigma (m, rad) of where a holder puts a part once the jaws' opening has
    confirmed the grasp, with which its estimate is kept with the holder (tighter than
    ``held_std``: the part is within its seat's error of the chosen grasp; :mod:`.prior`);
    ``rest_std``: one sigma (m, rad) of the height and the roll and pitch of a part lying on its
    support, with the kinematic prior (``supports`` in :meth:`Tracker.step`; the support's
    height and flatness as the cell file knows them); ``support_speed``: how fast (m/s across
    the support, rad/s about its normal) a support moves a part lying on it at most (a
    conveyor's belt), with the kinematic prior: the rates a lying part's filter starts with
    (one sigma) and the bound its rates are held to (:func:`~.prior.fusion._keep_support_speed`);
    ``awaiting_registration``: the cameras are to be registered to an arm
    (:mod:`.registration`): until the first :meth:`Tracker.recalibrate`, a tracked part is
    ``degraded`` with the reason :data:`~.update.UNREGISTERED` (the calibration's error the
    cameras share is in the estimate and not in its covariance: in ``harsh`` cells the first
    fix is up to 11 mm off with a sigma of 0.4 mm); ``edge_margin_px``: a feature predicted
    nearer the image's edge than this is not measured there (the corner extractor cannot
    refine a corner whose window the edge cuts: on a line of parts, the features of a part
    leaving a camera's view went unfound within 6 px of the edge, and the track was degraded
    for them).
    """

    sigma_px: float = 0.5
    adaptive_noise: bool = False
    carried_noise: tuple[float, float] = (1e-6, 1e-5)
    near_occluder_hold_s: float = 0.5
    resume_support: int = 1
    camera_offsets_px: float = 0.0
    camera_offsets_walk_px: float = 0.0
    held_std: tuple[float, float] = (0.01, 0.05)
    hold_std: tuple[float, float] = (0.003, 0.02)
    rest_std: tuple[float, float] = (0.002, 0.01)
    support_speed: tuple[float, float] = (0.1, 0.1)
    awaiting_registration: bool = False
    edge_margin_px: float = 8.0

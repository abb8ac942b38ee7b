"""The parts a :class:`~cellsight.tracking.Tracker` is wired from, as protocols: any object
with these methods plugs in (:class:`~cellsight.tracking.config.TrackerParts`; the visibility
source is :class:`cellsight.visibility.VisibilitySource`, the extractor a separate argument of
the tracker).

Each protocol has its default implementation:

============================  ===========================================================
protocol                      default
============================  ===========================================================
:class:`Selector`             :class:`~cellsight.tracking.selection.OptimalSelector`
:class:`WindowPlanner`        :class:`~cellsight.tracking.windowing.CovarianceWindows`
:class:`Extractor`            :class:`~cellsight.tracking.extraction.CornerExtractor`
:class:`Gate`                 :class:`~cellsight.tracking.gate.ChiSquareGate`
:class:`MotionModel`          :class:`~cellsight.tracking.motion.ConstantVelocity`
:class:`MeasurementModel`     :class:`~cellsight.tracking.measurement.PinholeMeasurement`
:class:`Acquisition`          :class:`~cellsight.tracking.acquisition.PnPAcquisition`
:class:`TrackHealth`          :class:`~cellsight.tracking.loss.LossRule`
:class:`HealthCheck`          :class:`~cellsight.tracking.health.HealthRule`
:class:`TrackMonitor`         :class:`~cellsight.tracking.health.HealthMonitor`
:class:`OccluderMemory`       :class:`~cellsight.tracking.unknown.UnknownOccluderRule`
:class:`OccluderMap`          :class:`~cellsight.tracking.unknown.UnknownOccluders`
============================  ===========================================================

Conventions: C cameras in the tracker's order, F features of one workpiece, pixels ``(u, v)``
as in the image (with distortion) unless said otherwise, times in s; state layout and units in
:mod:`cellsight.tracking.motion`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np

from cellsight.camera import Camera
from cellsight.tracking.health import TrackHealthReport
from cellsight.tracking.measurement import Observation
from cellsight.tracking.pnp import PoseFix
from cellsight.tracking.selection import Selection
from cellsight.tracking.unknown import Grid
from cellsight.tracking.windowing import WindowPlan


class Selector(Protocol):
    """Chooses, per frame, which features of a part to measure."""

    def select(self, pixels: np.ndarray, usable: np.ndarray, resolution: np.ndarray) -> Selection:
        """The chosen features among the ``usable`` ones (C, F) bool (predicted visible, not
        next to an occluder), with their predicted pixels ``pixels`` (C, F, 2) px; ``resolution``
        (C,) px/m: each camera's focal length over the part's depth. A choice outside ``usable``
        is measured all the same; :meth:`Selection.of` wraps a plain mask."""
        ...


class WindowPlanner(Protocol):
    """Places the image windows of one camera around the selected features."""

    def plan(self, camera: Camera, centers: np.ndarray, features: np.ndarray,
             covariance: np.ndarray, crowd: np.ndarray, own: np.ndarray,
             size_px: float | None = None) -> WindowPlan:
        """Windows in ``camera``'s image for ``features`` (n,) predicted at ``centers`` (n, 2) px
        with innovation covariances ``covariance`` (n, 2, 2) px^2; ``crowd`` (m, 2) px: every
        predicted-visible feature in this camera (any part), ``own`` (n,) the row of ``crowd``
        that is each window's own feature; ``size_px``: fixed full width and height (px) of
        every window (acquisition, where there is no covariance yet), None: the planner's."""
        ...


class Extractor(Protocol):
    """The sensor: finds the features in one camera's image windows."""

    def extract(self, camera_index: int, observed: Any, plan: WindowPlan) -> dict[int, np.ndarray]:
        """Feature index -> measured pixel (2,) px as in the image (with distortion), for the
        windows of ``plan``; a feature not found is missing. ``observed``: what this camera's
        sensor took this frame, as passed to :meth:`Tracker.step` (an image for the corner
        extractor; None when the camera gave nothing)."""
        ...


@runtime_checkable
class CornerDetector(Protocol):
    """A sensor that can also find corners in a camera's whole image (an extractor with a
    ``detect`` method): what the whole-image search (:mod:`cellsight.tracking.search`)
    matches the part's model against."""

    def detect(self, observed: Any) -> np.ndarray:
        """(N, 2) px, as in the image: the corners in what one camera took (``observed``, as
        given to :meth:`Extractor.extract`)."""
        ...


class Gate(Protocol):
    """Validation gate of the EKF update (:mod:`cellsight.tracking.gate`)."""

    def accepts(self, mahalanobis2: np.ndarray) -> np.ndarray:
        """Boolean mask (m,): which squared Mahalanobis distances (m,) of the innovations
        pass."""
        ...


class MotionModel(Protocol):
    """Transition model of a part's state (12,) (:mod:`cellsight.tracking.motion`)."""

    def matrix(self, dt: float) -> np.ndarray:
        """Transition matrix (12x12) over ``dt`` seconds."""
        ...

    def covar(self, dt: float) -> np.ndarray:
        """Process noise covariance (12x12) over ``dt`` seconds."""
        ...

    def function(self, state: np.ndarray, dt: float) -> np.ndarray:
        """The state (12,) propagated over ``dt`` seconds without noise."""
        ...


class MeasurementModel(Protocol):
    """One camera's model of a part's feature pixels: ``evaluate(state, points_model)`` gives
    the predicted ideal pixels (n, 2) and their Jacobian (2n, 12) w.r.t. the state (layout in
    :mod:`cellsight.tracking.motion`); ``sigma_px`` the pixel noise (px)."""

    camera: Camera
    sigma_px: float

    def evaluate(
        self, state: np.ndarray, points_model: np.ndarray, rotation: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]: ...


class Acquisition(Protocol):
    """Starts the filter of a part not tracked yet, or lost, from one frame's measurements
    (:mod:`cellsight.tracking.acquisition`)."""

    @property
    def window_px(self) -> float:
        """Full width and height (px) of the window around every usable feature."""
        ...

    @property
    def verify_window_px(self) -> float:
        """Full width and height (px) of the windows that verify a fix."""
        ...

    def guess(self, base: np.ndarray, attempt: int) -> np.ndarray:
        """Where to look (``T_base_part``) at the ``attempt``-th try around ``base``, while a
        part never acquired is not found."""
        ...

    def fix(self, observations: list[Observation], sigma_px: float,
            coarse: bool = False, guess: np.ndarray | None = None,
            support: tuple[np.ndarray, tuple[float, float]] | None = None) -> PoseFix | None:
        """The pose to start from (ideal pixels with noise ``sigma_px`` px), or None;
        ``coarse``: a first fix, which only has to bring the verification's windows near;
        ``guess``: the ``T_base_part`` the windows were placed at, where it is already near;
        ``support``: the part's ``T_base_part`` lying on a level support, and one sigma (m,
        rad) of its height and of its roll and pitch there."""
        ...

    def enough(self, fix: PoseFix) -> bool:
        """Whether ``fix`` has the points a fix needs."""
        ...

    def confirms(self, fix: PoseFix, looked: np.ndarray, used: np.ndarray) -> bool:
        """Whether ``fix``, from windows at a first fix's predictions, verifies that fix
        (``looked``, ``used`` (C,): per camera, the features looked for there and those
        ``fix`` kept)."""
        ...

    def covariance(self, pose_covariance: np.ndarray) -> np.ndarray:
        """Initial state covariance (12x12) from a pose covariance (6x6, xyz + rpy)."""
        ...

    def start(self, fix: PoseFix) -> np.ndarray:
        """Initial state covariance (12x12) from a fix."""
        ...


class TrackHealth(Protocol):
    """When a track coasts and when it is lost (:mod:`cellsight.tracking.loss`)."""

    def coasts(self, t: float, last_update: float) -> bool:
        """The motion model still propagates the estimate at time ``t`` (s), the last accepted
        measurement being at ``last_update`` (s)."""
        ...

    def lost(self, t: float, last_update: float, unseen_since: float) -> bool:
        """The track is lost at time ``t`` (s) (the tracker then re-acquires it);
        ``unseen_since`` (s): since when every frame looked for its features in vain
        (:meth:`in_vain`; ``inf`` when the last frame that said saw the part)."""
        ...

    def in_vain(self, looked: int, accepted: int, in_view: bool) -> bool | None:
        """Whether a tracked frame that looked for ``looked`` features (in the cameras that
        gave something) and accepted ``accepted``, its prediction ``in_view`` of some camera
        or not, looked in vain (True: it counts towards ``unseen_since``), saw the part
        (False: ``unseen_since`` is reset) or says nothing (None)."""
        ...


class TrackMonitor(Protocol):
    """One track's health (:mod:`cellsight.tracking.health`), fed every frame the track is
    tracked (not while it is acquired)."""

    def reset(self, t: float) -> None:
        """Forget the past: the track's filter (re)starts at time ``t`` (s)."""
        ...

    def update(self, t: float, visible: np.ndarray, selected: np.ndarray, measured: np.ndarray,
               rejected: np.ndarray, mahalanobis2: np.ndarray,
               unknown: np.ndarray | None = None,
               off_holder: float | None = None) -> TrackHealthReport:
        """Add the frame at time ``t`` (s), the record's arrays per camera and feature (C, F):
        predicted ``visible``, ``selected``, ``measured`` (C, F, 2) px (NaN where not found),
        gate-``rejected``, the gate's ``mahalanobis2`` and ``unknown`` (under the
        unknown-occluder map); ``off_holder``: a held part's estimate's distance (m) from
        where its holder puts it (None: not held); the report, whose reasons make a tracked
        frame degraded."""
        ...


class HealthCheck(Protocol):
    """Makes each track's health monitor (:mod:`cellsight.tracking.health`)."""

    def monitor(self, cameras: Sequence[str]) -> TrackMonitor:
        """A new monitor for one track seen by ``cameras`` (names, in the tracker's order)."""
        ...


class OccluderMap(Protocol):
    """Where, per camera, something the cell file does not know hides the workpieces
    (:mod:`cellsight.tracking.unknown`); shared by every part of one tracker."""

    def covered(self, c: int, pixels: np.ndarray, t: float) -> np.ndarray:
        """(n,) bool: which ``pixels`` (n, 2) px of camera ``c`` an unknown occluder covers at
        time ``t`` (s)."""
        ...

    def learn(self, c: int, t: float, failed: np.ndarray) -> None:
        """Camera ``c`` at time ``t`` (s): features looked for at the predicted pixels
        ``failed`` (n, 2) px were not found, or rejected where the camera accepted none."""
        ...

    def mask(self, c: int, t: float) -> Grid:
        """Camera ``c``'s occluded cells at time ``t`` (s)."""
        ...


class OccluderMemory(Protocol):
    """Makes a tracker's unknown-occluder map (:mod:`cellsight.tracking.unknown`)."""

    min_accepted: int
    trust_s: float

    def maps(self, cameras: Sequence[Camera]) -> OccluderMap:
        """Empty maps for ``cameras`` (the tracker's order); a frame's failures are learnt
        only within ``trust_s`` seconds of a frame whose update accepted ``min_accepted``
        measurements of the part."""
        ...

"""The closed visual tracking loop of the paper's Fig. 5, one :meth:`Tracker.step` per frame.

The tracker only wires its parts (:class:`~cellsight.tracking.config.TrackerParts`, each a
protocol of :mod:`.interfaces` with its default in its own module):

1. the motion model (:mod:`.motion`; or the holder's measured motion with the kinematic prior)
   predicts every tracked part (:class:`~cellsight.tracking.ekf.PoseEKF`), within the track
   health rule's coasting time (:mod:`.loss`);
2. the visibility source (:class:`cellsight.visibility.VisibilitySource`: the BSP predictor)
   predicts, at the predicted poses, which features each camera sees; every tracked part is
   passed, so parts can hide each other;
3. the parts to acquire after the tracked ones. Each tracked part (:mod:`.update`): the
   selector chooses among the usable features (:mod:`.eligibility`, :mod:`.selection`) and
   the window planner places their windows (:mod:`.windowing`); each camera's windows of
   every tracked part are grabbed at once (:mod:`.grabbing`); then part by part the
   extractor finds them in what the sensors took (:mod:`.extraction`), the gate
   (:mod:`.gate`) screens the innovations and the EKF updates with the accepted ones
   (:mod:`.measurement`, :mod:`.ekf`); the track's health monitor (:mod:`.health`) takes the
   frame's outcome, and a tracked part whose figures pass its limits is degraded (so is every
   tracked part while the cameras await their registration to an arm:
   ``TrackerConfig.awaiting_registration``); the unknown-occluder map (:mod:`.unknown`,
   shared by the parts; off by default) learns from the features not found, or rejected where
   their camera accepted none, and no feature it covers is selected or used for acquisition;
   the camera check (:mod:`.camera_check`, shared) drops a camera whose innovations are
   consistently biased while another's are not, and re-estimates its pose. A part not
   tracked yet, or lost, is acquired (:mod:`.acquisition`: windows at the guess or the last
   prediction, or where it was let go by a gripper; a part that a gripper holds starts where
   the gripper holds it, ``holders`` of :meth:`Tracker.step`; failing that, at most every
   ``search.every_s``, the whole-image search over its support plane, :mod:`.search`, each of
   its best candidates tried with the same windows and PnP, the confirmed fix of the most
   points taken; a fix stands only when narrow windows where it predicts the part's features
   confirm it).

Within a step, each part's work carries one :class:`StepContext`. Measured pixels are as in the
image (distorted); the camera undistorts them before the update. Stage times: :mod:`.timing`;
statuses: :mod:`.status`; records: :mod:`.records`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.transforms import xyz_rpy_from_pose
from cellsight.tracking.acquire import Acquirer
from cellsight.tracking.acquisition import twin_turns
from cellsight.tracking.adaptive_noise import AdaptiveNoise
from cellsight.tracking.config import TrackerConfig, TrackerParts
from cellsight.tracking.ekf import PoseEKF
from cellsight.tracking.eligibility import NearOccluderHold
from cellsight.tracking.extraction import CornerExtractor
from cellsight.tracking.interfaces import Extractor
from cellsight.tracking.measuring import Measurer
from cellsight.tracking.motion import POSE_DIM
from cellsight.tracking.offsets import CameraOffsets
from cellsight.tracking.part_track import (
    PartTrack,
    StepContext,
    observed_of,
    visible_pixels,
)
from cellsight.tracking.records import PartFrame, TrackerFrame
from cellsight.tracking.timing import StageTimer
from cellsight.tracking.update import Updater, with_held_out
from cellsight.visibility import Recalibrating, Views, VisibilitySource


class Tracker:
    """Occlusion-aware multi-camera tracker of one or more workpieces (module docstring).

    ``cameras`` in the order the visibility source reports them; ``parts``: workpiece name ->
    feature points (F, 3) in the part frame (m); ``predictor``: the visibility source;
    ``extractor``: the sensor, fed what :meth:`step` is given (default
    :class:`~cellsight.tracking.extraction.CornerExtractor`, on images); ``config``: the plain
    numbers; ``initial_poses``: name -> guessed ``T_base_part`` for acquisition (a part without
    one waits for :meth:`initialise`); ``components``: the other parts (selector, window
    planner, gate, motion, acquisition, loss, health, measurement model).
    """

    def __init__(
        self,
        cameras: Sequence[Camera],
        parts: Mapping[str, np.ndarray],
        predictor: VisibilitySource,
        extractor: Extractor | None = None,
        config: TrackerConfig | None = None,
        initial_poses: Mapping[str, np.ndarray] | None = None,
        components: TrackerParts | None = None,
    ) -> None:
        self.config = config or TrackerConfig()
        self.components = components or TrackerParts()
        self.cameras = list(cameras)
        self.predictor = predictor
        self.models = [self.components.measurement(c, self.config.sigma_px)
                       for c in self.cameras]
        self.unknown = self.components.unknown.maps(self.cameras)
        self.measurer = Measurer(self.cameras, self.components.windows,
                                 extractor or CornerExtractor(), self.models, self.unknown,
                                 self.config.edge_margin_px)
        self.camera_check = self.components.cameras.check(self.cameras)
        self.acquirer = Acquirer(self)
        self.updater = Updater(self)
        self.registered = not self.config.awaiting_registration
        guesses = dict(initial_poses or {})
        names = [c.name for c in self.cameras]
        self.tracks = {
            name: PartTrack(points, guesses.get(name),
                         NearOccluderHold(self.config.near_occluder_hold_s),
                         self.components.health.monitor(names), support=guesses.get(name),
                         twins=twin_turns(points))
            for name, pts in parts.items()
            for points in [np.asarray(pts, dtype=float).reshape(-1, 3)]
        }

    @property
    def extractor(self) -> Extractor:
        """The sensor (:class:`~.measuring.Measurer`'s): what extracts the features."""
        return self.measurer.extractor

    @extractor.setter
    def extractor(self, extractor: Extractor) -> None:
        self.measurer.extractor = extractor

    @classmethod
    def from_cell(
        cls,
        cell: Any,
        predictor: VisibilitySource,
        extractor: Extractor | None = None,
        config: TrackerConfig | None = None,
        components: TrackerParts | None = None,
    ) -> Tracker:
        """Tracker of every workpiece of a :class:`~cellsight.model.cell.Cell`, acquiring each
        around its nominal pose."""
        return cls(
            cell.cameras,
            {p.name: p.feature_points for p in cell.workpieces},
            predictor,
            extractor,
            config,
            {p.name: p.T_base_part for p in cell.workpieces},
            components,
        )

    def initialise(
        self, name: str, T_base_part: np.ndarray, t: float, covariance: np.ndarray | None = None,
        offsets: dict[int, np.ndarray] | None = None,
    ) -> None:
        """Start (or restart) the filter of a part at a known pose, zero velocity.

        ``covariance`` (12x12) defaults to 5 mm / 0.05 rad on the pose and the acquisition's
        velocity uncertainty. With camera offsets (``TrackerConfig.camera_offsets_px``), the
        filter keeps the earlier filter's offsets, or starts from ``offsets`` (camera index ->
        (2,) px, an acquisition's :attr:`~.pnp.PoseFix.offsets_px`), or from zero.
        """
        if covariance is None:
            covariance = self.components.acquisition.covariance(
                np.diag([0.005**2] * 3 + [0.05**2] * 3))
        track = self.tracks[name]
        xyz, rpy = xyz_rpy_from_pose(np.asarray(T_base_part, dtype=float))
        state = np.concatenate([xyz, rpy, np.zeros(POSE_DIM)])
        adaptive = AdaptiveNoise() if self.config.adaptive_noise else None
        model, offsets = None, None
        if self.config.camera_offsets_px > 0:  # the cameras' offsets outlive a track
            model = CameraOffsets(len(self.cameras), self.config.camera_offsets_px,
                                  self.config.camera_offsets_walk_px)
            offsets = _offset_prior(model, None if track.ekf is None else track.ekf.offsets,
                                    offsets)
        track.ekf = PoseEKF(self.components.motion, state, covariance, t, adaptive, model, offsets)
        track.last_update = float(t)
        track.lost = False
        track.coasted = True  # a new filter's first update needs the resume support too
        track.unseen_since = np.inf
        track.held_at = None
        track.monitor.reset(t)

    def step(
        self,
        observed: Any,
        joints: Mapping[str, np.ndarray] | None,
        t: float,
        openings: Mapping[str, float] | None = None,
        holders: Mapping[str, np.ndarray] | None = None,
        stamps: Any = None,
        supports: Mapping[str, np.ndarray] | None = None,
    ) -> TrackerFrame:
        """Process one vision frame at time ``t`` (s): the paper's Fig. 5 (module docstring).

        ``observed``: what the sensors took, one entry per camera (sequence in camera order, or
        mapping by camera name; None for a camera that gave nothing, or for the whole frame), each
        passed to the extractor: an image for the corner extractor, or whatever the extractor
        measures; ``joints``: robot name -> joint vector (m, rad) and ``openings``: robot name ->
        jaw opening (m), for the visibility source; ``holders`` and ``supports`` (the
        kinematic prior, optional; :mod:`.prior`): part name -> ``T_base_part`` where what
        holds the part rigidly this frame puts it (a gripper closed on it: its TCP from the
        joint measurements times the grasp's ``T_tcp_part``), and of a part lying on the level
        support it rests on this frame (a conveyor's belt, a table). A held part is carried
        by its holder's motion (:meth:`PoseEKF.predict_carried`), kept with the holder's pose
        (:func:`~.prior.fusion.fuse_priors`, ``TrackerConfig.hold_std``) and never lost; one
        never tracked starts there (``TrackerConfig.held_std``); one let go comes to rest, and
        is looked for where it was let go. A lying part keeps its support's height, roll and
        pitch (``TrackerConfig.rest_std``), and a lost one is searched for on its plane (a fix
        off the prior refused: :func:`~.prior.fusion.fits_prior`). ``stamps`` (optional): each
        camera's exposure time (s, at most ``t``; a sequence in camera order or a mapping by
        camera name, None for ``t``), for cameras not triggered together: the filter is
        predicted to ``t`` and each camera measures the pose of its own exposure
        (:class:`~cellsight.tracking.measurement.Observation` ``lag_s``).
        """
        lags = _lags(stamps, self.cameras, t)
        timer = StageTimer()
        records = {}
        with timer("total"):
            with timer("ekf"):
                poses = self._predict(t, holders or {}, supports or {})
            with timer("occlusion"):
                views = self.predictor.predict(joints, poses, openings) if poses else {}
            crowd = visible_pixels(views, len(self.cameras))

            def look(name: str, T_base_part: np.ndarray) -> Views:
                with timer("occlusion"):
                    return self.predictor.predict(joints, {**poses, name: T_base_part}, openings)

            tracked, acquiring = [], []
            for name, track in self.tracks.items():
                part_views = views.get(name)
                rec = records[name] = track.frame_record(name, part_views, len(self.cameras))
                if part_views is not None:
                    context = StepContext(t, observed, crowd, timer, track, rec, look, lags)
                    (acquiring if track.acquiring else tracked).append(context)
            records.update(self.updater.step_all(tracked))
            for context in acquiring:
                records[context.rec.name] = with_held_out(self.camera_check,
                                                          self.acquirer.acquire, context)
        masks = [self.unknown.mask(c, t) for c in range(len(self.cameras))]
        return TrackerFrame(float(t), records, timer.seconds, _grabbed(records, len(self.cameras)),
                            masks)

    def recalibrate(self, index: int, camera: Camera) -> None:
        """Take ``camera`` for camera ``index`` from now on (its calibration refined, e.g. by
        :mod:`.registration`): in the measurement model, the windows, the search and the camera
        check, and in the visibility source where it can
        (:class:`~cellsight.visibility.Recalibrating`: the BSP predictors and the projection
        baseline). The cameras then count as registered
        (``TrackerConfig.awaiting_registration``)."""
        self.cameras[index] = camera
        self.registered = True
        self.camera_check.cameras[index] = camera
        self.models[index] = self.components.measurement(camera, self.config.sigma_px)
        if isinstance(self.predictor, Recalibrating):
            self.predictor.recalibrate(index, camera)

    def _predict(self, t: float, holders: Mapping[str, np.ndarray],
                 supports: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Predict every tracked part to time ``t`` (:meth:`~.part_track.PartTrack.predict_to`);
        the pose each is looked for at."""
        poses = {}
        for name, track in self.tracks.items():
            pose = track.predict_to(t, holders.get(name), supports.get(name),
                                    self.components.loss, self.config)
            if pose is not None:
                poses[name] = pose
        return poses


def _lags(stamps: Any, cameras: Sequence[Camera], t: float) -> np.ndarray:
    """(C,) s: how long before ``t`` each camera was exposed, from ``stamps`` (see
    :meth:`Tracker.step`); a stamp after ``t`` or not finite is a ``ValueError`` naming the
    camera."""
    lags = np.zeros(len(cameras))
    if stamps is None:
        return lags
    for c in range(len(cameras)):
        stamp = observed_of(stamps, cameras, c)
        if stamp is None:
            continue
        lag = float(t) - float(stamp)
        if not (np.isfinite(lag) and lag >= -1e-9):
            raise ValueError(f"Tracker.step: camera {cameras[c].name!r} stamp {stamp!r} must "
                             f"be a finite time at or before the frame's t = {t}")
        lags[c] = max(lag, 0.0)
    return lags


def _grabbed(records: Mapping[str, PartFrame], n_cameras: int) -> np.ndarray:
    """Per camera, the fraction of its pixels grabbed by every part's windows."""
    grabbed = np.zeros(n_cameras)
    for rec in records.values():
        for c, plan in enumerate(rec.windows):
            if plan is not None:
                grabbed[c] += plan.fraction
    return grabbed


def _offset_prior(model: CameraOffsets, kept: tuple[np.ndarray, np.ndarray] | None,
                  found: dict[int, np.ndarray] | None) -> tuple[np.ndarray, np.ndarray] | None:
    """A new filter's camera offsets: the earlier filter's (mean and covariance), else the
    acquisition's (with the prior's covariance), else None (the prior)."""
    if kept is not None or not found:
        return kept
    mean, cov = model.prior()
    for c, shift in found.items():
        mean[2 * c:2 * c + 2] = shift
    return model.in_gauge(mean), cov

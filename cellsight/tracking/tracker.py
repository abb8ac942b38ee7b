"""The closed visual tracking loop of the paper's Fig. 5, one :meth:`Tracker.step` per frame.

The tracker only wires its parts (:class:`~cellsight.tracking.config.TrackerParts`, each a
protocol of :mod:`.interfaces` with its default in its own module):

1. the motion model (:mod:`.motion`; or the holder's measured motion with the kinematic prior)
   predicts every tracked part (:class:`~cellsight.tracking.ekf.PoseEKF`), within the track
   health rule's coasting time (:mod:`.loss`);
2. the visibility source (:class:`cellsight.visibility.VisibilitySource`: the BSP predictor)
   predicts, at the predicted poses, which features each camera sees; every tracked part is
   passed, so parts can hide each other;
3. per part: a part not tracked yet, or lost, is acquired (:mod:`.acquisition`: windows at
   the guess or the last prediction, or where it was let go by a gripper; a part that a
   gripper holds starts where the gripper holds it, ``holders`` of :meth:`Tracker.step`;
   failing that, at most every ``search.every_s``, the
   whole-image search over its support plane, :mod:`.search`, each of its best candidates
   tried with the same windows and PnP, the confirmed fix of the most points taken; a fix
   stands only when narrow windows where it predicts the part's features confirm it);
   otherwise
   the selector chooses among the usable features (:mod:`.eligibility`, :mod:`.selection`),
   the window planner places their windows (:mod:`.windowing`), the extractor finds them in
   what the sensors took (:mod:`.extraction`), the gate (:mod:`.gate`) screens the innovations
   and the EKF updates with the accepted ones (:mod:`.measurement`, :mod:`.ekf`); the track's
   health monitor (:mod:`.health`) takes the frame's outcome, and a tracked part whose figures
   pass its limits is degraded (so is every tracked part while the cameras await their
   registration to an arm: ``TrackerConfig.awaiting_registration``); the unknown-occluder
   map (:mod:`.unknown`, shared by the parts; off by default) learns from the features not
   found, or rejected where their camera accepted none, and no feature it covers is selected
   or used for acquisition; the camera check (:mod:`.camera_check`, shared) drops a camera
   whose innovations are consistently biased while another's are not, and re-estimates its
   pose.

Within a step, each part's work carries one :class:`StepContext`. Measured pixels are as in the
image (distorted); the camera undistorts them before the update. Stage times: :mod:`.timing`;
statuses: :mod:`.status`; records: :mod:`.records`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.transforms import xyz_rpy_from_pose
from cellsight.tracking.acquire import Acquirer
from cellsight.tracking.acquisition import twin_turns
from cellsight.tracking.camera_check import CameraCheck, CheckFrame
from cellsight.tracking.config import TrackerConfig, TrackerParts
from cellsight.tracking.ekf import (
    AdaptiveNoise,
    PoseEKF,
    UpdateReport,
)
from cellsight.tracking.eligibility import NearOccluderHold
from cellsight.tracking.extraction import CornerExtractor
from cellsight.tracking.gate import SupportedGate
from cellsight.tracking.grabbing import grabbed
from cellsight.tracking.interfaces import CornerDetector, Extractor, OccluderMap
from cellsight.tracking.measuring import Measurer
from cellsight.tracking.motion import POSE_DIM
from cellsight.tracking.offsets import CameraOffsets
from cellsight.tracking.part_track import (
    PartTrack,
    StepContext,
    cameras_grabbed,
    observed_of,
    record_estimate,
    visible_pixels,
)
from cellsight.tracking.prior.fusion import (
    hold_along_sight,
    off_holder,
)
from cellsight.tracking.records import PartFrame, TrackerFrame
from cellsight.tracking.selection import camera_resolution
from cellsight.tracking.status import TrackStatus
from cellsight.tracking.timing import StageTimer
from cellsight.visibility import Views, VisibilitySource

UNREGISTERED = "cameras not registered yet"  # the reason while awaiting the registration


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
        self._models = [self.components.measurement(c, self.config.sigma_px)
                        for c in self.cameras]
        self.unknown = self.components.unknown.maps(self.cameras)
        self.measurer = Measurer(self.cameras, self.components.windows,
                                 extractor or CornerExtractor(), self._models, self.unknown)
        self.camera_check = self.components.cameras.check(self.cameras)
        self.acquirer = Acquirer(self)
        self._registered = not self.config.awaiting_registration
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
        track.monitor.reset()

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
        jaw opening (m), for the visibility source; ``holders`` (the kinematic prior, optional):
        part name -> ``T_base_part`` where what holds the part rigidly this frame puts it (a
        gripper closed on it: its TCP from the joint measurements times the grasp's
        ``T_tcp_part``); a part held at this frame and the last one is predicted by the holder's
        motion (:meth:`PoseEKF.predict_carried`) instead of its motion model, a held part's
        estimate is kept with the holder's pose (:func:`~.prior.fusion.fuse_priors`,
        ``TrackerConfig.hold_std``; along a lone camera's sight line,
        :func:`~.prior.fusion.hold_along_sight`) and is never lost, a held part never
        tracked starts there (``TrackerConfig.held_std``), one let go comes to rest (its rates
        zeroed: it no longer moves with the holder, and stays still), and one let go while not
        tracked is looked for where it was let go; ``stamps`` (optional): each camera's exposure
        time (s, at most ``t``; a sequence in camera order or a mapping by camera name, None for
        ``t``), for cameras not triggered together: the filter is predicted to ``t`` and each
        camera measures the pose of its own exposure
        (:class:`~cellsight.tracking.measurement.Observation` ``lag_s``); ``supports`` (the
        kinematic prior, optional): part name -> ``T_base_part`` of the part lying on the level
        support it rests on this frame (a conveyor's belt, a table): a tracked part not held keeps
        that height, roll and pitch (:meth:`PoseEKF.fuse_prior`, ``TrackerConfig.rest_std``), and a
        lost one is searched for on that support's plane (a fix off it refused, ``LYING_TOL``).
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

            for name, track in self.tracks.items():
                part_views = views.get(name)
                rec = records[name] = track.frame_record(name, part_views, len(self.cameras))
                if part_views is not None:
                    context = StepContext(t, observed, crowd, timer, track, rec, look, lags)
                    part_step = self.acquirer.acquire if track.acquiring else self._track
                    records[name] = _with_held_out(self.camera_check, part_step, context)
        masks = [self.unknown.mask(c, t) for c in range(len(self.cameras))]
        return TrackerFrame(float(t), records, timer.seconds, _grabbed(records, len(self.cameras)),
                            masks)

    def recalibrate(self, index: int, camera: Camera) -> None:
        """Take ``camera`` for camera ``index`` from now on (its calibration refined, e.g. by
        :mod:`.registration`): in the measurement model, the windows, the search and the camera
        check, and in the visibility source where it can (its ``recalibrate(index, camera)``:
        the BSP predictors and the projection baseline have one). The cameras then count as
        registered (``TrackerConfig.awaiting_registration``)."""
        self.cameras[index] = camera
        self._registered = True
        self.camera_check.cameras[index] = camera
        self._models[index] = self.components.measurement(camera, self.config.sigma_px)
        move = getattr(self.predictor, "recalibrate", None)
        if move is not None:
            move(index, camera)

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

    def _track(self, context: StepContext) -> PartFrame:
        """Select, window, extract, gate and update (the paper's loop), then the health
        monitor: tracking, or degraded when it finds reasons. Returns the part's record."""
        rec, track, timer = context.rec, context.track, context.timer
        ekf = track.ekf
        _shift_by_offsets(rec, ekf)
        with timer("selection"):
            usable = self.measurer.usable(context, ekf.t)
            resolution = _resolution(self.cameras, track)
            sel = self.components.selector.select(rec.pixels, usable, resolution)
            rec.selection, rec.selected = sel, sel.selected

        def covariance(c: int, idx: np.ndarray) -> np.ndarray:
            return ekf.innovation_covariance(self._models[c], c, track.points[idx])[1]

        obs = self.measurer.measure(context, covariance)
        looked = rec.selected & cameras_grabbed(context.observed, self.cameras)[:, None]
        check, loss = self.camera_check, self.components.loss
        in_filter = _in_filter(check)
        counted = looked & in_filter[:, None]
        with timer("ekf"):
            gate = self.components.gate
            if track.coasted:
                support = loss.resume_support(int(counted.sum()))
                gate = SupportedGate(gate, max(self.config.resume_support, support))
            report = ekf.update([o for o in obs if in_filter[o.camera_index]], gate)
            track.coasted = report.n_accepted == 0
            if track.holder is not None:
                hold_along_sight(ekf, track.holder, self.cameras, report,
                                  self.config.hold_std[0])
            _record_update(rec, report)
            rec.health = track.monitor.update(context.t, rec.visible, counted, rec.measured,
                                              rec.rejected, rec.mahalanobis2, rec.unknown,
                                              off_holder(ekf, track.holder))
            if not self._registered:
                rec.health = replace(rec.health, reasons=(*rec.health.reasons, UNREGISTERED))
            unknown = self.components.unknown
            if report.n_accepted >= unknown.min_accepted:
                track.confirmed = context.t
            if context.t - track.confirmed <= unknown.trust_s:
                _learn_unknown(self.unknown, context.t, rec, counted)
        in_view = any(cam.in_image(rec.pixels[c]).any() for c, cam in enumerate(self.cameras))
        in_vain = loss.in_vain(int(counted.sum()), report.n_accepted, in_view)
        if in_vain is not None:
            track.unseen_since = min(track.unseen_since, context.t) if in_vain else np.inf
        if report.n_accepted:
            track.last_update = ekf.t
            track.held_at = None  # the filter knows where it is
            rec.status = TrackStatus.DEGRADED if rec.health.reasons else TrackStatus.TRACKING
        record_estimate(rec, ekf)
        _check_cameras(self.camera_check, self.extractor, self.cameras, context, looked,
                       report.n_accepted > 0)
        return rec


def _learn_unknown(unknown: OccluderMap, t: float, rec: PartFrame, looked: np.ndarray) -> None:
    """Teach the ``unknown``-occluder map this frame's failures: per camera, the predicted
    pixels of the looked-for features not found, or rejected where the camera had none of
    the part's corners accepted (:mod:`.unknown`)."""
    found = np.isfinite(rec.measured[..., 0])
    blinded = ~(found & ~rec.rejected).any(axis=1, keepdims=True)
    failed = looked & (~found | (rec.rejected & blinded))
    for c in np.flatnonzero(failed.any(axis=1)):
        unknown.learn(int(c), t, rec.pixels[c, failed[c]])


def _resolution(cameras: Sequence[Camera], track: PartTrack) -> np.ndarray:
    """Per camera: pixels per metre at the estimated part's centroid (focal / depth), the
    selection's weight of each camera."""
    T = track.ekf.pose
    return camera_resolution(cameras, track.points.mean(axis=0) @ T[:3, :3].T + T[:3, 3])


def _shift_by_offsets(rec: PartFrame, ekf: PoseEKF) -> None:
    """With camera offsets (:mod:`.offsets`), move each camera's predicted pixels by the
    filter's estimate of its offset, so that the windows are centred where the camera shows the
    features, not where its calibration says they are."""
    offsets = ekf.offsets
    if offsets is not None:
        rec.pixels += offsets[0].reshape(-1, 1, 2)


def _record_update(rec: PartFrame, report: UpdateReport) -> None:
    """Record an update's per-feature innovations, distances and rejections."""
    if len(report.accepted):
        c, f = report.camera_index, report.feature_ids
        rec.innovation[c, f] = report.innovation
        rec.mahalanobis2[c, f] = report.mahalanobis2
        rec.rejected[c, f] = ~report.accepted


def _in_filter(check: CameraCheck) -> np.ndarray:
    """(C,) bool: the cameras whose measurements the filter takes (:meth:`CameraCheck.usable`):
    only their features count as looked for in the health figures, the first update's support,
    the unknown-occluder map and the loss rule (a dropped camera's features, not found where
    the estimate predicts them, would keep a track coasting that the other camera holds)."""
    return np.array([check.usable(c) for c in range(len(check.cameras))], dtype=bool)


def _with_held_out(check: CameraCheck, step: Callable[[StepContext], PartFrame],
                   context: StepContext) -> PartFrame:
    """``step(context)``'s record, with the cameras the camera check held out of the filter as
    the step began (``PartFrame.held_out``; the check moves on at the step's end)."""
    held_out = ~_in_filter(check)
    rec = step(context)
    rec.held_out = held_out
    return rec


def _check_cameras(check: CameraCheck, extractor: Extractor, cameras: Sequence[Camera],
                   context: StepContext, looked: np.ndarray, updated: bool) -> None:
    """Feed the camera check (:mod:`.camera_check`) this frame of the part (``looked``: the
    (C, F) features looked for; ``updated``: the usable cameras updated the estimate)."""
    rec, T = context.rec, context.track.ekf.pose
    detect = extractor.detect if isinstance(extractor, CornerDetector) else None

    def corners(c: int) -> np.ndarray | None:
        seen = observed_of(context.observed, cameras, c)
        if detect is None or seen is None:
            return None
        with context.timer("grab"):
            seen = grabbed(seen)
        return detect(seen)

    check.update(context.t, CheckFrame(
        rec.innovation, rec.measured, rec.pixels, rec.visible, looked, updated,
        context.track.points @ T[:3, :3].T + T[:3, 3], corners))


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

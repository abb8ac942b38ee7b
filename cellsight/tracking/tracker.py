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
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from cellsight.camera import Camera
from cellsight.geometry.transforms import invert_pose, xyz_rpy_from_pose
from cellsight.tracking.acquisition import rates_covariance, twin_turns
from cellsight.tracking.camera_check import CameraCheck, CheckFrame
from cellsight.tracking.config import TrackerConfig, TrackerParts
from cellsight.tracking.ekf import (
    HELD,
    RESTING,
    STILL,
    SUPPORT_RATES,
    AdaptiveNoise,
    PoseEKF,
    UpdateReport,
)
from cellsight.tracking.eligibility import NearOccluderHold
from cellsight.tracking.extraction import CornerExtractor
from cellsight.tracking.gate import SupportedGate
from cellsight.tracking.grabbing import grabbed
from cellsight.tracking.interfaces import Acquisition, Extractor, OccluderMap, TrackMonitor
from cellsight.tracking.measurement import Observation
from cellsight.tracking.motion import POSE_DIM
from cellsight.tracking.offsets import CameraOffsets
from cellsight.tracking.pnp import PoseFix
from cellsight.tracking.records import PartFrame, TrackerFrame
from cellsight.tracking.selection import camera_resolution
from cellsight.tracking.status import TrackStatus
from cellsight.tracking.timing import StageTimer
from cellsight.visibility import CameraVisibility, Views, VisibilitySource

TWIN_VERTICAL = np.cos(np.radians(10.0))  # a twin's turn axis this close to the vertical
HOLD_SIGMAS = 3.0  # a held part's estimate this many holder sigmas off has left the grasp
ACROSS_SIGHT = 1.0  # m: the sigma across a lone camera's sight line of the hold along it
LYING_TOL = (0.015, 0.15)  # m, rad: a fix this far from its support's height and tilt is wrong
UNREGISTERED = "cameras not registered yet"  # the reason while awaiting the registration
Crowd = list[tuple[np.ndarray, dict[str, tuple[int, np.ndarray]]]]
"""Per camera: (M, 2) predicted pixels of every visible feature of every part (what the windows
must avoid), and each part's (first row, its visible feature indices) in them."""


@dataclass
class _Track:
    """One workpiece's track: feature points (F, 3) in the part frame, the acquisition guess
    (also the ``support`` pose of the whole-image search, until the kinematic prior gives the
    support the part lies on), the near-occluder hold, the health monitor, the filter, the
    last accepted measurement's time (s), the holder's pose of the
    part (the last frame's, this frame's once predicted), where a gripper holds the part or
    last held it since the filter last accepted a measurement (``held_at``, ``T_base_part``),
    whether the last tracked frame accepted no measurement, or the filter has just started
    (``coasted``: its next update needs the resume support, :mod:`.loss`), the last time (s)
    enough were accepted to confirm the estimate for the unknown-occluder map (``confirmed``),
    since when its features were looked for in vain (``unseen_since``, s; :mod:`.loss`) and
    when it was last searched for in the whole images (``searched``, s); the part's ``twins``
    (:func:`~cellsight.tracking.acquisition.twin_turns`); with the kinematic prior, the pose
    of the part lying on its support this frame (``lying``, None: held, or not known) and
    whether a holder let it go (``let_go``, until one holds it again)."""

    points: np.ndarray
    guess: np.ndarray | None
    hold: NearOccluderHold
    monitor: TrackMonitor
    ekf: PoseEKF | None = None
    base_guess: np.ndarray | None = None
    attempts: int = 0
    last_update: float = -np.inf
    lost: bool = False
    holder: np.ndarray | None = None
    held_at: np.ndarray | None = None
    coasted: bool = False
    confirmed: float = -np.inf
    unseen_since: float = np.inf
    searched: float = -np.inf
    support: np.ndarray | None = None
    twins: list[np.ndarray] = field(default_factory=list)
    lying: np.ndarray | None = None
    let_go: bool = False

    @property
    def acquiring(self) -> bool:
        """The part is to be acquired this frame: never acquired, or lost."""
        return self.ekf is None or self.lost

    def empty_record(self, name: str, status: TrackStatus, n_cameras: int) -> PartFrame:
        """A record of this track with nothing predicted or measured (:meth:`PartFrame.empty`)."""
        ekf = self.ekf
        return PartFrame.empty(name, status, n_cameras, len(self.points),
                               None if ekf is None else ekf.state,
                               None if ekf is None else ekf.covariance,
                               None if ekf is None else ekf.pose)

    def search_on(self, acquisition: Acquisition) -> None:
        """No fix this frame: a part never acquired is looked for at the next guess."""
        if self.ekf is None and self.guess is not None:
            if self.base_guess is None:
                self.base_guess = self.guess
            self.attempts += 1
            self.guess = acquisition.guess(self.base_guess, self.attempts)


@dataclass(frozen=True)
class StepContext:
    """One part's work in one :meth:`Tracker.step`: the frame's time ``t`` (s), what the
    sensors took (``observed``, as given to the step), the ``crowd`` of predicted pixels
    (:data:`Crowd`), the stage ``timer``, the part's ``track`` and its ``rec`` being filled;
    ``look(name, T_base_part)``: the visibility source's answer with that part at that pose
    (the others at their predictions); ``lags`` (C,) s: how long before ``t`` each camera was
    exposed."""

    t: float
    observed: Any
    crowd: Crowd
    timer: StageTimer
    track: _Track
    rec: PartFrame
    look: Callable[[str, np.ndarray], Views]
    lags: np.ndarray


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
        self.extractor = extractor or CornerExtractor()
        self._models = [self.components.measurement(c, self.config.sigma_px)
                        for c in self.cameras]
        self.unknown = self.components.unknown.maps(self.cameras)
        self.camera_check = self.components.cameras.check(self.cameras)
        self._registered = not self.config.awaiting_registration
        guesses = dict(initial_poses or {})
        names = [c.name for c in self.cameras]
        self.tracks = {
            name: _Track(points, guesses.get(name),
                         NearOccluderHold(self.config.near_occluder_hold_s),
                         self.components.health.monitor(names), support=guesses.get(name),
                         twins=twin_turns(points))
            for name, pts in parts.items()
            for points in [np.asarray(pts, dtype=float).reshape(-1, 3)]
        }

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
        estimate is kept with the holder's pose (:func:`_hold`, ``TrackerConfig.hold_std``; along a
        lone camera's sight line, :func:`_hold_along_sight`) and is never lost, a held part never
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
        lost one is searched for on that support's plane (an acquisition off it is refused,
        ``LYING_TOL``).
        """
        lags = _lags(stamps, self.cameras, t)
        timer = StageTimer()
        records = {}
        with timer("total"):
            with timer("ekf"):
                poses = self._predict(t, holders or {}, supports or {})
            with timer("occlusion"):
                views = self.predictor.predict(joints, poses, openings) if poses else {}
            crowd = _visible_pixels(views, len(self.cameras))

            def look(name: str, T_base_part: np.ndarray) -> Views:
                with timer("occlusion"):
                    return self.predictor.predict(joints, {**poses, name: T_base_part}, openings)

            for name, track in self.tracks.items():
                part_views = views.get(name)
                rec = records[name] = self._record(name, track, part_views)
                if part_views is not None:
                    context = StepContext(t, observed, crowd, timer, track, rec, look, lags)
                    part_step = self._acquire if track.acquiring else self._track
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
        """Predict every tracked part to time ``t`` (on its support, if it rests on one); the
        pose each is looked for at (the prediction, or the acquisition guess of a part never
        acquired; for a part to be acquired that a holder holds or let go, where it holds it or
        let it go)."""
        poses = {}
        loss = self.components.loss
        for name, track in self.tracks.items():
            holder, lying = holders.get(name), supports.get(name)
            track.lying = None if holder is not None or lying is None else np.asarray(
                lying, dtype=float)
            track.let_go = holder is None and (track.let_go or track.holder is not None)
            if track.ekf is not None:
                if holder is not None and track.holder is not None:
                    track.ekf.predict_carried(t, holder @ invert_pose(track.holder),
                                              self.config.carried_noise)
                elif loss.coasts(t, track.last_update):
                    track.ekf.predict(t, at_rest=track.holder is not None)  # let go: at rest
                _fuse_priors(track, t, holder, self.config)
                track.lost = loss.lost(t, track.last_update, track.unseen_since)
                poses[name] = track.ekf.pose
            elif track.guess is not None:
                poses[name] = track.guess
            if track.lying is not None:  # the whole-image search's plane
                track.support = track.lying
            track.holder = None if holder is None else np.asarray(holder, dtype=float)
            if track.holder is not None:
                track.held_at = track.holder
            if track.acquiring and track.held_at is not None:
                poses[name] = track.held_at
        return poses

    def _record(self, name: str, track: _Track,
                views: list[CameraVisibility] | None) -> PartFrame:
        """One part's record before its measurements: waiting (nothing predicted), to be
        acquired (waiting or lost) or coasting, with the visibility source's answer."""
        C = len(self.cameras)
        if views is None:
            return track.empty_record(name, TrackStatus.WAITING, C)
        if track.acquiring:
            status = TrackStatus.LOST if track.ekf is not None else TrackStatus.WAITING
        else:
            status = TrackStatus.COASTING
        rec = track.empty_record(name, status, C)
        rec.set_views(views)
        return rec

    def _track(self, context: StepContext) -> PartFrame:
        """Select, window, extract, gate and update (the paper's loop), then the health
        monitor: tracking, or degraded when it finds reasons. Returns the part's record."""
        rec, track, timer = context.rec, context.track, context.timer
        ekf = track.ekf
        _shift_by_offsets(rec, ekf)
        with timer("selection"):
            usable = self._usable(context, ekf.t)
            resolution = _resolution(self.cameras, track)
            sel = self.components.selector.select(rec.pixels, usable, resolution)
            rec.selection, rec.selected = sel, sel.selected

        def covariance(c: int, idx: np.ndarray) -> np.ndarray:
            return ekf.innovation_covariance(self._models[c], c, track.points[idx])[1]

        obs = self._measure(context, covariance)
        looked = rec.selected & _cameras_grabbed(context.observed, self.cameras)[:, None]
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
                _hold_along_sight(ekf, track.holder, self.cameras, report,
                                  self.config.hold_std[0])
            _record_update(rec, report)
            rec.health = track.monitor.update(context.t, rec.visible, counted, rec.measured,
                                              rec.rejected, rec.mahalanobis2, rec.unknown,
                                              _off_holder(ekf, track.holder))
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
        _record_estimate(rec, ekf)
        _check_cameras(self.camera_check, self.extractor, self.cameras, context, looked,
                       report.n_accepted > 0)
        return rec

    def _usable(self, context: StepContext, t_hold: float | None) -> np.ndarray:
        """(C, F) bool: the features that may be measured: predicted visible, not held back
        next to an occluder at time ``t_hold`` (s; :mod:`.eligibility`; None, for a pose
        acquisition tries: not flagged next to one at that pose) and not under an unknown
        occluder (recorded in ``rec.unknown``)."""
        rec = context.rec
        for c in range(len(self.cameras)):
            rec.unknown[c] = rec.visible[c] & self.unknown.covered(c, rec.pixels[c], context.t)
        if t_hold is None:  # the track's hold is of its own predictions, not of a trial pose's
            return rec.visible & ~rec.near_occluder & ~rec.unknown
        return context.track.hold.usable(rec.visible, rec.near_occluder, t_hold) & ~rec.unknown

    def _acquire(self, context: StepContext) -> PartFrame:
        """A fix at the guess or the last prediction, else from the whole-image search (module
        docstring); the filter starts from it. Returns the record of the windows that gave the
        fix (or of the guess's, when there is none)."""
        track, acquisition = context.track, self.components.acquisition
        if track.holder is not None:  # held, not tracked: it is where the gripper holds it
            rec = context.rec
            self.initialise(rec.name, track.held_at, context.t, acquisition.covariance(
                np.diag(np.repeat(np.square(self.config.held_std), 3))))
            rec.status = TrackStatus.ACQUIRED
            _record_estimate(rec, track.ekf)
            return rec
        fix = self._fix(context, acquisition.window_px, coarse=True)
        verified = None if fix is None else self._verify(context, fix)
        if verified is not None and not _lies_on(track.lying, verified[1].T_base_part):
            verified = None  # off the support it lies on: a wrong pose the corners fit
        searched = verified is None
        if searched:
            verified = self._search(context)
        if verified is not None:
            verified = _best_twin(lambda fix: self._verify(context, fix, searched), track.twins,
                                  verified)
        if verified is None:
            track.search_on(acquisition)
            return context.rec
        context, fix = verified
        rec = context.rec
        covariance = acquisition.start(fix)
        if track.lying is not None:  # on its support: as fast as a support moves it, at most
            covariance[POSE_DIM:, POSE_DIM:] = rates_covariance(self.config.support_speed)
        self.initialise(rec.name, fix.T_base_part, context.t, covariance, fix.offsets_px)
        for c, f in fix.dropped:
            rec.rejected[c, f] = True
        rec.status = TrackStatus.ACQUIRED
        _record_estimate(rec, track.ekf)
        return rec

    def _fix(self, context: StepContext, size_px: float, coarse: bool = False,
             guess: np.ndarray | None = None, on_support: bool = False) -> PoseFix | None:
        """Windows of ``size_px`` (px) on every usable feature of the record's prediction, then
        a fix (:mod:`.acquisition`; ``coarse``: a first one, to be verified; ``guess``: the
        pose of that prediction, to seed the fix where it is already near; ``on_support``: a
        part lying on its support may be fitted there, the search's candidates and their
        verification), or None. A camera the camera check holds out of the filter (dropped
        as knocked, or awaiting its second look) is held out of the fix too."""
        context.rec.selected = self._usable(context, None)

        def covariance(c: int, idx: np.ndarray) -> np.ndarray:
            return np.zeros((len(idx), 2, 2))

        usable = self.camera_check.usable
        obs = [o for o in self._measure(context, covariance, size_px) if usable(o.camera_index)]
        lying = context.track.lying
        support = None if lying is None or not on_support else (lying, self.config.rest_std)
        with context.timer("ekf"):
            return self.components.acquisition.fix(obs, self.config.sigma_px, coarse, guess,
                                                   support)

    def _verify(self, context: StepContext, fix: PoseFix,
                on_support: bool = False) -> tuple[StepContext, PoseFix] | None:
        """The fix checked against every feature it predicts (:mod:`.acquisition`): narrow
        windows where it predicts them (moved by the cameras' offsets it estimated, if any), and
        a second fix from what they find (``on_support``: as for :meth:`_fix`); that fix with
        the context of its record, or None when it does not confirm the first."""
        trial = _looked_at(context, fix.T_base_part, len(self.cameras))
        for c, shift in (fix.offsets_px or {}).items():  # where each camera shows the part
            trial.rec.pixels[c] += shift
        again = self._fix(trial, self.components.acquisition.verify_window_px,
                          guess=fix.T_base_part if on_support else None, on_support=on_support)
        if again is None:
            return None
        rec = trial.rec
        used = np.isfinite(rec.measured[..., 0])
        for c, f in again.dropped:
            used[c, f] = False
        looked = rec.selected & _cameras_grabbed(context.observed, self.cameras)[:, None]
        confirmed = self.components.acquisition.confirms(again, looked.sum(axis=1),
                                                         used.sum(axis=1))
        return (trial, again) if confirmed else None

    def _search(self, context: StepContext) -> tuple[StepContext, PoseFix] | None:
        """The whole-image search, when it is due (:mod:`.search`): of its best candidates
        whose windows give a fix of at least ``min_points`` points (seeded by the candidate;
        a part lying on its support may be fitted there, from fewer: :mod:`.acquisition`)
        that verification confirms, the one whose verifying fix has the most points (the
        fewest pixels of RMS among equals; a nearly symmetric part's turned twin fits fewer of
        its features than the part), with the context of its record; None otherwise. A camera
        held out of the filter (:meth:`_fix`) is not searched."""
        search, track, t = self.components.search, context.track, context.t
        acquisition = self.components.acquisition
        detect = getattr(self.extractor, "detect", None)
        observed = [_observed(context.observed, self.cameras, c)
                    if self.camera_check.usable(c) else None for c in range(len(self.cameras))]
        if (search is None or detect is None or track.support is None
                or t - track.searched < search.every_s - 1e-9
                or all(o is None for o in observed)):
            return None
        track.searched = t
        with context.timer("grab"):
            observed = [grabbed(o) for o in observed]
        with context.timer("extraction"):
            corners = [None if o is None else detect(o) for o in observed]
            centres = [track.support[:2, 3]] + ([] if track.ekf is None else
                                                [track.ekf.pose[:2, 3]])
            candidates = search.candidates(self.cameras, track.points, track.support,
                                           np.array(centres), corners)
        confirmed = []
        for candidate in candidates[:search.verify]:
            trial = _looked_at(context, candidate.T_base_part, len(self.cameras))
            fix = self._fix(trial, acquisition.window_px, coarse=True,
                            guess=candidate.T_base_part, on_support=True)
            enough = fix is not None and (acquisition.enough(fix) if fix.on_support
                                          else fix.n_points >= search.min_points)
            if enough:
                verified = self._verify(trial, fix, on_support=True)
                if verified is not None and _lies_on(track.lying, verified[1].T_base_part):
                    confirmed.append(verified)
        return max(confirmed, key=lambda c: (c[1].n_points, -c[1].rms_px), default=None)

    def _measure(self, context: StepContext,
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
                own = _own_rows(*offsets[rec.name], idx)
                plan = self.components.windows.plan(cam, rec.pixels[c, idx], idx,
                                                    covariance(c, idx), crowd, own, size_px)
                rec.windows[c] = plan
            with timer("grab"):
                seen = grabbed(_observed(context.observed, self.cameras, c), plan.boxes)
            with timer("extraction"):
                found = self.extractor.extract(c, seen, plan)
            if not found:
                continue
            ids = np.array(sorted(found), dtype=np.int64)
            px = np.array([found[i] for i in ids], dtype=float).reshape(-1, 2)
            rec.measured[c, ids] = px
            observations.append(Observation(self._models[c], c, ids, track.points[ids],
                                            cam.undistort(px), float(context.lags[c])))
        return observations


def _learn_unknown(unknown: OccluderMap, t: float, rec: PartFrame, looked: np.ndarray) -> None:
    """Teach the ``unknown``-occluder map this frame's failures: per camera, the predicted
    pixels of the looked-for features not found, or rejected where the camera had none of
    the part's corners accepted (:mod:`.unknown`)."""
    found = np.isfinite(rec.measured[..., 0])
    blinded = ~(found & ~rec.rejected).any(axis=1, keepdims=True)
    failed = looked & (~found | (rec.rejected & blinded))
    for c in np.flatnonzero(failed.any(axis=1)):
        unknown.learn(int(c), t, rec.pixels[c, failed[c]])


def _fuse_priors(track: _Track, t: float, holder: np.ndarray | None,
                 config: TrackerConfig) -> None:
    """The kinematic prior's pseudo-measurements of a tracked part at time ``t`` (s;
    :meth:`PoseEKF.fuse_prior`): held, it is kept with its ``holder`` (:func:`_hold`) and never
    lost (the holder measures it); lying on a support, it keeps the support's height, roll and
    pitch (``RESTING``); let go, it stays where it came to rest (``STILL``: every rate zero;
    a wrong corner's update can no longer set it moving). ``config.rest_std`` gives the
    sigmas of the height and the angles and of their rates per second."""
    if holder is not None:
        _hold(track.ekf, holder, config.hold_std)
        track.last_update, track.unseen_since = float(t), np.inf
        return
    h, a = config.rest_std
    if track.lying is not None:
        track.ekf.fuse_prior(track.lying, RESTING, [h, a, a, h, a, a])
        _keep_support_speed(track.ekf, config.support_speed)
    if track.let_go:
        track.ekf.fuse_prior(track.ekf.pose, STILL, [h, h, h, a, a, a])


def _keep_support_speed(ekf: PoseEKF, speed: tuple[float, float]) -> None:
    """A part lying on its support moves no faster than the support does (``speed``: m/s
    across it, rad/s about its normal; ``TrackerConfig.support_speed``): where the filter's
    rates go past that, they are fused at the bound (the nearest rates within it, a tenth of
    the bound as sigma; an inequality constraint held by its active set). In ``harsh`` runs
    re-acquired under the approaching gripper, the first update made 5 mm of disagreement a
    velocity of 0.17 m/s, which carried the estimate 60 mm off while it coasted."""
    lin, ang = speed
    rates = ekf.state[POSE_DIM:].copy()
    across, turn = float(np.hypot(rates[0], rates[1])), float(rates[5])
    if across <= lin and abs(turn) <= ang:
        return
    rates[:2] *= min(1.0, lin / max(across, 1e-12))
    rates[5] = np.clip(turn, -ang, ang)
    ekf.fuse_prior(ekf.pose, SUPPORT_RATES, [0.1 * lin, 0.1 * lin, 0.1 * ang], rates=rates)


def _lies_on(lying: np.ndarray | None, T_base_part: np.ndarray) -> bool:
    """Whether a pose found for a part lies on the support the kinematic prior says it lies on
    (``lying``: ``T_base_part`` there; None: nothing known): its height within
    ``LYING_TOL[0]`` (m) and its tilt from the lying pose within ``LYING_TOL[1]`` (rad)."""
    if lying is None:
        return True
    R = T_base_part[:3, :3] @ lying[:3, :3].T
    tilt = float(np.arccos(np.clip(R[2, 2], -1.0, 1.0)))
    return abs(T_base_part[2, 3] - lying[2, 3]) <= LYING_TOL[0] and tilt <= LYING_TOL[1]


def _hold(ekf: PoseEKF, holder: np.ndarray, std: tuple[float, float]) -> None:
    """Keep a held part's estimate with its holder's pose ``holder`` (the kinematic prior;
    ``std``: its one sigma, m and rad): where the filter knows the pose less well than the
    holder does, fuse the holder's pose; where the estimate is more than ``HOLD_SIGMAS`` of
    them from it (wrong corners carried it off, or the cameras' shared calibration error
    did), forget it and take the holder's. In between the images alone update it: a holder's
    error is a bias, and fused every frame it would soon outweigh every camera."""
    T = ekf.pose
    moved = np.linalg.norm(T[:3, 3] - holder[:3, 3]) / std[0]
    turned = Rotation.from_matrix(T[:3, :3].T @ holder[:3, :3]).magnitude() / std[1]
    P = ekf.covariance
    wide = (np.linalg.eigvalsh(P[:3, :3])[-1] > std[0] ** 2
            or np.linalg.eigvalsh(P[3:6, 3:6])[-1] > std[1] ** 2)
    off = max(moved, turned) > HOLD_SIGMAS
    if wide or off:
        ekf.fuse_prior(holder, HELD, np.repeat(std, 3), forget=off)


def _hold_along_sight(ekf: PoseEKF, holder: np.ndarray, cameras: Sequence[Camera],
                      report: UpdateReport, std: float) -> None:
    """A held part that one camera alone updated (``report``): fuse its ``holder``'s position
    along that camera's line of sight to it, with one sigma ``std`` (m; ``ACROSS_SIGHT``
    across it: no prior there). One camera measures the part across its sight line well and
    along it hardly at all: there the estimate drifted while carried (5-8 mm over 10 s with
    a knocked camera dropped, the gripper exact), and the holder, fused only once the estimate
    was ``HOLD_SIGMAS`` off (:func:`_hold`), let it. Along that line the holder is all there
    is to know, so it is fused every such frame; across it the camera rules."""
    seen = np.unique(report.camera_index[report.accepted])
    if len(seen) != 1:
        return
    sight = ekf.state[:3] - cameras[int(seen[0])].center
    along = np.outer(sight, sight) / float(sight @ sight)
    covariance = std**2 * along + ACROSS_SIGHT**2 * (np.eye(3) - along)
    ekf.fuse_prior(holder, HELD[:3], None, covariance=covariance)


def _off_holder(ekf: PoseEKF, holder: np.ndarray | None) -> float | None:
    """A held part's estimate's distance (m) from its ``holder``'s pose, for the health
    monitor; None when it is not held."""
    return None if holder is None else float(np.linalg.norm(ekf.pose[:3, 3] - holder[:3, 3]))


def _best_twin(verify: Callable[[PoseFix], tuple[StepContext, PoseFix] | None],
               twins: Sequence[np.ndarray],
               verified: tuple[StepContext, PoseFix]) -> tuple[StepContext, PoseFix]:
    """``verified``, or the confirmation (``verify``) of one of its fix's ``twins`` (the part
    turned onto itself, :func:`~cellsight.tracking.acquisition.twin_turns`) with more points.
    Only twins turned about an axis within ``TWIN_VERTICAL`` of the vertical are tried: they
    keep a lying part the right way up (turned over, in ``harsh``, the twins' features above
    the belt gave them more points than the part). An exact twin, whose features fall where
    the fix's do, is as good, and not taken."""
    best, T = verified, verified[1].T_base_part
    for turn in twins:
        axis = Rotation.from_matrix(turn[:3, :3]).as_rotvec()
        if abs(T[:3, :3] @ axis)[2] < TWIN_VERTICAL * np.linalg.norm(axis):
            continue  # it would turn the part over
        other = verify(replace(verified[1], T_base_part=T @ turn))
        if other is not None and other[1].n_points > best[1].n_points:
            best = other
    return best


def _resolution(cameras: Sequence[Camera], track: _Track) -> np.ndarray:
    """Per camera: pixels per metre at the estimated part's centroid (focal / depth), the
    selection's weight of each camera."""
    T = track.ekf.pose
    return camera_resolution(cameras, track.points.mean(axis=0) @ T[:3, :3].T + T[:3, 3])


def _looked_at(context: StepContext, T_base_part: np.ndarray, n_cameras: int) -> StepContext:
    """``context`` with a fresh record of the part predicted at ``T_base_part``."""
    name = context.rec.name
    views = context.look(name, T_base_part)
    rec = context.track.empty_record(name, context.rec.status, n_cameras)
    rec.set_views(views[name])
    return replace(context, rec=rec, crowd=_visible_pixels(views, n_cameras))


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


def _record_estimate(rec: PartFrame, ekf: PoseEKF) -> None:
    """Record the filter's state, covariance and pose."""
    rec.state, rec.covariance = ekf.state.copy(), ekf.covariance.copy()
    rec.T_base_part = ekf.pose


def _observed(observed: Any, cameras: Sequence[Camera], c: int) -> Any:
    """Camera ``c``'s entry of what the sensors took: from a sequence in camera order or a
    mapping by camera name (None when there is none)."""
    if observed is None:
        return None
    if isinstance(observed, Mapping):
        return observed.get(cameras[c].name)
    return observed[c] if c < len(observed) else None


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
    detect = getattr(extractor, "detect", None)

    def corners(c: int) -> np.ndarray | None:
        seen = _observed(context.observed, cameras, c)
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
        stamp = _observed(stamps, cameras, c)
        if stamp is None:
            continue
        lag = float(t) - float(stamp)
        if not (np.isfinite(lag) and lag >= -1e-9):
            raise ValueError(f"Tracker.step: camera {cameras[c].name!r} stamp {stamp!r} must "
                             f"be a finite time at or before the frame's t = {t}")
        lags[c] = max(lag, 0.0)
    return lags


def _cameras_grabbed(observed: Any, cameras: Sequence[Camera]) -> np.ndarray:
    """(C,) bool: the cameras that gave something this frame (a dropped frame's camera gave
    nothing: its selected features are not counted as not found)."""
    return np.array([_observed(observed, cameras, c) is not None for c in range(len(cameras))],
                    dtype=bool)


def _own_rows(start: int, visible: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Rows of the crowd (:data:`Crowd`) of the features ``idx`` of a part whose rows start at
    ``start`` for its visible features ``visible`` (sorted); -1 for a feature not among them."""
    pos = np.searchsorted(visible, idx)
    inside = pos < len(visible)
    inside[inside] = visible[pos[inside]] == idx[inside]
    return np.where(inside, start + pos, -1)


def _grabbed(records: Mapping[str, PartFrame], n_cameras: int) -> np.ndarray:
    """Per camera, the fraction of its pixels grabbed by every part's windows."""
    grabbed = np.zeros(n_cameras)
    for rec in records.values():
        for c, plan in enumerate(rec.windows):
            if plan is not None:
                grabbed[c] += plan.fraction
    return grabbed


def _visible_pixels(views: Views, n_cameras: int) -> Crowd:
    """The crowd (:data:`Crowd`) of the visibility source's answer ``views``."""
    out = []
    for c in range(n_cameras):
        rows, offsets, start = [], {}, 0
        for name, per_cam in views.items():
            v = per_cam[c]
            idx = np.flatnonzero(v.visible)
            offsets[name] = (start, idx)
            rows.append(np.asarray(v.pixels, dtype=float)[idx])
            start += len(idx)
        out.append((np.concatenate(rows) if rows else np.zeros((0, 2)), offsets))
    return out


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

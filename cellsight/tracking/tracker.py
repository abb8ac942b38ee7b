"""The closed visual tracking loop of the paper's Fig. 5, one :meth:`Tracker.step` per frame.

The tracker only wires its parts, each in its own module:

1. motion model (:mod:`.motion`; or the holder's measured motion with the kinematic prior)
   predicts every tracked part (:class:`~cellsight.tracking.ekf.PoseEKF`), within the
   :class:`~cellsight.tracking.loss.LossRule`'s coasting time;
2. the visibility source (:class:`cellsight.visibility.VisibilitySource`: the BSP predictor)
   predicts, at the predicted poses, which features each camera sees; every tracked part is
   passed, so parts can hide each other;
3. per part: a part not tracked yet, or lost, is acquired (:mod:`.acquisition`); otherwise
   the usable features (:mod:`.eligibility`) are selected (:mod:`.selection`), windows are
   planned around them (:mod:`.windowing`), the extractor finds them in the images
   (:mod:`.extraction`), the gate (:mod:`.gate`) screens the innovations and the EKF updates
   with the accepted ones (:mod:`.measurement`, :mod:`.ekf`).

Measured pixels are as in the image (distorted); the camera undistorts them before the update.
Stage times: :mod:`.timing`; statuses: :mod:`.status`; records: :mod:`.records`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.transforms import invert_pose, xyz_rpy_from_pose
from cellsight.tracking.acquisition import PnPAcquisition
from cellsight.tracking.ekf import AdaptiveNoise, PoseEKF
from cellsight.tracking.eligibility import NearOccluderHold
from cellsight.tracking.extraction import CornerExtractor
from cellsight.tracking.gate import ChiSquareGate
from cellsight.tracking.interfaces import Extractor, MeasurementModel
from cellsight.tracking.loss import LossRule
from cellsight.tracking.measurement import Observation, PinholeMeasurement
from cellsight.tracking.motion import POSE_DIM, ConstantVelocity
from cellsight.tracking.records import PartFrame, TrackerFrame
from cellsight.tracking.selection import SelectionConfig, camera_resolution, select_features
from cellsight.tracking.status import TrackStatus
from cellsight.tracking.timing import StageTimer
from cellsight.tracking.windowing import WindowConfig, plan_windows
from cellsight.visibility import CameraVisibility, Views, VisibilitySource


@dataclass(frozen=True)
class TrackerConfig:
    """The tracker's parts and parameters. Units: s, px, m^2/s, rad^2/s.

    ``sigma_px``: pixel noise of the measurement model; ``gate``: None accepts every
    measurement; ``carried_noise``: random-walk densities of a held part's pose relative to its
    holder, with the kinematic prior (``holders`` in :meth:`Tracker.step`);
    ``near_occluder_hold_s``: how long a feature stays unusable after it was last flagged
    ``near_occluder``; ``measurement``: builds a camera's measurement model from the camera and
    ``sigma_px``.
    """

    motion: ConstantVelocity = ConstantVelocity()
    sigma_px: float = 0.5
    adaptive_noise: bool = False
    gate: ChiSquareGate | None = ChiSquareGate(0.999)
    selection: SelectionConfig = SelectionConfig()
    windows: WindowConfig = WindowConfig()
    acquisition: PnPAcquisition = PnPAcquisition()
    loss: LossRule = LossRule()
    carried_noise: tuple[float, float] = (1e-6, 1e-5)
    near_occluder_hold_s: float = 0.5
    measurement: Callable[[Camera, float], MeasurementModel] = PinholeMeasurement


@dataclass
class _Track:
    """One workpiece's track: feature points (F, 3) in the part frame, the acquisition guess,
    the filter, the last accepted measurement's time (s) and the holder's pose last frame."""

    points: np.ndarray
    guess: np.ndarray | None
    hold: NearOccluderHold
    ekf: PoseEKF | None = None
    base_guess: np.ndarray | None = None
    attempts: int = 0
    last_update: float = -np.inf
    lost: bool = False
    holder: np.ndarray | None = None

    def empty_record(self, name: str, status: TrackStatus, n_cameras: int) -> PartFrame:
        ekf = self.ekf
        return PartFrame.empty(name, status, n_cameras, len(self.points),
                               None if ekf is None else ekf.state,
                               None if ekf is None else ekf.covariance,
                               None if ekf is None else ekf.pose)


class Tracker:
    """Occlusion-aware multi-camera tracker of one or more workpieces (module docstring).

    ``cameras`` in the order the visibility source reports them; ``parts``: workpiece name ->
    feature points (F, 3) in the part frame (m); ``initial_poses``: name -> guessed
    ``T_base_part`` for acquisition (a part without one waits for :meth:`initialise`).
    ``extractor`` defaults to :class:`~cellsight.tracking.extraction.CornerExtractor`.
    """

    def __init__(
        self,
        cameras: Sequence[Camera],
        parts: Mapping[str, np.ndarray],
        predictor: VisibilitySource,
        extractor: Extractor | None = None,
        config: TrackerConfig | None = None,
        initial_poses: Mapping[str, np.ndarray] | None = None,
    ) -> None:
        self.config = config or TrackerConfig()
        self.cameras = list(cameras)
        self.predictor = predictor
        self.extractor = extractor or CornerExtractor()
        self._models = [self.config.measurement(c, self.config.sigma_px) for c in self.cameras]
        guesses = dict(initial_poses or {})
        self.tracks = {
            name: _Track(np.asarray(pts, dtype=float).reshape(-1, 3), guesses.get(name),
                         NearOccluderHold(self.config.near_occluder_hold_s))
            for name, pts in parts.items()
        }

    @classmethod
    def from_cell(
        cls,
        cell: Any,
        predictor: VisibilitySource,
        extractor: Extractor | None = None,
        config: TrackerConfig | None = None,
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
        )

    def initialise(
        self, name: str, T_base_part: np.ndarray, t: float, covariance: np.ndarray | None = None
    ) -> None:
        """Start (or restart) the filter of a part at a known pose, zero velocity.

        ``covariance`` (12x12) defaults to 5 mm / 0.05 rad on the pose and the acquisition's
        velocity uncertainty.
        """
        if covariance is None:
            covariance = self.config.acquisition.covariance(
                np.diag([0.005**2] * 3 + [0.05**2] * 3))
        track = self.tracks[name]
        xyz, rpy = xyz_rpy_from_pose(np.asarray(T_base_part, dtype=float))
        state = np.concatenate([xyz, rpy, np.zeros(POSE_DIM)])
        adaptive = AdaptiveNoise() if self.config.adaptive_noise else None
        track.ekf = PoseEKF(self.config.motion, state, covariance, t, adaptive)
        track.last_update = float(t)
        track.lost = False

    def step(
        self,
        images: Any,
        joints: Mapping[str, np.ndarray] | None,
        t: float,
        openings: Mapping[str, float] | None = None,
        holders: Mapping[str, np.ndarray] | None = None,
    ) -> TrackerFrame:
        """Process one vision frame at time ``t`` (s): the paper's Fig. 5 (module docstring).

        ``images``: one image per camera (sequence in camera order, or mapping by camera name;
        None for a missing image), passed to the extractor; ``joints``: robot name -> joint
        vector (m, rad) and ``openings``: robot name -> jaw opening (m), for the visibility
        source; ``holders`` (the kinematic prior, optional): part name -> measured pose
        ``T_base_holder`` of what holds the part rigidly this frame (a gripper's TCP from the
        joint measurements); a part held at this frame and the last one is predicted by the
        holder's motion (:meth:`PoseEKF.predict_carried`) instead of its motion model.
        """
        timer = StageTimer()
        with timer("total"):
            with timer("ekf"):
                poses = self._predict(t, holders or {})
            with timer("occlusion"):
                views = self.predictor.predict(joints, poses, openings) if poses else {}
            crowd = _visible_pixels(views, len(self.cameras))
            records = {name: self._part(name, track, views.get(name), crowd, images, t, timer)
                       for name, track in self.tracks.items()}
        grabbed = np.zeros(len(self.cameras))
        for rec in records.values():
            for c, plan in enumerate(rec.windows):
                if plan is not None:
                    grabbed[c] += plan.fraction
        return TrackerFrame(float(t), records, timer.seconds, grabbed)

    def _predict(self, t: float, holders: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Predict every tracked part to time ``t``; the pose each is looked for at (the
        prediction, or the acquisition guess of a part never acquired)."""
        poses = {}
        loss = self.config.loss
        for name, track in self.tracks.items():
            holder = holders.get(name)
            if track.ekf is not None:
                if holder is not None and track.holder is not None:
                    track.ekf.predict_carried(t, holder @ invert_pose(track.holder),
                                              self.config.carried_noise)
                elif loss.coasts(t, track.last_update):
                    track.ekf.predict(t)
                track.lost = loss.lost(t, track.last_update)
                poses[name] = track.ekf.pose
            elif track.guess is not None:
                poses[name] = track.guess
            track.holder = None if holder is None else np.asarray(holder, dtype=float)
        return poses

    def _part(self, name: str, track: _Track, views: list[CameraVisibility] | None,
              crowd, images: Any, t: float, timer: StageTimer) -> PartFrame:
        """One part's record this frame: waiting, acquired/lost, or tracked."""
        C = len(self.cameras)
        if views is None:
            return track.empty_record(name, TrackStatus.WAITING, C)
        if track.ekf is None or track.lost:
            status = TrackStatus.LOST if track.ekf is not None else TrackStatus.WAITING
            rec = track.empty_record(name, status, C)
            rec.set_views(views)
            self._acquire(rec, track, crowd, images, t, timer)
        else:
            rec = track.empty_record(name, TrackStatus.PREDICTING, C)
            rec.set_views(views)
            self._track(rec, track, crowd, images, timer)
        return rec

    def _track(self, rec: PartFrame, track: _Track, crowd, images: Any,
               timer: StageTimer) -> None:
        """Select, window, extract, gate and update (the paper's loop)."""
        ekf = track.ekf
        with timer("selection"):
            usable = track.hold.usable(rec.visible, rec.near_occluder, ekf.t)
            sel = select_features(rec.pixels, usable, self._resolution(track),
                                  self.config.selection)
            rec.selection, rec.selected = sel, sel.selected

        def covariance(c: int, idx: np.ndarray) -> np.ndarray:
            return ekf.innovation_covariance(self._models[c], c, track.points[idx])[1]

        obs = self._measure(rec, track, crowd, images, timer, covariance, self.config.windows)
        with timer("ekf"):
            report = ekf.update(obs, self.config.gate)
        if len(report.accepted):
            c, f = report.camera_index, report.feature_ids
            rec.innovation[c, f] = report.innovation
            rec.mahalanobis2[c, f] = report.mahalanobis2
            rec.rejected[c, f] = ~report.accepted
        if report.n_accepted:
            track.last_update = ekf.t
            rec.status = TrackStatus.TRACKING
        rec.state, rec.covariance = ekf.state.copy(), ekf.covariance.copy()
        rec.T_base_part = ekf.pose

    def _resolution(self, track: _Track) -> np.ndarray:
        """Per camera: pixels per metre at the estimated part's centroid (focal / depth), the
        selection's weight of each camera."""
        T = track.ekf.pose
        return camera_resolution(self.cameras, track.points.mean(axis=0) @ T[:3, :3].T
                                 + T[:3, 3])

    def _acquire(self, rec: PartFrame, track: _Track, crowd, images: Any, t: float,
                 timer: StageTimer) -> None:
        """Windows of a fixed size on every usable feature, then PnP (:mod:`.acquisition`)."""
        acquisition = self.config.acquisition
        size = acquisition.window_px
        windows = replace(self.config.windows, min_size_px=size, max_size_px=size)
        rec.selected = track.hold.usable(rec.visible, rec.near_occluder, t)

        def covariance(c: int, idx: np.ndarray) -> np.ndarray:
            return np.zeros((len(idx), 2, 2))

        obs = self._measure(rec, track, crowd, images, timer, covariance, windows)
        with timer("ekf"):
            fix = acquisition.fix(obs, self.config.sigma_px)
            if fix is None and track.ekf is None and track.guess is not None:
                if track.base_guess is None:
                    track.base_guess = track.guess
                track.attempts += 1
                track.guess = acquisition.guess(track.base_guess, track.attempts)
            if fix is not None:
                self.initialise(rec.name, fix.T_base_part, t, acquisition.start(fix))
                rec.status = TrackStatus.ACQUIRED
                ekf = track.ekf
                rec.state, rec.covariance = ekf.state.copy(), ekf.covariance.copy()
                rec.T_base_part = ekf.pose

    def _measure(self, rec: PartFrame, track: _Track, crowd, images: Any, timer: StageTimer,
                 covariance: Callable[[int, np.ndarray], np.ndarray],
                 windows: WindowConfig) -> list[Observation]:
        """Plan the windows of the selected features, extract, build the observations."""
        observations = []
        for c, cam in enumerate(self.cameras):
            idx = np.flatnonzero(rec.selected[c])
            if len(idx) == 0:
                continue
            with timer("windowing"):
                others, offsets = crowd[c]
                start, vis_idx = offsets[rec.name]
                own = start + np.searchsorted(vis_idx, idx)
                plan = plan_windows(rec.pixels[c, idx], idx, covariance(c, idx), cam.width,
                                    cam.height, others, own, windows)
                rec.windows[c] = plan
            with timer("extraction"):
                found = self.extractor.extract(c, _image(images, self.cameras, c), plan)
            if not found:
                continue
            ids = np.array(sorted(found), dtype=np.int64)
            px = np.array([found[i] for i in ids], dtype=float).reshape(-1, 2)
            rec.measured[c, ids] = px
            observations.append(
                Observation(self._models[c], c, ids, track.points[ids], cam.undistort(px)))
        return observations


def _image(images: Any, cameras: Sequence[Camera], c: int) -> Any:
    """Camera ``c``'s image from a sequence in camera order or a mapping by camera name."""
    if images is None:
        return None
    if isinstance(images, Mapping):
        return images.get(cameras[c].name)
    return images[c] if c < len(images) else None


def _visible_pixels(views: Views, n_cameras: int) -> list[tuple[np.ndarray, dict]]:
    """Per camera: (M, 2) predicted pixels of every visible feature of every part (the
    crowd the windows must avoid), and each part's (row offset, visible feature indices)."""
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

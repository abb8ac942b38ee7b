"""The closed visual tracking loop of the paper's Fig. 5, one :meth:`Tracker.step` per frame.

Per vision frame and workpiece: EKF prediction -> occlusion prediction at the predicted pose
(BSP, :class:`VisibilitySource`) -> optimal selection -> windows -> feature extraction in the
windows (:class:`Extractor`) -> EKF update. The predicted pose of every tracked workpiece goes
to the occlusion predictor, so parts can hide each other.

Acquisition (a part not tracked yet, or lost): the occlusion predictor runs at a guess of the
pose (the cell's nominal pose of the part, or the last prediction of a lost part); every
predicted-visible feature gets a fixed-size window (``acquisition_window_px``); the corners
found there give a fused multi-camera PnP that drops up to three wrong corners
(:func:`~cellsight.tracking.pnp.estimate_pose_robust`); the filter starts from it when its RMS
reprojection error is below ``acquisition_max_rms_px``.
A part is *lost* after ``lost_after_s`` seconds without an accepted measurement; until then
frames without measurements only predict. The prediction coasts at most ``coast_s`` seconds
after the last accepted measurement, then stops (the last velocity would carry the pose away
for ever): a part that left the views is looked for where it was last predicted.

Selection and acquisition skip the features that the predictor flags ``near_occluder`` (next
to another object's silhouette, where the image corner is a junction a few pixels off), and
keep them out for ``near_occluder_hold_s`` after the last flag.

Measured pixels are as in the image (distorted); they are undistorted before the update.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.transforms import invert_pose, xyz_rpy_from_pose
from cellsight.tracking.ekf import AdaptiveNoise, PoseEKF
from cellsight.tracking.extraction import CornerExtractor
from cellsight.tracking.measurement import Observation, PinholeMeasurement, undistort_pixels
from cellsight.tracking.motion import POSE_DIM, STATE_DIM, ConstantVelocity
from cellsight.tracking.pnp import estimate_pose_robust
from cellsight.tracking.selection import Selection, SelectionConfig, select_features
from cellsight.tracking.windowing import WindowConfig, WindowPlan, plan_windows

STAGES = ("predict", "occlusion", "selection", "windowing", "extraction", "update", "total")


class CameraVisibilityLike(Protocol):
    """What the tracker reads from the occlusion predictor for one part in one camera:
    ``visible`` (F,) bool, ``pixels`` (F, 2) predicted, ``near_occluder`` (F,) bool: visible
    but next to another object's silhouette (never selected: its image corner is a junction
    with that silhouette)."""

    visible: np.ndarray
    pixels: np.ndarray
    near_occluder: np.ndarray


class VisibilitySource(Protocol):
    """The occlusion predictor (e.g. :class:`cellsight.occlusion.predictor.VisibilityPredictor`):
    workpiece name -> one visibility per camera, in the tracker's camera order."""

    def predict(
        self, joints: Mapping[str, np.ndarray] | None, part_poses: Mapping[str, np.ndarray]
    ) -> Mapping[str, Sequence[CameraVisibilityLike]]: ...


class Extractor(Protocol):
    """Finds the features in one camera's image windows: feature index -> pixel (2,)."""

    def extract(self, camera_index: int, image: Any, plan: WindowPlan) -> dict[int, np.ndarray]: ...


@dataclass(frozen=True)
class TrackerConfig:
    """Tracking parameters. Units: s, px, m/s, rad/s.

    ``init_velocity_std`` (linear, angular) is the velocity uncertainty at (re)initialisation;
    ``init_pose_inflation`` multiplies the PnP covariance used as the initial pose covariance.
    ``carried_noise`` (m^2/s, rad^2/s): random-walk densities of a held part's pose relative to
    its holder, with the kinematic prior (``holders`` in :meth:`Tracker.step`).
    ``near_occluder_hold_s`` (s): how long a feature stays unselectable after it was last
    flagged ``near_occluder``.
    """

    motion: ConstantVelocity = ConstantVelocity()
    sigma_px: float = 0.5
    gate_probability: float | None = 0.999
    adaptive_noise: bool = False
    selection: SelectionConfig = SelectionConfig()
    windows: WindowConfig = WindowConfig()
    acquisition_window_px: float = 64.0
    acquisition_max_rms_px: float = 2.0
    init_velocity_std: tuple[float, float] = (0.2, 0.5)
    init_pose_inflation: float = 4.0
    lost_after_s: float = 2.0
    coast_s: float = 4.0
    carried_noise: tuple[float, float] = (1e-6, 1e-5)
    near_occluder_hold_s: float = 0.5


@dataclass
class PartFrame:
    """What happened to one workpiece in one frame (C cameras, F features).

    ``status``: 'waiting' (not acquired), 'acquired' (initialised this frame by PnP),
    'tracking' (updated), 'predicting' (no accepted measurement: prediction only) or 'lost'.
    ``visible``/``pixels``: occlusion prediction at the predicted (or guessed) pose;
    ``near_occluder``: visible but next to another object's silhouette (not selectable);
    ``selected``: features whose windows were planned; ``windows``: one plan per camera;
    ``measured``: extracted pixels (NaN where none); ``innovation`` (px), ``mahalanobis2`` and
    ``rejected`` (gated out); ``state``/``covariance``/``T_base_part`` after the update
    (None while waiting); ``predicted_state`` before it.
    """

    name: str
    status: str
    visible: np.ndarray
    pixels: np.ndarray
    near_occluder: np.ndarray
    selected: np.ndarray
    selection: Selection | None
    windows: list[WindowPlan | None]
    measured: np.ndarray
    innovation: np.ndarray
    mahalanobis2: np.ndarray
    rejected: np.ndarray
    predicted_state: np.ndarray | None
    state: np.ndarray | None
    covariance: np.ndarray | None
    T_base_part: np.ndarray | None


@dataclass
class TrackerFrame:
    """One :meth:`Tracker.step`: time (s), per-part records, stage times (s) and the fraction
    of each camera's pixels grabbed."""

    t: float
    parts: dict[str, PartFrame]
    timings: dict[str, float]
    grabbed_fraction: np.ndarray


@dataclass
class _Track:
    points: np.ndarray
    guess: np.ndarray | None
    ekf: PoseEKF | None = None
    last_update: float = -np.inf
    lost: bool = False
    holder: np.ndarray | None = None  # T_base_holder at the last frame, while held
    near_at: np.ndarray | None = None  # (C, F) time (s) each feature was last near an occluder


class Tracker:
    """Occlusion-aware multi-camera tracker of one or more workpieces (module docstring).

    ``cameras`` in the order the predictor reports them; ``parts``: workpiece name -> feature
    points (F, 3) in the part frame (m); ``initial_poses``: name -> guessed ``T_base_part`` for
    acquisition (a part without one waits for :meth:`initialise`). ``extractor`` defaults to
    :class:`~cellsight.tracking.extraction.CornerExtractor`.
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
        self.models = [PinholeMeasurement(c, self.config.sigma_px) for c in self.cameras]
        self.predictor = predictor
        self.extractor = extractor or CornerExtractor()
        guesses = dict(initial_poses or {})
        self.tracks = {
            name: _Track(np.asarray(pts, dtype=float).reshape(-1, 3), guesses.get(name))
            for name, pts in parts.items()
        }
        self.history: list[TrackerFrame] = []

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

        ``covariance`` (12x12) defaults to 5 mm / 0.05 rad on the pose and the configured
        velocity uncertainty.
        """
        if covariance is None:
            covariance = self._initial_covariance(np.diag([0.005**2] * 3 + [0.05**2] * 3))
        track = self.tracks[name]
        xyz, rpy = xyz_rpy_from_pose(np.asarray(T_base_part, dtype=float))
        state = np.concatenate([xyz, rpy, np.zeros(POSE_DIM)])
        cfg = self.config
        adaptive = AdaptiveNoise() if cfg.adaptive_noise else None
        track.ekf = PoseEKF(cfg.motion, state, covariance, t, cfg.gate_probability, adaptive)
        track.last_update = float(t)
        track.lost = False

    def _initial_covariance(self, pose_cov: np.ndarray) -> np.ndarray:
        P = np.zeros((STATE_DIM, STATE_DIM))
        P[:POSE_DIM, :POSE_DIM] = pose_cov
        lin, ang = self.config.init_velocity_std
        P[POSE_DIM:, POSE_DIM:] = np.diag([lin**2] * 3 + [ang**2] * 3)
        return P

    def _image(self, images: Any, c: int) -> Any:
        if images is None:
            return None
        if isinstance(images, Mapping):
            return images.get(self.cameras[c].name)
        return images[c] if c < len(images) else None

    def step(
        self, images: Any, joints: Mapping[str, np.ndarray] | None, t: float,
        holders: Mapping[str, np.ndarray] | None = None,
    ) -> TrackerFrame:
        """Process one vision frame at time ``t`` (s).

        ``images``: one image per camera (sequence in camera order, or mapping by camera name;
        None for a missing image), passed to the extractor; ``joints``: robot name -> joint
        vector for the occlusion predictor; ``holders`` (the kinematic prior, optional): part
        name -> measured pose ``T_base_holder`` of what holds the part rigidly (a gripper's
        TCP from the joint measurements) this frame; a part held at this frame and the last
        one is predicted by the holder's motion (:meth:`PoseEKF.predict_carried`) instead of
        the constant-velocity model.
        """
        timings = dict.fromkeys(STAGES, 0.0)
        t_start = time.perf_counter()
        C = len(self.cameras)
        poses = {}
        tic = time.perf_counter()
        for name, track in self.tracks.items():
            holder = (holders or {}).get(name)
            if track.ekf is not None:
                if holder is not None and track.holder is not None:
                    track.ekf.predict_carried(t, holder @ invert_pose(track.holder),
                                              self.config.carried_noise)
                elif t - track.last_update <= self.config.coast_s:
                    track.ekf.predict(t)
                track.lost = t - track.last_update > self.config.lost_after_s
                poses[name] = track.ekf.pose
            elif track.guess is not None:
                poses[name] = track.guess
            track.holder = None if holder is None else np.asarray(holder, dtype=float)
        timings["predict"] = time.perf_counter() - tic
        tic = time.perf_counter()
        vis = self.predictor.predict(joints, poses) if poses else {}
        timings["occlusion"] = time.perf_counter() - tic
        all_visible = self._visible_pixels(vis)
        grabbed = np.zeros(C)
        records = {}
        for name, track in self.tracks.items():
            if name not in vis:
                records[name] = self._empty(name, track, "waiting")
                continue
            if track.ekf is None or track.lost:
                rec = self._acquire(name, track, vis[name], all_visible, images, t, timings)
            else:
                rec = self._track(name, track, vis[name], all_visible, images, timings)
            for c, plan in enumerate(rec.windows):
                if plan is not None:
                    grabbed[c] += plan.fraction
            records[name] = rec
        timings["total"] = time.perf_counter() - t_start
        frame = TrackerFrame(float(t), records, timings, grabbed)
        self.history.append(frame)
        return frame

    def _visible_pixels(self, vis: Mapping[str, Sequence[CameraVisibilityLike]]):
        """Per camera: (M, 2) predicted pixels of every visible feature of every part, and the
        row offset of each part."""
        out = []
        for c in range(len(self.cameras)):
            rows, offsets, start = [], {}, 0
            for name, per_cam in vis.items():
                v = per_cam[c]
                idx = np.flatnonzero(v.visible)
                offsets[name] = (start, idx)
                rows.append(np.asarray(v.pixels, dtype=float)[idx])
                start += len(idx)
            out.append((np.concatenate(rows) if rows else np.zeros((0, 2)), offsets))
        return out

    def _empty(self, name: str, track: _Track, status: str) -> PartFrame:
        C, F = len(self.cameras), len(track.points)
        ekf = track.ekf
        return PartFrame(
            name=name,
            status=status,
            visible=np.zeros((C, F), dtype=bool),
            pixels=np.full((C, F, 2), np.nan),
            near_occluder=np.zeros((C, F), dtype=bool),
            selected=np.zeros((C, F), dtype=bool),
            selection=None,
            windows=[None] * C,
            measured=np.full((C, F, 2), np.nan),
            innovation=np.full((C, F, 2), np.nan),
            mahalanobis2=np.full((C, F), np.nan),
            rejected=np.zeros((C, F), dtype=bool),
            predicted_state=None if ekf is None else ekf.state.copy(),
            state=None if ekf is None else ekf.state.copy(),
            covariance=None if ekf is None else ekf.covariance.copy(),
            T_base_part=None if ekf is None else ekf.pose,
        )

    def _windows_and_measure(
        self, rec, track, per_cam, all_visible, images, timings, selected, cov_of, wcfg
    ) -> list[Observation]:
        """Plan the windows of the selected features, extract, build the observations."""
        observations = []
        for c, cam in enumerate(self.cameras):
            idx = np.flatnonzero(selected[c])
            if len(idx) == 0:
                continue
            tic = time.perf_counter()
            centres = np.asarray(per_cam[c].pixels, dtype=float)[idx]
            others, offsets = all_visible[c]
            start, vis_idx = offsets[rec.name]
            own = start + np.searchsorted(vis_idx, idx)
            plan = plan_windows(centres, idx, cov_of(c, idx), cam.width, cam.height, others, own,
                                wcfg)
            rec.windows[c] = plan
            timings["windowing"] += time.perf_counter() - tic
            tic = time.perf_counter()
            found = self.extractor.extract(c, self._image(images, c), plan)
            timings["extraction"] += time.perf_counter() - tic
            if not found:
                continue
            ids = np.array(sorted(found), dtype=np.int64)
            px = np.array([found[i] for i in ids], dtype=float).reshape(-1, 2)
            rec.measured[c, ids] = px
            observations.append(
                Observation(self.models[c], c, ids, track.points[ids], undistort_pixels(cam, px))
            )
        return observations

    def _fill_prediction(self, rec: PartFrame, per_cam: Sequence[CameraVisibilityLike]) -> None:
        for c in range(len(self.cameras)):
            rec.visible[c] = np.asarray(per_cam[c].visible, dtype=bool)
            rec.pixels[c] = np.asarray(per_cam[c].pixels, dtype=float)
            rec.near_occluder[c] = np.asarray(per_cam[c].near_occluder, dtype=bool)

    def _usable(self, track: _Track, rec: PartFrame, t: float) -> np.ndarray:
        """Visible features not flagged near an occluder's silhouette within the last
        ``near_occluder_hold_s`` seconds (a flag that flickers at the ring's edge keeps the
        feature out)."""
        if track.near_at is None:
            track.near_at = np.full(rec.visible.shape, -np.inf)
        track.near_at[rec.near_occluder] = t
        return rec.visible & (t - track.near_at > self.config.near_occluder_hold_s)

    def _track(self, name, track, per_cam, all_visible, images, timings) -> PartFrame:
        ekf = track.ekf
        rec = self._empty(name, track, "predicting")
        self._fill_prediction(rec, per_cam)
        tic = time.perf_counter()
        T = ekf.pose
        centroid = track.points.mean(axis=0) @ T[:3, :3].T + T[:3, 3]
        rho = np.array([c.focal_px / max(c.depth(centroid[None])[0], 1e-6) for c in self.cameras])
        usable = self._usable(track, rec, ekf.t)
        sel = select_features(rec.pixels, usable, rho, self.config.selection)
        rec.selection, rec.selected = sel, sel.selected
        timings["selection"] += time.perf_counter() - tic

        def cov_of(c, idx):
            return ekf.innovation_covariance(self.models[c], c, track.points[idx])[1]

        obs = self._windows_and_measure(
            rec, track, per_cam, all_visible, images, timings, sel.selected, cov_of,
            self.config.windows,
        )
        tic = time.perf_counter()
        report = ekf.update(obs)
        timings["update"] += time.perf_counter() - tic
        if len(report.accepted):
            c, f = report.camera_index, report.feature_ids
            rec.innovation[c, f] = report.innovation
            rec.mahalanobis2[c, f] = report.mahalanobis2
            rec.rejected[c, f] = ~report.accepted
        if report.n_accepted:
            track.last_update = ekf.t
            rec.status = "tracking"
        rec.state, rec.covariance = ekf.state.copy(), ekf.covariance.copy()
        rec.T_base_part = ekf.pose
        return rec

    def _acquire(self, name, track, per_cam, all_visible, images, t, timings) -> PartFrame:
        rec = self._empty(name, track, "lost" if track.ekf is not None else "waiting")
        self._fill_prediction(rec, per_cam)
        size = self.config.acquisition_window_px
        wcfg = replace(self.config.windows, min_size_px=size, max_size_px=size)
        rec.selected = self._usable(track, rec, t)

        def cov_of(c, idx):
            return np.zeros((len(idx), 2, 2))

        obs = self._windows_and_measure(
            rec, track, per_cam, all_visible, images, timings, rec.selected, cov_of, wcfg
        )
        tic = time.perf_counter()
        fix = estimate_pose_robust(obs, self.config.acquisition_max_rms_px,
                                   sigma_px=self.config.sigma_px)
        if fix is not None and fix.rms_px <= self.config.acquisition_max_rms_px:
            P = self._initial_covariance(self.config.init_pose_inflation * fix.covariance)
            self.initialise(name, fix.T_base_part, t, P)
            rec.status = "acquired"
            ekf = track.ekf
            rec.state, rec.covariance = ekf.state.copy(), ekf.covariance.copy()
            rec.T_base_part = ekf.pose
        timings["update"] += time.perf_counter() - tic
        return rec

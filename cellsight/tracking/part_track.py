"""One workpiece's track and one part's work in one step of the tracker (for :mod:`.tracker`):
:class:`PartTrack`, :class:`StepContext` and the crowd of predicted pixels the windows must
avoid."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.transforms import invert_pose
from cellsight.tracking.config import TrackerConfig
from cellsight.tracking.ekf import (
    PoseEKF,
)
from cellsight.tracking.eligibility import NearOccluderHold
from cellsight.tracking.interfaces import Acquisition, TrackHealth, TrackMonitor
from cellsight.tracking.prior.fusion import fuse_priors
from cellsight.tracking.records import PartFrame
from cellsight.tracking.status import TrackStatus
from cellsight.tracking.timing import StageTimer
from cellsight.visibility import CameraVisibility, Views

Crowd = list[tuple[np.ndarray, dict[str, tuple[int, np.ndarray]]]]
"""Per camera: (M, 2) predicted pixels of every visible feature of every part (what the windows
must avoid), and each part's (first row, its visible feature indices) in them."""


@dataclass
class PartTrack:
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
    of the part lying on its support this frame (``lying``, None: held, or not known),
    when a holder last let it go (``let_go_t``, s; None: never, or held again since), and
    where a part waiting out of every view would come into them (``entry``, the search's;
    None: not found yet), and the way a line carries it across the cell (``travel``, x, y,
    m, base frame: a line's passing part; None: not known)."""

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
    let_go_t: float | None = None
    entry: list[np.ndarray] | None = None
    travel: np.ndarray | None = None

    @cached_property
    def centre(self) -> np.ndarray:
        """(3,) m: the centre of the feature points' box, in the part frame."""
        return 0.5 * (self.points.min(axis=0) + self.points.max(axis=0))

    @cached_property
    def radius(self) -> float:
        """m: the farthest feature point's distance from :attr:`centre`."""
        return float(np.linalg.norm(self.points - self.centre, axis=1).max())

    def centre_at(self, T_base_part: np.ndarray) -> np.ndarray:
        """(3,) m, base frame: :attr:`centre` with the part at ``T_base_part``."""
        return T_base_part[:3, :3] @ self.centre + T_base_part[:3, 3]

    @property
    def claims(self) -> bool:
        """The track holds its part's place: it has a filter and is not lost (a pose another
        part's acquisition finds there is this part's, :mod:`.acquire`)."""
        return self.ekf is not None and not self.lost

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

    def predict_to(self, t: float, holder: np.ndarray | None, lying: np.ndarray | None,
                   loss: TrackHealth, config: TrackerConfig) -> np.ndarray | None:
        """Predict the part to time ``t`` (s): by its ``holder``'s motion while held (its pose
        there this frame; None: not held), else by its motion model while it coasts, on its
        support if it rests on one (``lying``), with the kinematic prior fused
        (:func:`~.prior.fusion.fuse_priors`); lost when ``loss`` says so. Returns the pose it
        is looked for at (the prediction, or the acquisition guess of a part never acquired;
        for a part to be acquired that a holder holds or let go, where it holds it or let it
        go), None when there is none."""
        self.lying = None if holder is not None or lying is None else np.asarray(lying,
                                                                                 dtype=float)
        if holder is not None:
            self.let_go_t = None
        elif self.holder is not None:
            self.let_go_t = float(t)
        pose = None
        if self.ekf is not None:
            if holder is not None and self.holder is not None:
                self.ekf.predict_carried(t, holder @ invert_pose(self.holder),
                                         config.carried_noise)
            elif loss.coasts(t, self.last_update):
                self.ekf.predict(t, at_rest=self.holder is not None)  # let go: at rest
            fuse_priors(self, t, holder, config)
            self.lost = loss.lost(t, self.last_update, self.unseen_since)
            pose = self.ekf.pose
        elif self.guess is not None:
            pose = self.guess
        if self.lying is not None:  # the whole-image search's plane
            self.support = self.lying
        self.holder = None if holder is None else np.asarray(holder, dtype=float)
        if self.holder is not None:
            self.held_at = self.holder
        if self.acquiring and self.held_at is not None:
            pose = self.held_at
        return pose

    def frame_record(self, name: str, views: list[CameraVisibility] | None,
                     n_cameras: int) -> PartFrame:
        """The part's record before its measurements: waiting (nothing predicted), to be
        acquired (waiting or lost) or coasting, with the visibility source's answer."""
        if views is None:
            return self.empty_record(name, TrackStatus.WAITING, n_cameras)
        if self.acquiring:
            status = TrackStatus.LOST if self.ekf is not None else TrackStatus.WAITING
        else:
            status = TrackStatus.COASTING
        rec = self.empty_record(name, status, n_cameras)
        rec.set_views(views)
        return rec

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
    track: PartTrack
    rec: PartFrame
    look: Callable[[str, np.ndarray], Views]
    lags: np.ndarray


def looked_at(context: StepContext, T_base_part: np.ndarray, n_cameras: int) -> StepContext:
    """``context`` with a fresh record of the part predicted at ``T_base_part``."""
    name = context.rec.name
    views = context.look(name, T_base_part)
    rec = context.track.empty_record(name, context.rec.status, n_cameras)
    rec.set_views(views[name])
    return replace(context, rec=rec, crowd=visible_pixels(views, n_cameras))


def observed_of(observed: Any, cameras: Sequence[Camera], c: int) -> Any:
    """Camera ``c``'s entry of what the sensors took: from a sequence in camera order or a
    mapping by camera name (None when there is none)."""
    if observed is None:
        return None
    if isinstance(observed, Mapping):
        return observed.get(cameras[c].name)
    return observed[c] if c < len(observed) else None


def cameras_grabbed(observed: Any, cameras: Sequence[Camera]) -> np.ndarray:
    """(C,) bool: the cameras that gave something this frame (a dropped frame's camera gave
    nothing: its selected features are not counted as not found)."""
    return np.array([observed_of(observed, cameras, c) is not None for c in range(len(cameras))],
                    dtype=bool)


def visible_pixels(views: Views, n_cameras: int) -> Crowd:
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


def record_estimate(rec: PartFrame, ekf: PoseEKF) -> None:
    """Record the filter's state, covariance and pose."""
    rec.state, rec.covariance = ekf.state.copy(), ekf.covariance.copy()
    rec.T_base_part = ekf.pose

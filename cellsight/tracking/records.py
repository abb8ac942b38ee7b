"""What one :meth:`~cellsight.tracking.Tracker.step` reports, per workpiece and per frame."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cellsight.tracking.health import TrackHealthReport
from cellsight.tracking.motion import VELOCITY
from cellsight.tracking.selection import Selection
from cellsight.tracking.status import TrackStatus
from cellsight.tracking.unknown import UNKNOWN_LABEL, Grid
from cellsight.tracking.windowing import WindowPlan
from cellsight.visibility import CameraVisibility


@dataclass
class PartFrame:
    """What happened to one workpiece in one frame (C cameras, F features).

    ``status``: see :class:`TrackStatus`. ``views``: the visibility source's answer for this
    part, one per camera (empty when nothing was predicted); ``visible``/``pixels``: its
    prediction at the predicted (or guessed) pose (a tracked part's pixels moved by each
    camera's estimated offset, with camera offsets: :mod:`.offsets`); ``near_occluder``:
    visible but next to another object's silhouette (not selectable); ``unknown``: predicted
    visible, but under an unknown occluder learnt online (:mod:`.unknown`; not selectable);
    ``selected``: features whose windows were planned; ``windows``: one plan per camera;
    ``measured``: extracted pixels (NaN where none);
    ``innovation`` (px), ``mahalanobis2`` and ``rejected`` (gated out); ``state``/``covariance``/
    ``T_base_part`` after the update (None while waiting); ``predicted_state`` before it;
    ``health``: the health monitor's report (:mod:`.health`; None where the part was not
    tracked this frame), whose reasons :attr:`status_text` gives for a degraded track;
    ``held_out`` (C,): the cameras the camera check held out of the filter this frame
    (dropped, or between its two looks; :mod:`.camera_check`): their features are measured,
    and used for nothing.
    """

    name: str
    status: TrackStatus
    visible: np.ndarray
    pixels: np.ndarray
    near_occluder: np.ndarray
    unknown: np.ndarray
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
    views: list[CameraVisibility] = field(default_factory=list)
    health: TrackHealthReport | None = None
    held_out: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    @property
    def velocity(self) -> np.ndarray | None:
        """The part's estimated velocity after the update (m/s, base frame; None while
        waiting)."""
        return None if self.state is None else self.state[VELOCITY].copy()

    @classmethod
    def empty(cls, name: str, status: TrackStatus, n_cameras: int, n_features: int,
              state: np.ndarray | None, covariance: np.ndarray | None,
              T_base_part: np.ndarray | None) -> PartFrame:
        """A record with nothing predicted, selected or measured; the filter's ``state``,
        ``covariance`` and pose (None while there is no filter) as both before and after."""
        C, F = n_cameras, n_features
        return cls(
            name=name,
            status=status,
            visible=np.zeros((C, F), dtype=bool),
            pixels=np.full((C, F, 2), np.nan),
            near_occluder=np.zeros((C, F), dtype=bool),
            unknown=np.zeros((C, F), dtype=bool),
            selected=np.zeros((C, F), dtype=bool),
            selection=None,
            windows=[None] * C,
            measured=np.full((C, F, 2), np.nan),
            innovation=np.full((C, F, 2), np.nan),
            mahalanobis2=np.full((C, F), np.nan),
            rejected=np.zeros((C, F), dtype=bool),
            predicted_state=None if state is None else state.copy(),
            state=None if state is None else state.copy(),
            covariance=None if covariance is None else covariance.copy(),
            T_base_part=T_base_part,
            held_out=np.zeros(C, dtype=bool),
        )

    def set_views(self, views: list[CameraVisibility]) -> None:
        """Record the visibility source's answer for this part (one view per camera)."""
        self.views = list(views)
        for c, view in enumerate(views):
            self.visible[c] = np.asarray(view.visible, dtype=bool)
            self.pixels[c] = np.asarray(view.pixels, dtype=float)
            self.near_occluder[c] = np.asarray(view.near_occluder, dtype=bool)

    @property
    def status_text(self) -> str:
        """The status as a user reads it: ``degraded: <reasons joined by '; '>`` for a degraded
        track, else the status's value (``tracking``, ``coasting``...)."""
        if self.status == TrackStatus.DEGRADED and self.health is not None and self.health.reasons:
            return f"{self.status.value}: {'; '.join(self.health.reasons)}"
        return self.status.value

    @property
    def predicted_visible(self) -> np.ndarray:
        """(C, F) bool: what the tracker expects to see: predicted visible by the visibility
        source and not under an unknown occluder."""
        return self.visible & ~self.unknown

    @property
    def reasons(self) -> list[list[str]]:
        """Per camera, per feature: '' when predicted visible, else why it is hidden
        (:attr:`CameraVisibility.reason`, or ``unknown`` under an unknown occluder); empty when
        nothing was predicted."""
        return [[UNKNOWN_LABEL if self.unknown[c, f] else reason
                 for f, reason in enumerate(view.reason)]
                for c, view in enumerate(self.views)]


@dataclass
class TrackerFrame:
    """One step: time (s), per-part records, stage times (s, keyed by
    :data:`cellsight.tracking.timing.STAGES`), the fraction of each camera's pixels grabbed and
    each camera's unknown-occluder map after the step (:mod:`.unknown`)."""

    t: float
    parts: dict[str, PartFrame]
    timings: dict[str, float]
    grabbed_fraction: np.ndarray
    unknown: list[Grid] = field(default_factory=list)

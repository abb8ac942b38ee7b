"""The tracked parts' step (for :mod:`.tracker`; the paper's loop): for every tracked part, the
selector chooses among the usable features and the window planner places their windows; each
camera's windows of every part are grabbed at once; then part by part the extractor finds
them, the gate screens the innovations and the EKF updates with the accepted ones, and the
track's health monitor, the unknown-occluder map, the loss rule and the camera check take the
frame's outcome."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import partial
from typing import Any, Protocol

import numpy as np

from cellsight.camera import Camera
from cellsight.tracking.acquire import Measuring
from cellsight.tracking.camera_check import CameraCheck, CheckFrame
from cellsight.tracking.ekf import PoseEKF, UpdateReport
from cellsight.tracking.gate import SupportedGate
from cellsight.tracking.grabbing import grabbed
from cellsight.tracking.interfaces import MeasurementModel, OccluderMap
from cellsight.tracking.part_track import (
    PartTrack,
    StepContext,
    cameras_grabbed,
    observed_of,
    record_estimate,
)
from cellsight.tracking.prior.fusion import hold_along_sight, off_holder
from cellsight.tracking.records import PartFrame
from cellsight.tracking.selection import camera_resolution
from cellsight.tracking.status import TrackStatus
from cellsight.tracking.windowing import WindowPlan

UNREGISTERED = "cameras not registered yet"  # the reason while awaiting the registration


class Updating(Measuring, Protocol):
    """What a tracked part's step uses of the tracker besides acquisition's: the cameras'
    measurement models, the unknown-occluder map and whether the cameras are registered."""

    models: list[MeasurementModel]
    unknown: OccluderMap
    registered: bool


class Updater:
    """The tracked parts' step for ``tracker`` (module docstring)."""

    def __init__(self, tracker: Updating) -> None:
        self.tracker = tracker

    def step_all(self, contexts: Sequence[StepContext]) -> dict[str, PartFrame]:
        """Every tracked part's step (the paper's loop) in one pass: each part's features
        selected and their windows planned, then each camera's windows of every part grabbed
        at once, then part by part: extract, gate, update and the health monitor (tracking, or
        degraded when it finds reasons). Returns each part's record, by name."""
        if not contexts:
            return {}
        plans = [self._plan(context) for context in contexts]
        with contexts[0].timer("grab"):
            seen = self.tracker.measurer.grab(contexts[0].observed, plans)
        records = {}
        for context, plan in zip(contexts, plans, strict=True):
            finish = partial(self._finish, plans=plan, seen=seen)
            records[context.rec.name] = with_held_out(self.tracker.camera_check, finish, context)
        return records

    def _plan(self, context: StepContext) -> list[WindowPlan | None]:
        """Select among the part's usable features and plan their windows, per camera."""
        tracker = self.tracker
        rec, track, timer = context.rec, context.track, context.timer
        ekf = track.ekf
        _shift_by_offsets(rec, ekf)
        with timer("selection"):
            usable = tracker.measurer.usable(context, ekf.t)
            resolution = _resolution(tracker.cameras, track)
            sel = tracker.components.selector.select(rec.pixels, usable, resolution)
            rec.selection, rec.selected = sel, sel.selected

        def covariance(c: int, idx: np.ndarray) -> np.ndarray:
            return ekf.innovation_covariance(tracker.models[c], c, track.points[idx])[1]

        return tracker.measurer.plan(context, covariance)

    def _finish(self, context: StepContext, plans: Sequence[WindowPlan | None],
                seen: Sequence[Any]) -> PartFrame:
        """Extract the part's windows (``plans``) from what each camera gave (``seen``, read
        for every part's windows), gate, update, then the health monitor. Returns the part's
        record."""
        tracker = self.tracker
        rec, track = context.rec, context.track
        ekf, timer = track.ekf, context.timer
        obs = tracker.measurer.extract(context, plans, seen)
        looked = rec.selected & cameras_grabbed(context.observed, tracker.cameras)[:, None]
        check, loss = tracker.camera_check, tracker.components.loss
        filtered = check.in_filter()
        counted = looked & filtered[:, None]
        with timer("ekf"):
            gate = tracker.components.gate
            if track.coasted:
                support = loss.resume_support(int(counted.sum()))
                gate = SupportedGate(gate, max(tracker.config.resume_support, support))
            report = ekf.update([o for o in obs if filtered[o.camera_index]], gate)
            track.coasted = report.n_accepted == 0
            if track.holder is not None:
                hold_along_sight(ekf, track.holder, tracker.cameras, report,
                                  tracker.config.hold_std[0])
            _record_update(rec, report)
            rec.health = track.monitor.update(context.t, rec.visible, counted, rec.measured,
                                              rec.rejected, rec.mahalanobis2, rec.unknown,
                                              off_holder(ekf, track.holder))
            if not tracker.registered:
                rec.health = replace(rec.health, reasons=(*rec.health.reasons, UNREGISTERED))
            unknown = tracker.components.unknown
            if report.n_accepted >= unknown.min_accepted:
                track.confirmed = context.t
            if context.t - track.confirmed <= unknown.trust_s:
                _learn_unknown(tracker.unknown, context.t, rec, counted)
        in_view = any(cam.in_image(rec.pixels[c]).any() for c, cam in enumerate(tracker.cameras))
        in_vain = loss.in_vain(int(counted.sum()), report.n_accepted, in_view)
        if in_vain is not None:
            track.unseen_since = min(track.unseen_since, context.t) if in_vain else np.inf
        if report.n_accepted:
            track.last_update = ekf.t
            track.held_at = None  # the filter knows where it is
            rec.status = TrackStatus.DEGRADED if rec.health.reasons else TrackStatus.TRACKING
        record_estimate(rec, ekf)
        _check_cameras(check, tracker.measurer.detect, tracker.cameras, context, looked,
                       report.n_accepted > 0)
        return rec


def with_held_out(check: CameraCheck, step: Callable[[StepContext], PartFrame],
                  context: StepContext) -> PartFrame:
    """``step(context)``'s record, with the cameras the camera check held out of the filter as
    the step began (``PartFrame.held_out``; the check moves on at the step's end)."""
    held_out = ~check.in_filter()
    rec = step(context)
    rec.held_out = held_out
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


def _check_cameras(check: CameraCheck, detect: Callable[[Any], np.ndarray] | None,
                   cameras: Sequence[Camera], context: StepContext, looked: np.ndarray,
                   updated: bool) -> None:
    """Feed the camera check (:mod:`.camera_check`) this frame of the part (``detect``: the
    whole-image corner detector, None: none; ``looked``: the (C, F) features looked for;
    ``updated``: the usable cameras updated the estimate)."""
    rec, T = context.rec, context.track.ekf.pose

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

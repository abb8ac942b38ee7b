"""Each vision frame's row of ``frames.csv`` (columns: :mod:`cellsight.runfolder.framelog`),
from what the run loop has at hand: the tracker's record, the simulator's truth (read once per
frame: :class:`FrameTruth`), the PnP baseline and the task."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellsight.experiments.plant import GroundTruth, SimulatedCell
from cellsight.model.robot import Robot
from cellsight.runfolder.framelog import (
    WRONG_PX,
    camera_column,
    encode_bits,
    encode_corners,
    encode_grid,
    encode_labels,
    encode_windows,
    joint_fields,
    pose_fields,
    timing_fields,
)
from cellsight.tracking.health import TrackHealthReport
from cellsight.tracking.records import PartFrame, TrackerFrame
from cellsight.visibility import CameraVisibility


@dataclass(frozen=True)
class PartTruth:
    """The simulator's truth about one workpiece at one frame: ``T_base_part`` and what each
    camera sees of it (``views``, one per camera)."""

    T_base_part: np.ndarray
    views: list[CameraVisibility]

    @classmethod
    def of(cls, world: GroundTruth, part: str) -> PartTruth:
        return cls(world.true_part_poses()[part], world.true_views()[part])

    @property
    def pixels(self) -> np.ndarray:
        """(C, F, 2) true projections (px, distorted; NaN behind a camera)."""
        return np.stack([v.pixels for v in self.views])

    @property
    def visible(self) -> np.ndarray:
        """(C, F) truly visible."""
        return np.stack([v.visible for v in self.views])


@dataclass(frozen=True)
class FrameTruth:
    """The simulator's truth at one vision frame, read once: the workpiece's (``part``; None
    where nothing knows it, e.g. a recording without the part's pose), every robot's true
    ``joints`` (rad, m), and of the grasping robot: its jaw opening (m), its jaws closed on the
    part, the grasp engaged."""

    part: PartTruth | None
    joints: dict[str, np.ndarray]
    jaw_opening: float
    jaws_closed: bool
    grasped: bool

    @classmethod
    def of(cls, world: SimulatedCell, part: str, robot: str) -> FrameTruth:
        """The truth now about workpiece ``part`` and robot ``robot``."""
        return cls(PartTruth.of(world, part), world.true_joints(), world.jaw_openings()[robot],
                   world.jaws_closed_on_part(robot), world.grasp(robot) is not None)


class FrameRows:
    """Builds the rows for one workpiece grasped by ``robot``. ``pixel_errors``: log the
    extraction error (``err_px_c*``; meaningless for the ideal sensor, which draws its
    measurements around the truth)."""

    def __init__(self, robot: Robot, n_cameras: int, pixel_errors: bool) -> None:
        self.robot = robot
        self.n_cameras = n_cameras
        self.pixel_errors = pixel_errors

    def row(self, t: float, phase: str, stage: str, frame: TrackerFrame, rec: PartFrame,
            truth: FrameTruth, pnp: np.ndarray | None) -> dict:
        """The row of the frame at time ``t`` (s), in the task's ``phase`` and ``stage``."""
        row: dict[str, object] = {"t": round(t, 5), "phase": phase, "stage": stage,
                                  "status": rec.status_text}
        estimate = rec.T_base_part if rec.status.has_estimate else None
        true_pose = None if truth.part is None else truth.part.T_base_part
        for prefix, T in (("true", true_pose), ("est", estimate), ("pnp", pnp)):
            row.update(pose_fields(prefix, T))
        row.update(self._gripper(truth))
        row.update(joint_fields(truth.joints))
        reasons = rec.reasons
        for c in range(self.n_cameras):
            row.update(self._camera(c, rec, truth.part, reasons[c] if reasons else None))
            if c < len(frame.unknown):
                row[camera_column("unknown", c + 1)] = encode_grid(frame.unknown[c])
        row.update(timing_fields(frame.timings))
        return row

    def _gripper(self, truth: FrameTruth) -> dict:
        """The gripper's columns: its true TCP position (m, base frame) and its jaws."""
        tcp = self.robot.tcp_pose(truth.joints[self.robot.name])[:3, 3]
        return {"gripper_x": tcp[0], "gripper_y": tcp[1], "gripper_z": tcp[2],
                "jaw_opening": truth.jaw_opening, "jaws_closed": int(truth.jaws_closed),
                "grasped": int(truth.grasped)}

    def _camera(self, c: int, rec: PartFrame, truth: PartTruth | None,
                reasons: list[str] | None) -> dict:
        """Camera ``c``'s columns (0-based; columns are numbered from 1); ``reasons``: the
        prediction's, None when nothing was predicted; without a ``truth`` its columns
        (``vis_true``, ``occ_true``, ``wrong``, ``err_px``) are empty."""
        measured = np.all(np.isfinite(rec.measured[c]), axis=1)
        plan = rec.windows[c]
        values = {
            "vis_pred": encode_bits(rec.predicted_visible[c]),
            "sel": encode_bits(rec.selected[c]), "meas": encode_bits(measured),
            "rej": encode_bits(rec.rejected[c]),
            "occ_pred": None if reasons is None else encode_labels(reasons),
            "grab": 0.0 if plan is None else plan.fraction,
            "windows": "" if plan is None else encode_windows(plan.features, plan.boxes),
            "corners": encode_corners(rec.measured[c]),
            "held_out": int(c < len(rec.held_out) and rec.held_out[c]),
            **_health_fields(rec.health, c),
        }
        if truth is not None:
            view = truth.views[c]
            err = np.linalg.norm(rec.measured[c, measured] - view.pixels[measured], axis=1)
            wrong = np.zeros_like(measured)
            wrong[measured] = ~(err <= WRONG_PX)
            values.update({
                "vis_true": encode_bits(view.visible), "wrong": encode_bits(wrong),
                "occ_true": encode_labels(view.reason),
                "err_px": float(np.median(err)) if len(err) and self.pixel_errors else None})
        return {camera_column(name, c + 1): v for name, v in values.items()}


def _health_fields(health: TrackHealthReport | None, c: int) -> dict[str, float | None]:
    """Camera ``c``'s health columns (``nis``, ``notfound``, ``rejfrac``): None (empty) while
    the track has no health report or the figure is not judged (NaN)."""
    if health is None:
        return {"nis": None, "notfound": None, "rejfrac": None}
    values = {"nis": health.nis_ratio[c], "notfound": health.missing_fraction[c],
              "rejfrac": health.rejected_fraction[c]}
    return {k: round(float(v), 4) if np.isfinite(v) else None for k, v in values.items()}

"""Each vision frame's row of ``frames.csv`` (columns: :mod:`cellsight.runfolder.framelog`),
from what the run session has at hand: the tracker's record, what the source knows of the truth
(read once per frame: :class:`FrameTruth`), the PnP baseline and the task."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cellsight.model.robot import Robot
from cellsight.runfolder.framelog import (
    WRONG_PX,
    FrameWriter,
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
from cellsight.runfolder.writes import RunWrites
from cellsight.session.baseline import PnPBaseline
from cellsight.session.frames import FrameRecord, FrameTruth, PartTruth
from cellsight.session.protocols import RunContext
from cellsight.tracking.health import TrackHealthReport
from cellsight.tracking.records import PartFrame, TrackerFrame


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


class FramesCsv:
    """The sink of ``frames.csv``: one row a frame (:class:`FrameRows`), with the pose the
    PnP ``baseline`` finds from the same corners. On a line, one for each of the ``picks``
    (names, in order): ``part`` names the pick it logs, into ``name`` (in the run folder); its
    phase and stage are the task's while it is picked now, ``waiting`` before its turn and
    ``done`` after it (None: the record's part, ``frames.csv``); a part not among ``picks`` (a
    line's passing part) is ``passing``."""

    def __init__(self, rows: FrameRows, baseline: PnPBaseline, part: str | None = None,
                 name: str = "frames.csv", picks: Sequence[str] = ()) -> None:
        self.rows, self.baseline = rows, baseline
        self.part, self.name, self.picks = part, name, list(picks)
        self.writer: FrameWriter | None = None
        self.writes: RunWrites | None = None

    def start(self, run: RunContext) -> None:
        self.writes = run.writes
        path = run.out / self.name
        with self.writes.guard(path):
            path.parent.mkdir(parents=True, exist_ok=True)
        self.writer = FrameWriter(path, len(run.cell.cameras),
                                  {r.name: r.n_joints for r in run.cell.robots})

    def frame(self, record: FrameRecord) -> None:
        current = record.part.name
        name = current if self.part is None else self.part
        part = record.result.parts[name]
        phase, stage = record.phase, record.stage
        if name not in self.picks and self.part is not None:
            phase, stage = "passing", ""
        elif name != current:
            before = self.picks.index(name) < self.picks.index(current)
            phase, stage = ("done", "") if before else ("waiting", "")
        pnp = self.baseline.update(record.t, part.measured)
        row = self.rows.row(record.t, phase, stage, record.result, part,
                            record.truth_of(name), pnp)
        with self.writes.guard(self.writer.path):
            self.writer.write(row)

    def close(self, completed: bool) -> None:
        self.writes.close(self.writer.path, self.writer.close)

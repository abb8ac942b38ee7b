"""A run folder read back for replay (:class:`RunReplay`), through
:func:`cellsight.runfolder.load_run` (``metrics.json``, the cell and ``frames.csv``, checked
against each other: a missing file, a field of the wrong type, a run logged before the joint
columns or a log that does not fit the cell is a :class:`~cellsight.errors.CellsightError`
naming the file and the field), plus the selection and measurement bits the view draws, and
the windows and measured corners where the run logged them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cellsight.geometry.transforms import transform_points
from cellsight.runfolder import load_run
from cellsight.runfolder.framelog import camera_column, decode_corners, decode_windows
from cellsight.view.states import FeatureState, FrameState

BIT_COLUMNS = ("vis_pred", "vis_true", "sel", "meas", "rej")


class RunReplay:
    """A run's frames for the view: ``n`` frames at times ``t`` (s), :meth:`state` of each.

    ``cell_arg``: ``--cell`` (a built-in cell's name or a file), overriding the cell file named
    in ``metrics.json``.
    """

    def __init__(self, folder: str | Path, cell_arg: str | None = None) -> None:
        self.folder = Path(folder)
        self.run = load_run(self.folder, cell_arg)
        self.cell = self.run.cell
        self.part, self.robot = self.run.part.name, self.run.robot
        self.bits = {name: self.run.bits(name) for name in BIT_COLUMNS}
        self.text = {k: self.run.frames.text(k) for k in ("phase", "stage", "status")}
        self.unknown = [self.run.frames.grids(camera_column("unknown", c + 1))
                        for c in range(len(self.cell.cameras))]
        self.n, self.t = self.run.n, self.run.t

    def _logged(self, k: int, n_features: int) -> tuple[list | None, np.ndarray | None]:
        """Frame ``k``'s windows (per camera (n, 4)) and measured corners (C, F, 2) as the run
        logged them; (None, None) for a run logged before those columns."""
        frames = self.run.frames
        if camera_column("windows", 1) not in frames.columns:
            return None, None
        cameras = range(1, len(self.cell.cameras) + 1)
        windows = [decode_windows(frames.text(camera_column("windows", c))[k])[1]
                   for c in cameras]
        corners = np.array([decode_corners(frames.text(camera_column("corners", c))[k],
                                           n_features) for c in cameras])
        return windows, corners

    def frame_at(self, t: float) -> int:
        """The frame nearest to time ``t`` (s)."""
        return int(np.argmin(np.abs(self.t - t)))

    def caption(self, k: int) -> str:
        text = self.text
        return (f"t = {self.t[k]:.2f} s · frame {k + 1}/{self.n} · {text['phase'][k]} "
                f"({text['stage'][k]}) · tracker {text['status'][k]}")

    def state(self, k: int) -> FrameState:
        """Frame ``k`` (0-based): the logged joints, true and estimated part, jaw opening and
        bits; predicted pixels at the estimate (the true pose while there is none)."""
        run, cell, bits = self.run, self.cell, self.bits
        joints = {robot: q[k] for robot, q in run.joints.items()}
        true = run.T_true[k]
        estimates = {}
        if np.all(np.isfinite(run.T_est[k])):
            estimates[self.part] = run.T_est[k]
        openings = {}
        if self.robot in joints and np.isfinite(run.opening[k]):
            openings[self.robot] = float(run.opening[k])
        points = cell.workpiece(self.part).feature_points
        shown = transform_points(estimates.get(self.part, true), points)
        truth = transform_points(true, points)
        windows, corners = self._logged(k, len(points))
        features = FeatureState(
            visible=bits["vis_pred"][k], truth=bits["vis_true"][k],
            pixels=np.array([cam.project(shown) for cam in cell.cameras]),
            selected=bits["sel"][k], measured=bits["meas"][k],
            rejected=bits["rej"][k],
            measured_pixels=(corners if corners is not None
                             else np.array([cam.project(truth) for cam in cell.cameras])),
            windows=windows)
        return FrameState(joints, {self.part: true}, openings, estimates,
                          {self.part: features}, self.caption(k),
                          [grids[k] for grids in self.unknown])

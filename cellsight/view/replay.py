"""A run folder read back for replay (:class:`RunReplay`): ``metrics.json`` (its ``cell`` key
names the cell file; ``robot`` and ``workpiece`` the grasping robot and the tracked part) and
``frames.csv`` (:class:`~cellsight.framelog.FrameLog`: every robot's logged joints, the part's
true and estimated pose, the jaw opening, the per-camera visibility, selection and measurement
bits). Everything is checked against the cell when the folder is opened; a missing file, a
field of the wrong type, a run logged before the joint columns or a log that does not fit the
cell is a :class:`~cellsight.errors.CellsightError` naming the file and the field."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cellsight.errors import CellsightError, short_repr
from cellsight.framelog import FrameLog, camera_column
from cellsight.geometry.transforms import pose_from_xyz_rpy, transform_points
from cellsight.model.cell import Cell
from cellsight.model.loader import load_cell
from cellsight.view.states import FeatureState, FrameState

BIT_COLUMNS = ("vis_pred", "vis_true", "sel", "meas", "rej")


def read_metrics(folder: Path) -> dict:
    """``<folder>/metrics.json`` as a dict, else a clear error naming the file."""
    path = folder / "metrics.json"
    if not folder.is_dir():
        raise CellsightError(f"{folder}: no such run folder (the output folder of "
                             f"'cellsight run')")
    try:
        metrics = json.loads(path.read_bytes().decode("utf-8"))
    except FileNotFoundError as exc:
        raise CellsightError(f"{path}: no metrics.json here (is {folder} the output folder of "
                             f"'cellsight run'?)") from exc
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise CellsightError(f"{path}: not a readable JSON file ({exc})") from exc
    if not isinstance(metrics, dict):
        raise CellsightError(f"{path}: expected a JSON object, got {short_repr(metrics)}")
    return metrics


def _text_field(metrics: dict, key: str, path: Path) -> str:
    value = metrics.get(key)
    if not isinstance(value, str) or not value:
        raise CellsightError(f"{path}: field {key!r}: expected a name, got {short_repr(value)}")
    return value


def run_cell(folder: Path, metrics: dict, cell_arg: str | None) -> Cell:
    """The run's cell: ``cell_arg`` (``--cell``) when given, else the file ``metrics.json``
    names; an error that says which when it cannot be loaded."""
    if cell_arg is not None:
        return load_cell(cell_arg)
    source = _text_field(metrics, "cell", folder / "metrics.json")
    try:
        return load_cell(source)
    except CellsightError as exc:
        raise CellsightError(f"{folder / 'metrics.json'}: field 'cell': {source!r} cannot be "
                             f"loaded ({exc}); give the cell with --cell") from exc


@dataclass
class _Columns:
    """The log's columns as arrays, N frames."""

    t: np.ndarray  # (N,)
    joints: dict[str, np.ndarray]  # robot -> (N, n)
    true: np.ndarray  # (N, 6)
    est: np.ndarray  # (N, 6), NaN rows without an estimate
    opening: np.ndarray  # (N,), NaN where missing
    bits: dict[str, np.ndarray]  # BIT_COLUMNS name -> (N, C, F)
    text: dict[str, list[str]]  # phase, stage, status


class RunReplay:
    """A run's frames for the view: ``n`` frames at times ``t`` (s), :meth:`state` of each.

    ``cell_arg``: ``--cell`` (a built-in cell's name or a file), overriding the cell file named
    in ``metrics.json``.
    """

    def __init__(self, folder: str | Path, cell_arg: str | None = None) -> None:
        self.folder = Path(folder)
        self.metrics = read_metrics(self.folder)
        self.cell = run_cell(self.folder, self.metrics, cell_arg)
        metrics_path = self.folder / "metrics.json"
        self.part = _text_field(self.metrics, "workpiece", metrics_path)
        self.robot = self.metrics.get("robot")
        self.cell.workpiece(self.part)
        self.log = FrameLog.read(self.folder / "frames.csv")
        self._columns = self._read_columns()
        self.n = self.log.n
        self.t = self._columns.t

    def _read_columns(self) -> _Columns:
        log, path, cell = self.log, self.folder / "frames.csv", self.cell
        if log.n == 0:
            raise CellsightError(f"{path}: no frames (missing or empty file)")
        if not log.robots:
            raise CellsightError(f"{path}: no joint columns (q_<robot>_<j>): the run was logged "
                                 f"before they were added; run it again to replay it")
        joints = {}
        for robot, n in log.robots.items():
            try:
                expected = cell.robot(robot).chain.n
            except KeyError as exc:
                raise CellsightError(f"{path}: columns q_{robot}_*: {exc.args[0]}") from exc
            if n != expected:
                raise CellsightError(f"{path}: columns q_{robot}_1..{n}: robot {robot} of "
                                     f"{cell.name} has {expected} joints")
            joints[robot] = log.joints(robot)
            if not np.all(np.isfinite(joints[robot])):
                raise CellsightError(f"{path}: columns q_{robot}_*: a value is missing or not "
                                     f"a number")
        bits = {name: self._bits(name) for name in BIT_COLUMNS}
        return _Columns(log.floats("t"), joints, log.poses("true"), log.poses("est"),
                        log.floats("jaw_opening"), bits,
                        {k: log.text(k) for k in ("phase", "stage", "status")})

    def _bits(self, name: str) -> np.ndarray:
        """(N, C, F) bool of a per-camera 0/1 column, checked against the cell."""
        path, cell = self.folder / "frames.csv", self.cell
        C, F = len(cell.cameras), len(cell.workpiece(self.part).feature_points)
        if self.log.n_cameras != C:
            raise CellsightError(f"{path}: columns vis_pred_c*: {self.log.n_cameras} cameras "
                                 f"logged; cell {cell.name} has {C}")
        out = np.zeros((self.log.n, C, F), dtype=bool)
        for c in range(C):
            try:
                out[:, c] = self.log.bits(camera_column(name, c + 1), F)
            except ValueError as exc:
                raise CellsightError(f"{path}: {exc} (workpiece {self.part} of {cell.name})"
                                     ) from exc
        return out

    def frame_at(self, t: float) -> int:
        """The frame nearest to time ``t`` (s)."""
        return int(np.argmin(np.abs(self.t - t)))

    def caption(self, k: int) -> str:
        text = self._columns.text
        return (f"t = {self.t[k]:.2f} s · frame {k + 1}/{self.n} · {text['phase'][k]} "
                f"({text['stage'][k]}) · tracker {text['status'][k]}")

    def state(self, k: int) -> FrameState:
        """Frame ``k`` (0-based): the logged joints, true and estimated part, jaw opening and
        bits; predicted pixels at the estimate (the true pose while there is none)."""
        cols, cell = self._columns, self.cell
        joints = {robot: q[k] for robot, q in cols.joints.items()}
        true = pose_from_xyz_rpy(cols.true[k, :3], cols.true[k, 3:])
        estimates = {}
        if np.all(np.isfinite(cols.est[k])):
            estimates[self.part] = pose_from_xyz_rpy(cols.est[k, :3], cols.est[k, 3:])
        openings = {}
        if self.robot in joints and np.isfinite(cols.opening[k]):
            openings[self.robot] = float(cols.opening[k])
        points = cell.workpiece(self.part).feature_points
        shown = transform_points(estimates.get(self.part, true), points)
        truth = transform_points(true, points)
        features = FeatureState(
            visible=cols.bits["vis_pred"][k], truth=cols.bits["vis_true"][k],
            pixels=np.array([cam.project(shown) for cam in cell.cameras]),
            selected=cols.bits["sel"][k], measured=cols.bits["meas"][k],
            rejected=cols.bits["rej"][k],
            measured_pixels=np.array([cam.project(truth) for cam in cell.cameras]))
        return FrameState(joints, {self.part: true}, openings, estimates,
                          {self.part: features}, self.caption(k))

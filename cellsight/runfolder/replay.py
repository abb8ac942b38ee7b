"""A run folder read back (:func:`load_run`), for everything that replays a run: ``cellsight
view``, ``cellsight export`` and ``cellsight place-cameras``. Its ``metrics.json``, its cell and
its ``frames.csv`` are checked against each other, with every problem a :class:`RunDataError`
naming the file, the field and the value.

A run logged before ``frames.csv`` had the robots' joints (``q_<robot>_<j>``) cannot be
replayed: its robots' motion is not in the log, so neither their poses nor the camera images
(where they hide the part) could be made right; it says so and asks for the run again.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cellsight.errors import CellsightError, short_repr
from cellsight.geometry.transforms import pose_from_xyz_rpy
from cellsight.model.cell import Cell, Workpiece
from cellsight.model.loader import load_cell
from cellsight.runfolder.cell_copy import kept_cell
from cellsight.runfolder.checked import frames_digest
from cellsight.runfolder.digest import cell_digest, file_digest
from cellsight.runfolder.framelog import POSE, FrameLog, camera_column
from cellsight.runfolder.metrics import RunDataError, read_metrics


@dataclass
class RunData:
    """A run's log, checked. ``t`` (N,) s; ``joints``: robot -> (N, n); ``T_true`` (N, 4, 4)
    the part's true pose (NaN in a tracked recording's frames without one); ``T_est``
    (N, 4, 4), NaN where the tracker had no estimate;
    ``opening`` (N,) the grasping robot's jaw opening (m, NaN where not logged);
    ``vis_pred`` / ``vis_true``: per camera (N, F) bool and ``*_present`` (N,) bool."""

    folder: Path
    metrics: dict
    cell: Cell
    frames: FrameLog
    part: Workpiece
    robot: str | None
    t: np.ndarray
    joints: dict[str, np.ndarray]
    T_true: np.ndarray
    T_est: np.ndarray
    opening: np.ndarray
    vis_pred: list[np.ndarray]
    vis_true: list[np.ndarray]
    vis_pred_present: list[np.ndarray]
    vis_true_present: list[np.ndarray]

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def gripper(self) -> str | None:
        """The robot whose jaw opening frames.csv logs: the grasping robot, when it has a
        tool."""
        tool = self.robot is not None and any(r.name == self.robot and r.tool is not None
                                              for r in self.cell.robots)
        return self.robot if tool else None

    def world_cell(self) -> Cell:
        """The cell the run's world was: its realism profile's draws for its seed
        (``realism_spec`` and ``seed`` of ``metrics.json``), or the cell file's when the world
        was ``exact`` (or the profile is not known). Images re-rendered of the run come from it;
        a profile file edited since the run draws another world."""
        spec = self.metrics.get("realism_spec")
        if not isinstance(spec, str) or spec == "exact":
            return self.cell
        from cellsight.realism import draw_world

        return draw_world(spec, self.cell, int(self.metrics.get("seed") or 0)).cell

    def bits(self, name: str) -> np.ndarray:
        """(N, C, F) bool of the per-camera 0/1 column ``name`` (``vis_pred``, ``vis_true``,
        ``sel``, ``meas``, ``rej``, ``wrong``); rows without a value are all False."""
        return np.stack(_visibility(self.frames, self.cell, self.part, name)[0], axis=1)


def _text_field(metrics: dict, key: str, path: Path, optional: bool = False) -> str | None:
    value = metrics.get(key)
    if value is None and optional:
        return None
    if not isinstance(value, str) or not value:
        raise RunDataError(f"{path}: field {key!r}: got {short_repr(value)}; expected a name")
    return value


def run_cell(metrics: dict, folder: Path, cell: str | Path | None = None) -> Cell:
    """The run's cell: ``cell`` if given (a name or a file), else the cell kept in the run
    folder (:func:`~cellsight.runfolder.cell_copy.kept_cell`), else, for a run from before
    cells were kept, metrics.json's ``cell`` as long as it is the file the run used
    (``cell_sha256``)."""
    if cell is not None:
        return load_cell(cell)
    kept = kept_cell(folder, metrics)
    if kept is not None:
        return kept
    path = folder / "metrics.json"
    source = _text_field(metrics, "cell", path)
    try:
        the_cell = load_cell(source)
    except CellsightError as exc:
        raise RunDataError(f"{path}: field 'cell': {source!r} cannot be loaded ({exc}); pass "
                           f"--cell NAME|FILE to name the run's cell") from exc
    recorded = metrics.get("cell_sha256")
    now = cell_digest(the_cell) if metrics.get("metrics_version", 0) else file_digest(source)
    if recorded is not None and recorded != now:
        raise RunDataError(f"{path}: field 'cell': {source} has changed since the run (its "
                           f"SHA-256 differs from cell_sha256); pass --cell NAME|FILE to "
                           f"replay with it anyway")
    return the_cell


def _row_error(frames: FrameLog, t: np.ndarray, row: int, column: str) -> RunDataError:
    value = frames.text(column)[row] if column in frames.columns else None
    shown = "empty" if not value else f"{short_repr(value)}, not a finite number"
    when = f" (t = {t[row]:.3f} s)" if np.isfinite(t[row]) else ""
    return RunDataError(f"frames.csv row {row + 1}{when}: field {column!r} is {shown}")


def _finite_columns(frames: FrameLog, t: np.ndarray, names: list[str]) -> np.ndarray:
    """(N, len(names)) floats of columns that must have a finite value in every row."""
    for name in names:
        if name not in frames.columns:
            raise RunDataError(f"frames.csv: no column {name!r}")
    values = np.column_stack([frames.floats(n) for n in names]).reshape(frames.n, len(names))
    bad = np.argwhere(~np.isfinite(values))
    if len(bad):
        row, col = bad[0]
        raise _row_error(frames, t, int(row), names[int(col)])
    return values


def _times(frames: FrameLog, path: Path) -> np.ndarray:
    if frames.n == 0:
        raise RunDataError(f"{path}: no frames (missing, empty, or no complete row)")
    t = _finite_columns(frames, np.full(frames.n, np.nan), ["t"])[:, 0]
    if np.any(t < 0) or np.any(np.diff(t) < 0):
        row = int(np.flatnonzero((t < 0) | np.r_[False, np.diff(t) < 0])[0])
        raise RunDataError(f"{path} row {row + 1}: field 't' = {t[row]!r}; expected times "
                           f">= 0 s, in increasing order")
    return t


def _joints(frames: FrameLog, cell: Cell, t: np.ndarray, path: Path) -> dict[str, np.ndarray]:
    """Every cell robot's logged joints, checked against the cell."""
    logged = frames.robots
    if not logged:
        raise RunDataError(f"{path}: no joint columns (q_<robot>_<j>): this run was logged "
                           f"before cellsight logged the robots' joints, so its robots cannot "
                           f"be replayed; run the experiment again (cellsight run) to replay "
                           f"or export it")
    names = {r.name for r in cell.robots}
    for robot, n in logged.items():
        if robot not in names:
            raise RunDataError(f"{path}: joint columns of robot {robot!r}, which cell "
                               f"{cell.source} does not have (its robots: {sorted(names)})")
        if n != cell.robot(robot).n_joints:
            raise RunDataError(f"{path}: robot {robot!r} has {n} joint columns; cell "
                               f"{cell.source} gives it {cell.robot(robot).n_joints} joints")
    missing = sorted(names - set(logged))
    if missing:
        raise RunDataError(f"{path}: no joint columns of robot(s) {missing} of cell "
                           f"{cell.source}")
    return {r.name: _finite_columns(frames, t, [f"q_{r.name}_{j}"
                                                for j in range(1, r.n_joints + 1)])
            for r in cell.robots}


def _poses(rows: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses of (N, 6) pose columns; NaN where a row is missing."""
    out = np.full((len(rows), 4, 4), np.nan)
    for i, row in enumerate(rows):
        if np.all(np.isfinite(row)):
            out[i] = pose_from_xyz_rpy(row[:3], row[3:])
    return out


def _visibility(frames: FrameLog, cell: Cell, part: Workpiece, name: str):
    """Per camera: (N, F) bits of the 0/1 column ``name`` and (N,) rows with a value."""
    F = len(part.feature_points)
    bits, present = [], []
    for c in range(1, len(cell.cameras) + 1):
        column = camera_column(name, c)
        try:
            bits.append(frames.bits(column, F))
        except CellsightError as exc:
            raise RunDataError(f"{exc} (the features of workpiece {part.name!r} of cell "
                               f"{cell.source})") from exc
        present.append(frames.present(column))
    return bits, present


def load_run(folder: str | Path, cell: str | Path | None = None,
             metrics: dict | None = None) -> RunData:
    """Read and check a run folder (module docstring); ``cell`` overrides metrics.json's;
    ``metrics``: the run's metrics when its metrics.json is not written yet (a run's report,
    written just before it)."""
    folder = Path(folder)
    if metrics is None:
        metrics = read_metrics(folder)
        frames_digest(folder, metrics)
    the_cell = run_cell(metrics, folder, cell)
    path = folder / "metrics.json"
    part_name = _text_field(metrics, "workpiece", path)
    try:
        part = the_cell.workpiece(part_name)
    except KeyError as exc:
        raise RunDataError(f"{path}: field 'workpiece': {exc.args[0]}") from None
    robot = _text_field(metrics, "robot", path, optional=True)
    csv_path = folder / "frames.csv"
    frames = FrameLog.read(csv_path)
    t = _times(frames, csv_path)
    if frames.n_cameras != len(the_cell.cameras):
        raise RunDataError(f"{csv_path}: {frames.n_cameras} cameras logged (vis_pred_c*); cell "
                           f"{the_cell.source} has {len(the_cell.cameras)}")
    joints = _joints(frames, the_cell, t, csv_path)
    T_true = (_poses(frames.poses("true")) if "recording" in metrics  # truth where recorded
              else _poses(_finite_columns(frames, t, [f"true_{a}" for a in POSE])))
    T_est = _poses(frames.poses("est"))
    opening = frames.floats("jaw_opening")
    vis_pred, pred_present = _visibility(frames, the_cell, part, "vis_pred")
    vis_true, true_present = _visibility(frames, the_cell, part, "vis_true")
    return RunData(folder, metrics, the_cell, frames, part, robot, t, joints, T_true, T_est,
                   opening, vis_pred, vis_true, pred_present, true_present)

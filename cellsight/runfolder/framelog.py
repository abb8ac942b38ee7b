"""``frames.csv``, the per-frame log of an experiment run: its columns, its writer and reader.

One row per vision frame, written and flushed as the run goes: its columns, their units and
meanings are :data:`COLUMN_DOCS` (C cameras numbered c = 1..C, F features; an empty field is a
missing value).

Strings are quoted (``csv.QUOTE_NONNUMERIC``); read the 0/1 columns as strings (pandas:
``dtype=str``) or their leading zeros are lost. :class:`FrameWriter` writes the file,
:class:`FrameLog` reads it back with typed accessors; run folders written before this module
existed have the same format and load the same way.
"""

from __future__ import annotations

import csv
import re
from collections.abc import Callable, Mapping, Sequence
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TextIO

import numpy as np

from cellsight.errors import CellsightError
from cellsight.geometry.transforms import xyz_rpy_from_pose
from cellsight.runfolder.digest import is_regular_file
from cellsight.runfolder.writes import WriteError, write_error
from cellsight.tracking.timing import STAGES
from cellsight.tracking.unknown import Grid

POSE = ("x", "y", "z", "roll", "pitch", "yaw")
"""The six pose columns after a prefix: position (m), roll-pitch-yaw (rad)."""
POSE_PREFIXES = ("true", "est", "pnp")
GRIPPER = ("gripper_x", "gripper_y", "gripper_z", "jaw_opening", "jaws_closed", "grasped")
PER_CAMERA = ("vis_pred", "vis_true", "sel", "meas", "rej", "wrong", "occ_pred", "occ_true",
              "grab", "err_px", "nis", "notfound", "rejfrac", "unknown", "windows", "corners",
              "held_out")
COLUMN_DOCS: dict[str, tuple[str, str]] = {
    "t": ("s", "the frame's time since the start of the run"),
    "phase": ("-", "the grasping task's phase: waiting, approach, grasp, manipulate, release, "
              "done or failed"),
    "stage": ("-", "the task's stage within its phase"),
    "status": ("-", "the tracker's status (TrackStatus): waiting, acquired, tracking, degraded "
               "with its reasons ('degraded: 75% not found in cam1'), coasting, lost"),
    "true_{x,y,z,roll,pitch,yaw}": ("m, rad", "the part's true pose in the base frame, "
                                    "roll-pitch-yaw as xyz_rpy_from_pose"),
    "est_{x,y,z,roll,pitch,yaw}": ("m, rad", "the EKF's estimate after this frame's update; "
                                   "empty while the part is not acquired yet, or lost"),
    "pnp_{x,y,z,roll,pitch,yaw}": ("m, rad", "the per-frame multi-camera PnP baseline on the "
                                   "same measurements (a frame with too few holds the last fix, "
                                   "for at most the tracker's lost_after_s)"),
    "gripper_{x,y,z}": ("m", "the grasping robot's true TCP in the base frame"),
    "jaw_opening": ("m", "the grasping robot's jaw opening"),
    "jaws_closed": ("0/1", "the jaws are closed on the part"),
    "grasped": ("0/1", "the part is held"),
    "q_{robot}_{j}": ("rad, m", "every robot's true joint j (1-based): enough to replay the "
                      "cell (cellsight view, cellsight export)"),
    "vis_pred_c{c}": ("F bits", "predicted visible at the tracker's predicted pose, and not "
                      "under an unknown occluder"),
    "vis_true_c{c}": ("F bits", "visible by the simulator's ray casts at the true pose"),
    "sel_c{c}": ("F bits", "selected: a window was planned"),
    "meas_c{c}": ("F bits", "a feature was measured in its window"),
    "rej_c{c}": ("F bits", "measured, and rejected by the EKF's gate"),
    "wrong_c{c}": ("F bits", "measured more than WRONG_PX (3 px) from the feature's true "
                   "projection"),
    "occ_pred_c{c}": ("F labels", "why each feature is predicted hidden, joined by ';': empty "
                      "when visible, self, behind, outside, the hiding object's label, or "
                      "unknown (under the tracker's unknown-occluder map)"),
    "occ_true_c{c}": ("F labels", "the same, by the simulator's ray casts at the true pose"),
    "grab_c{c}": ("fraction", "share of the image's pixels grabbed"),
    "err_px_c{c}": ("px", "median distance of this frame's measurements from the true "
                    "projections (rendered sensor)"),
    "nis_c{c}": ("-", "the track's normalised innovation squared per degree of freedom over "
                 "its sliding window; empty while the part is not tracked or judged"),
    "notfound_c{c}": ("fraction", "share of selected, predicted-visible features not found, "
                      "over the health window"),
    "rejfrac_c{c}": ("fraction", "share of measured features the gate rejected, over the "
                     "health window"),
    "unknown_c{c}": ("grid", "the unknown-occluder map's occluded cells after the frame "
                     "(encode_grid: '<rows>x<columns>@<pitch_px>:<hex>'); empty when none"),
    "windows_c{c}": ("px", "the windows planned, each 'j u0 v0 u1 v1' (feature index from 0, "
                     "half-open pixel box), joined by ';'"),
    "corners_c{c}": ("px", "the corners measured, each 'j u v' (to 0.001 px), joined by ';'"),
    "held_out_c{c}": ("0/1", "the camera check held the camera out of the filter (dropped, or "
                      "between its two looks): its measurements used for nothing"),
    "t_{stage}_ms": ("ms", "the tracker's time in each stage of STAGES: occlusion, selection, "
                     "windowing, extraction, ekf (prediction + update), total; then grab, the "
                     "cameras' reading of the windows, in no other stage"),
}
"""Every column family of ``frames.csv``: name pattern -> (unit, meaning). ``F bits``: a string
of F characters ``0``/``1`` in feature order (:func:`encode_bits`); ``F labels``: F labels
joined by ``;`` (:func:`encode_labels`)."""
WRONG_PX = 3.0  # a measurement this far (px) from the true projection is another image point
LABEL_SEPARATOR = ";"


def camera_column(name: str, c: int) -> str:
    """The column of per-camera quantity ``name`` (one of :data:`PER_CAMERA`) for camera
    ``c`` (1-based)."""
    return f"{name}_c{c}"


def timing_column(stage: str) -> str:
    """The column of a tracker stage's time (ms)."""
    return f"t_{stage}_ms"


def joint_column(robot: str, j: int) -> str:
    """The column of robot ``robot``'s joint ``j`` (1-based)."""
    return f"q_{robot}_{j}"


def joint_fields(joints: Mapping[str, np.ndarray]) -> dict[str, float]:
    """The ``q_{robot}_{j}`` columns of every robot's joint vector."""
    return {joint_column(robot, j + 1): float(v) for robot, q in joints.items()
            for j, v in enumerate(q)}


def columns(n_cameras: int, joint_counts: Mapping[str, int] | None = None) -> list[str]:
    """The header of ``frames.csv`` for ``n_cameras`` cameras and robots with
    ``joint_counts`` (name -> number of joints) joints."""
    cols = ["t", "phase", "stage", "status"]
    for prefix in POSE_PREFIXES:
        cols += [f"{prefix}_{a}" for a in POSE]
    cols += list(GRIPPER)
    for robot, n in (joint_counts or {}).items():
        cols += [joint_column(robot, j) for j in range(1, n + 1)]
    for c in range(1, n_cameras + 1):
        cols += [camera_column(name, c) for name in PER_CAMERA]
    cols += [timing_column(s) for s in STAGES]
    return cols


def encode_bits(mask: Sequence[bool] | np.ndarray) -> str:
    """A boolean mask (F,) as a string of F characters '0'/'1'."""
    return "".join("1" if m else "0" for m in mask)


def decode_bits(text: str) -> np.ndarray:
    """A '0'/'1' string as a boolean mask (the inverse of :func:`encode_bits`)."""
    return np.frombuffer(text.encode(), dtype=np.uint8) == ord("1")


def encode_grid(grid: Grid) -> str:
    """A :class:`~cellsight.tracking.unknown.Grid` as text:
    ``"<rows>x<columns>@<pitch_px>:<hex>"``, the row-major bits packed big-endian into bytes;
    empty when no cell is set."""
    cells = np.asarray(grid.cells, dtype=bool)
    if not cells.any():
        return ""
    bits = np.packbits(cells.ravel()).tobytes().hex()
    return f"{cells.shape[0]}x{cells.shape[1]}@{int(grid.pitch_px)}:{bits}"


def decode_grid(text: str) -> Grid | None:
    """The grid of :func:`encode_grid`; None for an empty text. A text of another
    form is a ValueError quoting it."""
    if not text:
        return None
    match = re.fullmatch(r"(\d+)x(\d+)@(\d+):([0-9a-f]*)", text)
    rows, cols = (int(match[1]), int(match[2])) if match else (0, 0)
    if match is None or len(match[4]) != 2 * (-(-rows * cols // 8)):
        raise ValueError(f"grid {text[:40]!r}: not <rows>x<columns>@<pitch>:<hex of the bits>")
    bits = np.unpackbits(np.frombuffer(bytes.fromhex(match[4]), dtype=np.uint8))
    return Grid(bits[: rows * cols].reshape(rows, cols).astype(bool), int(match[3]))

def encode_windows(features: np.ndarray, boxes: np.ndarray) -> str:
    """Windows (feature index ``features`` (n,), ``boxes`` (n, 4) int) as one field."""
    return LABEL_SEPARATOR.join(f"{int(j)} {int(b[0])} {int(b[1])} {int(b[2])} {int(b[3])}"
                                for j, b in zip(features, boxes, strict=True))


def decode_windows(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Feature indices (n,) and boxes (n, 4) of :func:`encode_windows`' text (empty: none); a
    text of another form is a ValueError quoting it."""
    rows = _number_rows(text, 5, "windows")
    return rows[:, 0].astype(np.int64), rows[:, 1:].astype(np.int64)


def encode_corners(measured: np.ndarray) -> str:
    """The measured corners (F, 2) px, NaN where none, as one field."""
    return LABEL_SEPARATOR.join(f"{j} {u:.3f} {v:.3f}" for j, (u, v) in enumerate(measured)
                                if np.isfinite(u) and np.isfinite(v))


def decode_corners(text: str, n_features: int) -> np.ndarray:
    """(F, 2) px of :func:`encode_corners`' text, NaN where none."""
    rows = _number_rows(text, 3, "corners")
    out = np.full((n_features, 2), np.nan)
    index = rows[:, 0].astype(np.int64)
    if np.any((index < 0) | (index >= n_features)):
        raise ValueError(f"corners {text[:40]!r}: a feature index outside 0..{n_features - 1}")
    out[index] = rows[:, 1:]
    return out


def _number_rows(text: str, width: int, what: str) -> np.ndarray:
    """The ``;``-separated rows of ``width`` numbers of a field, (n, width)."""
    if not text:
        return np.zeros((0, width))
    try:
        rows = np.array([[float(x) for x in part.split()] for part in
                         text.split(LABEL_SEPARATOR)])
    except ValueError:
        rows = np.zeros((0, 0))
    if rows.ndim != 2 or rows.shape[1] != width or not np.all(np.isfinite(rows)):
        raise ValueError(f"{what} {text[:40]!r}: not rows of {width} numbers separated by "
                         f"{LABEL_SEPARATOR!r}")
    return rows


def encode_labels(labels: Sequence[str]) -> str:
    """Per-feature labels ('' for none) as one field."""
    return LABEL_SEPARATOR.join(labels)


def pose_fields(prefix: str, T: np.ndarray | None) -> dict[str, float]:
    """The six ``{prefix}_*`` columns of a pose ``T`` (4x4); none when ``T`` is None (the
    fields stay empty)."""
    if T is None:
        return {}
    xyz, rpy = xyz_rpy_from_pose(T)
    return dict(zip([f"{prefix}_{a}" for a in POSE], [*xyz, *rpy], strict=True))


def timing_fields(seconds: Mapping[str, float]) -> dict[str, float]:
    """The ``t_{stage}_ms`` columns from stage times in seconds (a missing stage is 0), in ms
    rounded to 0.1 us."""
    return {timing_column(s): round(1e3 * seconds.get(s, 0.0), 4) for s in STAGES}


class FrameWriter:
    """Writes ``frames.csv`` row by row, flushing each row (an interrupted run keeps them).
    Use as a context manager or call :meth:`close`. A failed write (a full disk) is a
    :class:`~cellsight.runfolder.writes.WriteError` naming the file; the rows flushed before it
    stay (a row cut off mid-write is dropped on reading)."""

    def __init__(self, path: Path, n_cameras: int,
                 joint_counts: Mapping[str, int] | None = None) -> None:
        self.path = Path(path)
        self.columns = columns(n_cameras, joint_counts)
        try:
            self._file: TextIO = self.path.open("w", newline="")
        except OSError as exc:
            raise write_error(self.path, exc) from exc
        self._writer = csv.DictWriter(self._file, self.columns, quoting=csv.QUOTE_NONNUMERIC)
        try:
            self._written(self._writer.writeheader)
        except WriteError:  # no writer to close it: the file is closed here, what it can
            with suppress(OSError):
                self._file.close()
            raise

    def _written(self, write: Callable[[], object]) -> None:
        """``write`` then flush; an OSError is a WriteError naming the file."""
        try:
            write()
            self._file.flush()
        except OSError as exc:
            raise write_error(self.path, exc) from exc

    def write(self, row: Mapping[str, object]) -> None:
        """Write one row (column -> value); missing columns and None values become empty
        fields; an unknown column is an error."""
        unknown = set(row) - set(self.columns)
        if unknown:
            raise KeyError(f"frames.csv has no columns {sorted(unknown)}")
        self._written(lambda: self._writer.writerow(
            {k: ("" if v is None else v) for k, v in row.items()}))

    def close(self) -> None:
        """Close the file (safe to call twice); a failure to write out its end is a
        WriteError naming it."""
        try:
            self._file.close()
        except OSError as exc:
            raise write_error(self.path, exc) from exc

    def __enter__(self) -> FrameWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        self.close()


@dataclass
class FrameLog:
    """``frames.csv`` read back: ``columns`` name -> one string per row ('' = missing), ``n``
    rows, ``source`` the file (for errors). The accessors type the columns; an absent column
    reads as missing in every row; a value that is not what its column holds is a
    :class:`~cellsight.errors.CellsightError` naming the file, the column and the row."""

    columns: dict[str, list[str]]
    n: int
    source: str = "frames.csv"

    @classmethod
    def read(cls, path: Path) -> FrameLog:
        """Read a frames file; rows with the wrong field count (a line cut off mid-write) are
        dropped. An absent file reads as no rows; one that is not a regular file, not UTF-8
        text, or not CSV (a field past the csv module's limit) is a :class:`CellsightError`
        naming it."""
        path = Path(path)
        if not path.exists():
            return cls({}, 0)
        if not is_regular_file(path):  # a FIFO would block for ever
            raise CellsightError(f"{path}: not a regular file (a folder, a FIFO or a device); "
                                 f"expected a run's frames.csv")
        try:
            with path.open(newline="", encoding="utf-8") as f:
                reader = csv.reader(f)
                header = next(reader, [])
                rows = [r for r in reader if header and len(r) == len(header)]
        except UnicodeDecodeError:
            raise CellsightError(f"{path}: not UTF-8 text: not a cellsight run's frames.csv, "
                                 f"or damaged") from None
        except csv.Error as exc:
            raise CellsightError(f"{path}: not a CSV file cellsight can read ({exc}): not a "
                                 f"cellsight run's frames.csv, or damaged") from None
        except OSError as exc:
            raise CellsightError(f"{path}: cannot read it ({exc.strerror or exc})") from None
        return cls({name: [r[i] for r in rows] for i, name in enumerate(header)}, len(rows),
                   str(path))

    def text(self, name: str) -> list[str]:
        """A column's strings."""
        return self.columns.get(name, [""] * self.n)

    def floats(self, name: str) -> np.ndarray:
        """A column as float (N,), NaN where missing."""
        values = self.text(name)
        try:
            return np.array([float(v) if v else np.nan for v in values], dtype=float)
        except ValueError:
            row, bad = next((i, v) for i, v in enumerate(values) if v and not _is_number(v))
            raise CellsightError(f"{self.source}: column {name!r}, row {row + 1}: {bad!r} is "
                                 f"not a number (edited by hand, or not a cellsight run's "
                                 f"frames.csv?)") from None

    def present(self, name: str) -> np.ndarray:
        """(N,) bool: rows where the column has a value."""
        return np.array([bool(v) for v in self.text(name)], dtype=bool)

    def used(self) -> np.ndarray:
        """(N,) bool: rows whose measurements went into an estimate (the status is neither
        ``waiting`` nor ``lost``: an acquisition that gave no fix used nothing)."""
        return ~np.isin(np.array(self.text("status"), dtype=str), ("waiting", "lost"))

    def used_by_camera(self) -> np.ndarray:
        """(N, C) bool: per camera, rows whose measurements went into an estimate
        (:meth:`used`, and the camera not ``held_out``)."""
        held_out = np.zeros((self.n, self.n_cameras), dtype=bool)
        for c in range(self.n_cameras):
            held_out[:, c] = self.floats(camera_column("held_out", c + 1)) == 1
        return self.used()[:, None] & ~held_out

    def bits(self, name: str, n_features: int | None = None) -> np.ndarray:
        """A 0/1 column as (N, F) bool; missing rows are all False. ``n_features`` defaults to
        :attr:`n_features`; a row of another length is an error."""
        F = self.n_features if n_features is None else n_features
        out = np.zeros((self.n, F), dtype=bool)
        for i, s in enumerate(self.text(name)):
            if s:
                if len(s) != F:
                    raise CellsightError(f"{self.source}: column {name!r}, row {i + 1}: "
                                         f"{len(s)} flags, expected {F}")
                out[i] = decode_bits(s)
        return out

    def labels(self, name: str, n_features: int | None = None) -> np.ndarray:
        """A label column as (N, F) str objects ('' = none, or a missing row); ``n_features``
        as in :meth:`bits`."""
        F = self.n_features if n_features is None else n_features
        out = np.full((self.n, F), "", dtype=object)
        for i, s in enumerate(self.text(name)):
            if s:
                parts = s.split(LABEL_SEPARATOR)
                if len(parts) != F:
                    raise CellsightError(f"{self.source}: column {name!r}, row {i + 1}: "
                                         f"{len(parts)} labels, expected {F}")
                out[i] = parts
        return out

    def grids(self, name: str) -> list[Grid | None]:
        """A grid column (:func:`encode_grid`) per row: the grid, or None where empty."""
        return [decode_grid(s) for s in self.text(name)]

    def poses(self, prefix: str) -> np.ndarray:
        """(N, 6) ``{prefix}_x .. {prefix}_yaw`` (m, rad), NaN rows where missing."""
        return np.column_stack([self.floats(f"{prefix}_{a}") for a in POSE]).reshape(-1, 6)

    @property
    def robots(self) -> dict[str, int]:
        """Robot name -> number of joints, for every robot with ``q_{robot}_{j}`` columns (in
        the order logged; none in runs logged before them)."""
        counts: dict[str, int] = {}
        for name in self.columns:
            match = re.fullmatch(r"q_(.+)_(\d+)", name)
            if match:
                counts[match[1]] = max(counts.get(match[1], 0), int(match[2]))
        return counts

    def joints(self, robot: str) -> np.ndarray:
        """(N, n) robot ``robot``'s logged joint values; a KeyError names the robots logged."""
        n = self.robots.get(robot)
        if n is None:
            raise KeyError(f"frames.csv has no joint columns of robot {robot!r} (logged: "
                           f"{sorted(self.robots) or 'none'})")
        return np.column_stack([self.floats(joint_column(robot, j))
                                for j in range(1, n + 1)]).reshape(self.n, n)

    @property
    def n_cameras(self) -> int:
        """Number of cameras c = 1, 2, ... that have a ``vis_pred_c{c}`` column."""
        c = 0
        while camera_column("vis_pred", c + 1) in self.columns:
            c += 1
        return c

    @property
    def n_features(self) -> int:
        """Number of features: the length of the first 0/1 field of camera 1 (0 if none)."""
        for name in ("vis_true", "vis_pred"):
            flags = [s for s in self.text(camera_column(name, 1)) if s]
            if flags:
                return len(flags[0])
        return 0


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True

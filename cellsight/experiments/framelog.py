"""``frames.csv``: one row per vision frame, written and flushed as the run goes.

Columns (C cameras numbered c = 1..C, F features; an empty field is a missing value):

- ``t`` (s), ``phase`` and ``stage`` of the grasping task, ``status`` of the tracker;
- ``true_x, true_y, true_z, true_roll, true_pitch, true_yaw``: the part's true pose (m, rad,
  base frame, roll-pitch-yaw as in :func:`~cellsight.geometry.transforms.xyz_rpy_from_pose`);
  ``est_*`` the EKF's estimate after this frame's update (empty while the part is not acquired
  yet or lost); ``pnp_*`` the per-frame multi-camera
  PnP baseline on the same measurements (a frame with too few holds the last fix, for at
  most the tracker's ``lost_after_s``);
- ``gripper_x, gripper_y, gripper_z`` (m): the grasping robot's true TCP; ``jaw_opening`` (m);
  ``jaws_closed`` (jaws closed on the part, 0/1); ``grasped`` (part held, 0/1);
- per camera: ``vis_pred_c{c}`` (predicted visible at the tracker's predicted pose),
  ``vis_true_c{c}`` (visible by the simulator's ray casts at the true pose), ``sel_c{c}``
  (selected: a window was planned), ``meas_c{c}`` (a feature was measured in it), ``rej_c{c}``
  (measured, rejected by the EKF's gate), ``wrong_c{c}`` (measured more than ``WRONG_PX`` from
  the feature's true projection): strings of F characters ``0``/``1`` in feature order;
  ``occ_pred_c{c}``, ``occ_true_c{c}``: F labels joined by ``;`` (empty when visible, ``self``,
  ``behind``, ``outside`` or the hiding object's label); ``grab_c{c}``: fraction of the image's
  pixels grabbed; ``err_px_c{c}``: median distance (px) of this frame's measurements from the
  true projections (rendered sensor);
- ``t_occlusion_ms, t_selection_ms, t_windowing_ms, t_extraction_ms, t_ekf_ms, t_total_ms``:
  the tracker's stage times (EKF = prediction + update).

Strings are quoted (``csv.QUOTE_NONNUMERIC``); read the 0/1 columns as strings (pandas:
``dtype=str``) or their leading zeros are lost.
"""

from __future__ import annotations

import csv
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TextIO

POSE = ("x", "y", "z", "roll", "pitch", "yaw")
STAGES = ("occlusion", "selection", "windowing", "extraction", "ekf", "total")
PER_CAMERA = ("vis_pred", "vis_true", "sel", "meas", "rej", "wrong", "occ_pred", "occ_true",
              "grab", "err_px")
WRONG_PX = 3.0  # a measurement this far (px) from the true projection is another image point


def columns(n_cameras: int) -> list[str]:
    """The header of ``frames.csv`` for ``n_cameras`` cameras."""
    cols = ["t", "phase", "stage", "status"]
    for prefix in ("true", "est", "pnp"):
        cols += [f"{prefix}_{a}" for a in POSE]
    cols += ["gripper_x", "gripper_y", "gripper_z", "jaw_opening", "jaws_closed", "grasped"]
    for c in range(1, n_cameras + 1):
        cols += [f"{name}_c{c}" for name in PER_CAMERA]
    cols += [f"t_{s}_ms" for s in STAGES]
    return cols


def bits(mask) -> str:
    """A boolean mask as a string of '0'/'1'."""
    return "".join("1" if m else "0" for m in mask)


class FrameLog:
    """Writes ``frames.csv`` row by row, flushing each row (an interrupted run keeps them)."""

    def __init__(self, path: Path, n_cameras: int) -> None:
        self.path = Path(path)
        self.columns = columns(n_cameras)
        self._file: TextIO = self.path.open("w", newline="")
        self._writer = csv.DictWriter(self._file, self.columns, quoting=csv.QUOTE_NONNUMERIC)
        self._writer.writeheader()
        self._file.flush()

    def write(self, row: Mapping[str, object]) -> None:
        """Write one row; missing values (None) become empty fields."""
        unknown = set(row) - set(self.columns)
        if unknown:
            raise KeyError(f"frames.csv has no columns {sorted(unknown)}")
        self._writer.writerow({k: ("" if v is None else v) for k, v in row.items()})
        self._file.flush()

    def close(self) -> None:
        self._file.close()


def read_frames(path: Path) -> Iterator[dict[str, str]]:
    """The rows of a ``frames.csv`` as dicts of strings (0/1 masks kept as strings)."""
    with Path(path).open(newline="") as f:
        yield from csv.DictReader(f)

"""A calibration folder (``cellsight calibrate --out DIR``) read back and applied to its cell:
``run``, ``sweep``, ``track`` and the API take it as the model side (``--calibration DIR``).

``DIR/calibration.json`` holds, in the reference robot's base frame (its frame 0, the frame the
calibration is made in), each camera's intrinsics (``K``, ``dist``, image size) and pose
(``T_ref_cam``: the optical frame, x right, y down, z forward, in the reference frame; m), and
each other robot's base (``T_ref_robot``). Applied to the cell the calibration was made for
(the same cell file and files, by their SHA-256), the cell's base frame is kept where the cell
file puts the reference robot: a camera's pose becomes ``T_base_ref @ T_ref_cam`` and another
robot's base ``T_base_ref @ T_ref_robot``, with ``T_base_ref`` the cell file's pose of the
reference robot. What else the cell file says (workpieces, static objects) is kept as it is.

Every refusal names the file, the field and the value, and what to do.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from cellsight.camera import Camera
from cellsight.errors import CellsightError
from cellsight.geometry.transforms import is_rigid
from cellsight.model import Cell
from cellsight.runfolder.digest import cell_digest

CALIBRATION_FILE = "calibration.json"
SCHEMA_VERSION = 1


def _matrix(file: Path, field: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        array = np.empty(0)
    if array.shape != shape or not np.all(np.isfinite(array)):
        raise CellsightError(f"{file}: {field}: expected {'x'.join(map(str, shape))} finite "
                             f"numbers, got {str(value)[:80]}")
    return array


def _pose(file: Path, field: str, value: object) -> np.ndarray:
    T = _matrix(file, field, value, (4, 4))
    if not is_rigid(T):
        raise CellsightError(f"{file}: {field}: not a rigid transform")
    return T


def read_calibration(folder: str | Path) -> dict:
    """``DIR/calibration.json`` as written by ``cellsight calibrate``, its version checked."""
    file = Path(folder) / CALIBRATION_FILE
    try:
        data = json.loads(file.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CellsightError(f"--calibration: {folder}: no {CALIBRATION_FILE} (a folder "
                             f"written by cellsight calibrate --out)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CellsightError(f"{file}: not a calibration: {exc}") from None
    if not isinstance(data, dict) or data.get("schema") != SCHEMA_VERSION:
        version = data.get("schema") if isinstance(data, dict) else None
        raise CellsightError(f"{file}: schema: expected {SCHEMA_VERSION}, got {version!r}")
    return data


def _camera(file: Path, data: dict, camera: Camera, T_base_ref: np.ndarray) -> Camera:
    entry = data.get("cameras", {}).get(camera.name)
    if not isinstance(entry, dict):
        raise CellsightError(f"{file}: cameras: no camera {camera.name!r} (calibrated: "
                             f"{', '.join(data.get('cameras', {}))}); calibrate this cell")
    size = (entry.get("width"), entry.get("height"))
    if size != (camera.width, camera.height):
        raise CellsightError(f"{file}: cameras.{camera.name}: image {size[0]}x{size[1]}, the "
                             f"cell's is {camera.width}x{camera.height}")
    K = _matrix(file, f"cameras.{camera.name}.K", entry.get("K"), (3, 3))
    dist = _matrix(file, f"cameras.{camera.name}.dist", entry.get("dist"), (5,))
    T = _pose(file, f"cameras.{camera.name}.T_ref_cam", entry.get("T_ref_cam"))
    return Camera(K, camera.width, camera.height, T_base_ref @ T, dist, camera.name)


def calibrated_cell(cell: Cell, folder: str | Path) -> Cell:
    """``cell`` with the cameras and robot bases of the calibration in ``folder`` (module
    docstring); refused when the calibration was made for another cell, or another version of
    this one."""
    data = read_calibration(folder)
    file = Path(folder) / CALIBRATION_FILE
    digest = cell_digest(cell)
    if data.get("cell_sha256") != digest:
        raise CellsightError(
            f"{file}: cell_sha256: calibrated for {data.get('cell')!r} "
            f"({str(data.get('cell_sha256'))[:12]}), not for {cell.source!r} "
            f"({str(digest)[:12]}): another cell, or its files changed since; run cellsight "
            f"calibrate on this cell")
    reference = data.get("reference_robot")
    if reference not in {r.name for r in cell.robots}:
        raise CellsightError(f"{file}: reference_robot: {reference!r} is not a robot of "
                             f"{cell.source}")
    T_base_ref = cell.robot(reference).T_base_robot
    cameras = [_camera(file, data, c, T_base_ref) for c in cell.cameras]
    bases = data.get("robots", {})
    robots = [replace(r, T_base_robot=T_base_ref @ _pose(
                  file, f"robots.{r.name}.T_ref_robot", bases[r.name]["T_ref_robot"]))
              if r.name in bases and r.name != reference else r for r in cell.robots]
    return Cell(cell.name, robots, cell.workpieces, cell.static, cameras, cell.source,
                cell.experiments, cell.files)

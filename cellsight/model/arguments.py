"""Command-line values of a cell's state, shared by ``cellsight show``, ``visibility`` and
``view``: ``--joints`` and ``--part-pose`` (JSON text, or the name of a JSON file). Every bad
value is a :class:`~cellsight.errors.CellsightError` naming the option and the value."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from cellsight.errors import CellsightError, short_repr
from cellsight.geometry.transforms import is_rigid, pose_from_xyz_rpy


def json_value(text: str | None, option: str):
    """``text`` parsed as JSON, or the JSON file it names (text starting with ``{`` or ``[`` is
    always JSON); None when ``text`` is None."""
    if text is None:
        return None
    source = text
    if text.lstrip()[:1] not in ("{", "["):
        path = Path(text)
        try:
            is_file = path.is_file()
        except (OSError, ValueError):  # not a usable path: take it as JSON text
            is_file = False
        if is_file:
            try:
                source = path.read_bytes().decode("utf-8")
            except UnicodeDecodeError as exc:
                raise CellsightError(f"--{option}: {path}: not UTF-8 text") from exc
    try:
        return json.loads(source, object_pairs_hook=lambda pairs: _unique(pairs, option))
    except json.JSONDecodeError as exc:
        raise CellsightError(f"--{option}: not valid JSON ({exc.msg} at column {exc.colno})"
                             ) from exc


def _unique(pairs: list[tuple[str, object]], option: str) -> dict:
    """A JSON object's pairs as a dict; a key given twice is an error (as in a cell file)."""
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise CellsightError(f"--{option}: key {key!r} given twice")
        out[key] = value
    return out


def _has_bool(value: object) -> bool:
    """``value`` is, or nests in lists, a JSON ``true``/``false``."""
    return isinstance(value, bool) or (isinstance(value, list) and any(map(_has_bool, value)))


def _numbers(value, what: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """``value`` as finite floats (of ``shape`` if given), else an error naming ``what``; a
    ``true`` or ``false`` is not a number."""
    try:
        array = None if _has_bool(value) else np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        array = None
    if (array is None or array.ndim == 0 or (shape is not None and array.shape != shape)
            or not np.all(np.isfinite(array))):
        expected = "finite numbers" if shape is None else f"finite numbers of shape {shape}"
        raise CellsightError(f"{what}: expected {expected}, got {short_repr(value)}")
    return array


def parse_joints(text: str | None) -> dict[str, np.ndarray]:
    """``{"R7AX": [q1, ...], ...}`` (JSON or a JSON file) -> robot name -> joint vector."""
    data = json_value(text, "joints") or {}
    if not isinstance(data, dict):
        raise CellsightError(f"--joints: expected an object robot -> list of numbers, got "
                             f"{short_repr(data)}")
    return {name: _numbers(q, f"--joints: robot {name!r}") for name, q in data.items()}


def parse_openings(text: str | None) -> dict[str, float]:
    """``{"R7AX": 0.03, ...}`` (JSON or a JSON file) -> robot name -> jaw opening (m); the
    range is the cell's to check (:meth:`Cell.snapshot <cellsight.model.Cell.snapshot>`)."""
    data = json_value(text, "openings") or {}
    if not isinstance(data, dict):
        raise CellsightError(f"--openings: expected an object robot -> opening in metres, got "
                             f"{short_repr(data)}")
    out = {}
    for name, value in data.items():
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not np.isfinite(value):
            raise CellsightError(f"--openings: robot {name!r}: expected a finite number of "
                                 f"metres, got {short_repr(value)}")
        out[name] = float(value)
    return out


def parse_part_poses(text: str | None) -> dict[str, np.ndarray]:
    """``{"part": {"xyz": [...], "rpy": [...]}}`` or a 4x4 rigid transform per workpiece."""
    data = json_value(text, "part-pose") or {}
    if not isinstance(data, dict):
        raise CellsightError(f"--part-pose: expected an object name -> pose, got "
                             f"{short_repr(data)}")
    return {name: _pose(value, f"--part-pose: {name!r}") for name, value in data.items()}


def parse_tcp_pose(text: str) -> np.ndarray:
    """``{"xyz": [...], "rpy": [...]}`` or a 4x4 rigid transform (JSON or a JSON file) -> the
    pose (4, 4)."""
    return _pose(json_value(text, "tcp-pose"), "--tcp-pose")


def _pose(value, what: str) -> np.ndarray:
    """A pose from ``{"xyz": [...], "rpy": [...]}`` (m, rad; missing: zeros) or a 4x4 rigid
    transform; ``what`` names the argument in the error."""
    if isinstance(value, dict):
        unknown = sorted(set(value) - {"xyz", "rpy"})
        if unknown:
            raise CellsightError(f"{what}: unknown keys {unknown}; expected xyz and rpy")
        xyz = _numbers(value.get("xyz", [0, 0, 0]), f"{what}.xyz", (3,))
        rpy = _numbers(value.get("rpy", [0, 0, 0]), f"{what}.rpy", (3,))
        return pose_from_xyz_rpy(xyz, rpy)
    T = _numbers(value, what, (4, 4))
    if not is_rigid(T):
        raise CellsightError(f"{what}: expected a rigid transform (rotation with det +1, "
                             f"last row 0 0 0 1), got {short_repr(value)}")
    return T

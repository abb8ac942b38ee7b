"""Cells of any size for scaling studies: UR5 arms (real collision meshes from
example-robot-data) around a long table, U-shaped 16-point workpieces on it, cameras on a ring.

:func:`scale_cell_text` writes the cell file (YAML, the same format as ``ur_cell.yaml``);
:func:`scale_cell` loads it. Layout (base frame on the floor, z up, metres):

- a table ``0.8 * arms + 0.8`` m long (x) and 1.6 m wide, its top at 0.55 m;
- arm k stands on the table's edge, on the -y side for even k and the +y side for odd k, at
  evenly spaced x, facing the table's centre line; each carries the built-in cell's gripper;
- workpiece j lies on the centre line at evenly spaced x, yawed by ``0.4 * j`` rad;
- camera i sits on an ellipse 1.2 m outside the table's corners, 1.9 m high, at evenly spaced
  angles (starting at -90 degrees: the -y side), looking at the table's centre; 768x576, 8.3 um
  pixels, 6 mm lens (about 56 degrees across), so that every camera sees most of the table.

The bench (``bench/bench_scale.py``) and the tests draw random joints and part poses in it
(:func:`cellsight.occlusion.scenarios.random_snapshots`).
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import yaml

from cellsight.model.cell import Cell
from cellsight.model.loader import load_cell

TABLE_TOP = 0.55  # m
UR5 = "package://example-robot-data/robots/ur_description/urdf/ur5_robot.urdf"
GRIPPER = {  # the built-in cell's parallel-jaw gripper, on tool0
    "palm": [{"box": {"size": [0.08, 0.15, 0.07], "center": [0.0, 0.0, 0.035]}}],
    "jaw": {"box": {"size": [0.035, 0.012, 0.09], "center": [0.0, 0.006, 0.115]}},
    "max_opening": 0.09,
    "tcp": [0.0, 0.0, 0.145],
}
U_PART = {"prism": {  # the built-in 16-point U-shaped part, 10 x 6 x 3 cm
    "polygon": [[-0.05, -0.03], [0.05, -0.03], [0.05, 0.03], [0.02, 0.03], [0.02, 0.01],
                [-0.02, 0.01], [-0.02, 0.03], [-0.05, 0.03]],
    "height": 0.03,
}}


def scale_cell_text(cameras: int, arms: int, parts: int) -> str:
    """The cell file (YAML text) of ``cameras`` cameras, ``arms`` UR5 arms and ``parts``
    workpieces; each count at least 1."""
    if min(cameras, arms, parts) < 1:
        raise ValueError(f"cameras, arms and parts must be >= 1, got {cameras}, {arms}, {parts}")
    length = 0.8 * arms + 0.8
    spec = {
        "name": f"scale cell: {cameras} cameras, {arms} UR5, {parts} parts",
        "robots": [_arm(k, arms, length) for k in range(arms)],
        "workpieces": [_part(j, parts, length) for j in range(parts)],
        "static": [{"name": "table", "solids": [{"box": {
            "size": [length, 1.6, 0.05], "center": [0.0, 0.0, TABLE_TOP - 0.025]}}]}],
        "cameras": [_camera(i, cameras, length) for i in range(cameras)],
    }
    return yaml.safe_dump(spec, sort_keys=False)


def scale_cell(cameras: int, arms: int, parts: int) -> Cell:
    """The loaded cell of :func:`scale_cell_text` (meshes are read once per process)."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"scale_{cameras}c_{arms}a_{parts}p.yaml"
        path.write_text(scale_cell_text(cameras, arms, parts))
        return load_cell(path)


def _spaced(k: int, n: int, length: float) -> float:
    """The x of the k-th of n evenly spaced places along a table ``length`` long (m)."""
    return (k + 0.5) / n * length - 0.5 * length


def _arm(k: int, arms: int, length: float) -> dict:
    """Arm k: alternately on the -y and +y edge, facing the centre line."""
    side = -1.0 if k % 2 == 0 else 1.0
    pairs = (arms + 1) // 2
    x = _spaced(k // 2, pairs, length)
    return {"name": f"UR5_{k + 1}",
            "base": {"xyz": [round(x, 4), 0.7 * side, TABLE_TOP], "rpy": [0.0, 0.0,
                                                                        -side * math.pi / 2]},
            "urdf": {"file": UR5, "geometry": "collision"},
            "tool": GRIPPER,
            "home": [0.0, -1.57, 1.57, -1.57, -1.57, 0.0]}


def _part(j: int, parts: int, length: float) -> dict:
    """Workpiece j on the table's centre line."""
    x = _spaced(j, parts, 0.6 * length)
    return {"name": f"part{j + 1}", "solid": U_PART,
            "pose": {"xyz": [round(x, 4), 0.0, TABLE_TOP], "rpy": [0.0, 0.0, 0.4 * j]}}


def _camera(i: int, cameras: int, length: float) -> dict:
    """Camera i on an ellipse around the table, looking at its centre."""
    angle = -math.pi / 2 + 2 * math.pi * i / cameras
    eye = [round((0.5 * length + 1.2) * math.cos(angle), 4),
           round(2.0 * math.sin(angle), 4), 1.9]
    return {"name": f"cam{i + 1}", "width": 768, "height": 576, "lens_mm": 6.0,
            "pixel_mm": 0.0083,
            "look_at": {"eye": eye, "target": [0.0, 0.0, TABLE_TOP + 0.1]}}

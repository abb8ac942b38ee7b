"""Where the unmodelled bodies of a realism profile go (:mod:`cellsight.world.intruders`).

- ``unknown.box``: a box standing at the part's height 15-30 cm from its start towards one
  camera (up to 10 cm to either side), turned to face it, so that it may hide the part's lower
  features from that camera; never on the conveyor's path (the conveyor would carry the part
  through it, and the gripper grasps the part there): a spot nearer the path than
  ``PATH_CLEARANCE_M`` beyond the box's half width and the part's or the open gripper's,
  whichever is wider, is moved straight away from the path to that distance;
- ``unknown.forearm``: a 40 x 8 x 8 cm bar, horizontal and across one camera's line of sight to
  the part (5 cm above the part's start), 25-60 % of the way to the camera; it comes in along
  its own length from 80 cm to the side and leaves the same way.

``place`` values in [0, 1) pick the spot within those ranges. Units: m, s.
"""

from __future__ import annotations

import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.polyhedron import box
from cellsight.geometry.transforms import make_pose, transform_points
from cellsight.model.cell import Workpiece
from cellsight.world.intruders import Intruder

FOREARM_SIZE = (0.40, 0.08, 0.08)  # m: length, width, height
FOREARM_REACH = 0.8  # m travelled sideways to come in
PATH_CLEARANCE_M = 0.02  # m between the box and the part anywhere along the conveyor's path


def _frame(x_axis: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """A pose with horizontal x along ``x_axis`` (projected), z up, at ``origin``."""
    x = np.array([x_axis[0], x_axis[1], 0.0])
    x /= np.linalg.norm(x)
    z = np.array([0.0, 0.0, 1.0])
    return make_pose(np.column_stack([x, np.cross(z, x), z]), origin)


def table_box(part: Workpiece, camera: Camera, size: np.ndarray, place: np.ndarray,
              path: np.ndarray | None = None, gripper_m: float = 0.0) -> Intruder:
    """The box of the module docstring, ``size`` (3,) m; ``path``: the conveyor's polyline
    ((k, 2) x, y of the part's origin, base frame), none for a part that stays put;
    ``gripper_m``: how far the gripper reaches across its approach around the part's grasp
    (:meth:`~cellsight.model.robot.ParallelGripper.reach_across`)."""
    start = part.T_base_part[:3, 3]
    vertices = transform_points(part.T_base_part, part.solid.vertices)
    towards = camera.center - start
    frame = _frame(towards, np.zeros(3))
    ahead, side = frame[:3, 0], frame[:3, 1]
    centre = start + (0.15 + 0.15 * place[0]) * ahead + (place[1] - 0.5) * 0.2 * side
    centre[2] = vertices[:, 2].min() + 0.5 * size[2]
    if path is not None and len(path):
        part_m = float(np.linalg.norm(vertices[:, :2] - start[:2], axis=1).max())
        reach = 0.5 * float(np.hypot(size[0], size[1])) + max(part_m, gripper_m) + (
            PATH_CLEARANCE_M)
        centre[:2] = _off_path(centre[:2], np.vstack([start[:2], path]), reach, side[:2])
    frame[:3, 3] = centre
    return Intruder("unknown.box", box("unknown.box", size), frame)


def _off_path(xy: np.ndarray, path: np.ndarray, reach: float, side: np.ndarray) -> np.ndarray:
    """``xy`` moved straight away from the polyline ``path`` (k, 2) to ``reach`` (m) from it
    when nearer (along ``side`` when on it); else unchanged."""
    a, b = path[:-1], path[1:]
    ab = b - a
    length2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18)
    s = np.clip(np.einsum("ij,ij->i", xy - a, ab) / length2, 0.0, 1.0)
    nearest = a + s[:, None] * ab
    gaps = np.linalg.norm(xy - nearest, axis=1)
    k = int(np.argmin(gaps)) if len(gaps) else 0
    if not len(gaps) or gaps[k] >= reach:
        return xy
    away = (xy - nearest[k]) / gaps[k] if gaps[k] > 1e-9 else side / np.linalg.norm(side)
    return nearest[k] + reach * away


def forearm(part: Workpiece, camera: Camera, t_in: float, t_out: float, place: float
            ) -> Intruder:
    """The forearm of the module docstring, in view from ``t_in`` to ``t_out`` (s)."""
    target = part.T_base_part[:3, 3] + [0.0, 0.0, 0.05]
    sight = camera.center - target
    across = np.cross(sight, [0.0, 0.0, 1.0])
    T_in = _frame(across, target + (0.25 + 0.35 * place) * sight)
    T_out = T_in.copy()
    T_out[:3, 3] += FOREARM_REACH * T_in[:3, 0]
    return Intruder("unknown.forearm", box("unknown.forearm", FOREARM_SIZE), T_in, T_out,
                    t_in, t_out)
